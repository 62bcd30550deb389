"""``ordervib simulate``: pass-off runs of the built-in test-bed simulator, to MCAP.

Writes REC.mcap (contract sections 1 and 3), REC.schedule.toml (section 4) and
REC.truth.json (run times, shutdown times, OC intervals, fault onset, schedule
origin, noise scale). The same seed gives byte-identical files. ``--schedule``
runs the OCs of a contract schedule file instead of the built-in 12;
``--noise-scale`` scales every sensor's noise. The optional order phases
(``yA_ph``, ``yB_ph``, ``yC_ph``, degrees) are written unless ``--no-phase``; every
other channel is the same either way.
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import re
import time

from node.cli.logs import Progress
from node.cli.outputs import check_output, replacing
from node.contract.errors import OrdervibError

log = logging.getLogger(__name__)

NAME = "simulate"
HELP = "write pass-off runs of the built-in three-shaft turbofan simulator to an MCAP recording"

_BED_RE = re.compile(r"^[A-Za-z0-9_.-]+$")
MAX_RUNS = 100


def add_arguments(p: argparse.ArgumentParser) -> None:
    from simulator.campaign import FAULTS

    p.add_argument("--runs", type=int, default=3, metavar="N", help="number of runs (default 3)")
    p.add_argument("--seed", type=int, default=0, metavar="S", help="random seed (default 0)")
    p.add_argument("--out", required=True, metavar="REC.mcap", help="output recording")
    p.add_argument(
        "--fault", choices=FAULTS, default=None, help="inject a fault into the last run"
    )
    p.add_argument(
        "--fault-seed",
        type=int,
        default=None,
        metavar="F",
        help="with --fault: draw the fault's onset (OC and time) from seed F (default: from --seed)",
    )
    p.add_argument(
        "--fault-size",
        type=float,
        default=None,
        metavar="X",
        help="with --fault: scale the fault's magnitude by X > 0 (default 1 = nominal): "
        "imbalance adds X x 0.9 x the base imbalance of plane 1; stiffness lowers the 0.95 "
        "mode's stiffness by X x 10 %% over 20 s (X < 10); drift ramps yB by X x 0.5 mm/s "
        "per minute; stuck-sensor ignores it",
    )
    p.add_argument(
        "--schedule",
        default=None,
        metavar="S.toml",
        help="run the OCs of this contract schedule (INTERFACE.md section 4; switch \"nB\"; "
        "speeds 2600-9800 rpm, in test order) instead of the built-in 12; each [[oc]] may add "
        "plateau = nominal plateau length in s (default 40) and rate = nominal transition rate "
        "in rpm/s (default 90). The sidecar REC.schedule.toml is then this schedule",
    )
    p.add_argument(
        "--noise-scale",
        type=float,
        default=1.0,
        metavar="X",
        help="multiply every channel's sensor noise sigma (absolute and relative part) by X > 0 "
        "(default 1); recorded in the truth JSON",
    )
    p.add_argument("--bed", default="bed1", metavar="NAME", help="test-bed name (default bed1)")
    p.add_argument(
        "--plateau-scale",
        type=float,
        default=1.0,
        metavar="X",
        help="scale the nominal plateau lengths (default 1; smaller gives shorter runs)",
    )
    p.add_argument(
        "--skip",
        type=int,
        default=0,
        metavar="K",
        help="simulate all runs but write only those after the first K (same engine history)",
    )
    p.add_argument(
        "--channels",
        default=None,
        metavar="LIST",
        help="publish only these channels, comma-separated (default: all 21 of the contract "
        "and the 3 order phases yA_ph, yB_ph, yC_ph)",
    )
    p.add_argument(
        "--no-phase",
        action="store_true",
        help="leave out the order phases yA_ph, yB_ph, yC_ph (a test bed without once-per-rev "
        "reference); the other channels are the same either way",
    )
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")


def _channels(arg: str | None, phase: bool) -> tuple[str, ...] | None:
    from node.contract import PHASE_CHANNELS, SENSOR_CHANNELS

    if arg is None:
        return None
    known = SENSOR_CHANNELS + (PHASE_CHANNELS if phase else ())
    names = tuple(c.strip() for c in arg.split(",") if c.strip())
    unknown = [c for c in names if c not in known]
    if unknown or not names or len(set(names)) != len(names):
        without = " (--no-phase leaves out the phases)" if not phase else ""
        raise OrdervibError(
            f"--channels must be distinct names among {','.join(known)}{without}, got {arg!r}"
        )
    return names


def _check(args: argparse.Namespace) -> None:
    if not 1 <= args.runs <= MAX_RUNS:
        raise OrdervibError(f"--runs must be between 1 and {MAX_RUNS}, got {args.runs}")
    if args.seed < 0:
        raise OrdervibError(f"--seed must be >= 0, got {args.seed}")
    if args.fault_seed is not None and (args.fault is None or args.fault_seed < 0):
        raise OrdervibError("--fault-seed needs --fault and must be >= 0")
    if args.fault_size is not None and (
        args.fault is None or not (math.isfinite(args.fault_size) and args.fault_size > 0)
    ):
        raise OrdervibError("--fault-size needs --fault and must be > 0 and finite")
    if args.fault == "stiffness" and args.fault_size is not None and args.fault_size >= 10.0:
        raise OrdervibError(
            f"--fault-size must be < 10 for a stiffness fault (no stiffness left), "
            f"got {args.fault_size:g}"
        )
    if not _BED_RE.match(args.bed):
        raise OrdervibError(f"--bed must be letters, digits, '_', '-' or '.', got {args.bed!r}")
    if not 0.05 <= args.plateau_scale <= 10.0:
        raise OrdervibError(f"--plateau-scale must be between 0.05 and 10, got {args.plateau_scale}")
    if not (math.isfinite(args.noise_scale) and args.noise_scale > 0):
        raise OrdervibError(f"--noise-scale must be > 0 and finite, got {args.noise_scale:g}")
    if not 0 <= args.skip < args.runs:
        raise OrdervibError(f"--skip must be between 0 and runs - 1, got {args.skip}")
    inputs = [args.schedule] if args.schedule else []
    check_output(args.out, "--out", suffix=".mcap", inputs=inputs)


def run(args: argparse.Namespace) -> int:
    _check(args)
    channels = _channels(args.channels, not args.no_phase)
    from simulator.campaign import simulate_campaign
    from simulator.export import write_recording, write_sidecars
    from simulator.schedule import load_sim_schedule

    schedule = None if args.schedule is None else load_sim_schedule(args.schedule)

    start = time.perf_counter()
    campaign = simulate_campaign(
        args.runs,
        args.seed,
        args.fault,
        args.plateau_scale,
        args.fault_seed,
        fault_size=1.0 if args.fault_size is None else args.fault_size,
        schedule=schedule,
        noise_scale=args.noise_scale,
        phase=not args.no_phase,
    )
    progress = Progress(NAME, log)
    with replacing(args.out) as part:
        count = write_recording(
            campaign, part, args.bed, args.seed, args.skip, progress, channels=channels
        )
    schedule_path, truth_path = write_sidecars(
        campaign, args.out, args.bed, args.seed, args.skip, channels
    )
    log.info(
        "simulate: %d runs, %d messages -> %s (+ %s, %s) in %.1f s",
        args.runs - args.skip, count, args.out, os.path.basename(schedule_path),
        os.path.basename(truth_path), time.perf_counter() - start,
    )
    return 0
