"""A simulated campaign written to files, the one entry of ``ordervib simulate`` and the benchmarks.

``Simulation`` holds the settings (each checked by ``Simulation.check`` with a one-line error);
``simulate_files`` simulates the campaign and writes REC.mcap (contract sections 1 and 3),
REC.schedule.toml (section 4) and REC.truth.json. The same settings give byte-identical files.

>>> Simulation(runs=0).check()
Traceback (most recent call last):
...
node.contract.errors.OrdervibError: --runs must be between 1 and 100, got 0
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Callable
from dataclasses import dataclass

from node.contract.errors import OrdervibError

_BED_RE = re.compile(r"^[A-Za-z0-9_.-]+$")
MAX_RUNS = 100


@dataclass(frozen=True)
class Simulation:
    """The settings of one simulated campaign (``ordervib simulate``'s options, same names).

    runs: runs simulated; skip: the first ``skip`` are simulated (engine history) but not
    written; fault, fault_seed, fault_size: a fault in the last run (``FAULTS``), its draw and
    its magnitude (None: nominal); schedule: a contract schedule file to run instead of the
    built-in OCs; channels: comma list of the channels written (None: all); phase: write the
    order phases; tracker: the order tracker's lag, "fixed" (1 s) or "drawn" per engine (0.5-2 s).
    """

    runs: int = 3
    seed: int = 0
    fault: str | None = None
    fault_seed: int | None = None
    fault_size: float | None = None
    schedule: str | None = None
    noise_scale: float = 1.0
    bed: str = "bed1"
    plateau_scale: float = 1.0
    skip: int = 0
    channels: str | None = None
    phase: bool = True
    tracker: str = "fixed"

    def check(self) -> None:
        """One-line ``OrdervibError`` for the first setting out of its range."""
        from simulator.campaign import FAULTS, STIFFNESS_FAULTS

        if not 1 <= self.runs <= MAX_RUNS:
            raise OrdervibError(f"--runs must be between 1 and {MAX_RUNS}, got {self.runs}")
        if self.seed < 0:
            raise OrdervibError(f"--seed must be >= 0, got {self.seed}")
        if self.fault is not None and self.fault not in FAULTS:
            raise OrdervibError(f"--fault must be one of {', '.join(FAULTS)}, got {self.fault!r}")
        if self.fault_seed is not None and (self.fault is None or self.fault_seed < 0):
            raise OrdervibError("--fault-seed needs --fault and must be >= 0")
        if self.fault_size is not None and (
            self.fault is None or not (math.isfinite(self.fault_size) and self.fault_size > 0)
        ):
            raise OrdervibError("--fault-size needs --fault and must be > 0 and finite")
        if self.fault in STIFFNESS_FAULTS and self.fault_size is not None and self.fault_size >= 10.0:
            raise OrdervibError(
                f"--fault-size must be < 10 for a stiffness fault (no stiffness left), "
                f"got {self.fault_size:g}"
            )
        if not _BED_RE.match(self.bed):
            raise OrdervibError(f"--bed must be letters, digits, '_', '-' or '.', got {self.bed!r}")
        if not 0.05 <= self.plateau_scale <= 10.0:
            raise OrdervibError(f"--plateau-scale must be between 0.05 and 10, got {self.plateau_scale}")
        if not (math.isfinite(self.noise_scale) and self.noise_scale > 0):
            raise OrdervibError(f"--noise-scale must be > 0 and finite, got {self.noise_scale:g}")
        if self.tracker not in ("fixed", "drawn"):
            raise OrdervibError(f"--tracker must be fixed or drawn, got {self.tracker!r}")
        if not 0 <= self.skip < self.runs:
            raise OrdervibError(f"--skip must be between 0 and runs - 1, got {self.skip}")
        self.channel_names()

    def channel_names(self) -> tuple[str, ...] | None:
        """The channels written (None: every one), checked against the known ones."""
        from node.contract import PHASE_CHANNELS, SENSOR_CHANNELS

        if self.channels is None:
            return None
        known = SENSOR_CHANNELS + (PHASE_CHANNELS if self.phase else ())
        names = tuple(c.strip() for c in self.channels.split(",") if c.strip())
        unknown = [c for c in names if c not in known]
        if unknown or not names or len(set(names)) != len(names):
            without = " (--no-phase leaves out the phases)" if not self.phase else ""
            raise OrdervibError(
                f"--channels must be distinct names among {','.join(known)}{without}, "
                f"got {self.channels!r}"
            )
        return names


def simulate_files(
    sim: Simulation,
    out: str,
    progress: Callable[[float], None] | None = None,
    part: str | None = None,
) -> tuple[int, str, str]:
    """Simulate ``sim`` (checked first) and write ``out`` (.mcap) with its two sidecars.

    part: where to write the recording's bytes (a temporary name the caller renames to
    ``out``; default ``out`` itself); the sidecars are named after ``out``.
    Returns (messages written, schedule path, truth path).
    """
    sim.check()
    channels = sim.channel_names()
    from simulator.campaign import simulate_campaign
    from simulator.export import write_recording, write_sidecars
    from simulator.schedule import load_sim_schedule

    schedule = None if sim.schedule is None else load_sim_schedule(sim.schedule)
    campaign = simulate_campaign(
        sim.runs,
        sim.seed,
        sim.fault,
        sim.plateau_scale,
        sim.fault_seed,
        fault_size=1.0 if sim.fault_size is None else sim.fault_size,
        schedule=schedule,
        noise_scale=sim.noise_scale,
        phase=sim.phase,
        tracker=sim.tracker,
    )
    count = write_recording(
        campaign, os.fspath(part or out), sim.bed, sim.seed, sim.skip, progress, channels=channels
    )
    schedule_path, truth_path = write_sidecars(campaign, out, sim.bed, sim.seed, sim.skip, channels)
    return count, schedule_path, truth_path
