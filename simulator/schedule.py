"""The pass-off schedule: 12 operating conditions (OCs) on the IP shaft speed ``nB``.

Also builds one run's speed command (rpm, on the 40 Hz grid) with run-to-run
variation of the transition rates and plateau lengths, reads another schedule
from a contract TOML file (``load_sim_schedule``: docs/contract.md section 4, plus the
optional keys ``plateau`` and ``rate`` per OC) and writes the schedule as the
contract's TOML.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import tomllib
from dataclasses import dataclass

import numpy as np

from node.contract import FS
from node.contract.errors import OrdervibError

DT = 1.0 / FS


@dataclass(frozen=True)
class OC:
    """One operating condition: the transition into ``speed`` and its steady plateau."""

    name: str
    speed: float  # plateau speed of nB, rpm
    plateau: float  # nominal plateau length, s
    rate: float  # nominal transition rate, rpm/s


# Test order as in the dissertation (OC2a ... OC13), not monotonic: OC8 steps back,
# OC12 and OC13 come down. OC7 and OC10 sit on the two nB resonances (about 0.83 and
# 0.95 of the top speed, 9800 rpm) once the rotor is warm.
DEFAULT_OCS: tuple[OC, ...] = (
    OC("OC2a", 3900.0, 40.0, 90.0),
    OC("OC3", 4700.0, 60.0, 70.0),
    OC("OC4", 5600.0, 25.0, 90.0),
    OC("OC5", 6500.0, 25.0, 100.0),
    OC("OC6", 7300.0, 30.0, 100.0),
    OC("OC7", 8100.0, 40.0, 80.0),
    OC("OC8", 7700.0, 25.0, 90.0),
    OC("OC9", 8700.0, 30.0, 100.0),
    OC("OC10", 9350.0, 35.0, 70.0),
    OC("OC11", 9800.0, 35.0, 60.0),
    OC("OC12", 9000.0, 25.0, 90.0),
    OC("OC13", 5200.0, 30.0, 150.0),
)

IDLE_NB = 2600.0  # ground idle, rpm
TOP_NB = 9800.0  # top IP speed (gaspath.NB_TOP, the normalisation of the maps), rpm
SWITCH = "nB"
TOLERANCE = 0.02
# An OC of a schedule file without ``plateau`` / ``rate`` keys gets these (s, rpm/s).
DEFAULT_PLATEAU = 40.0
DEFAULT_RATE = 90.0
PLATEAU_RANGE = (1.0, 3600.0)  # allowed nominal plateau lengths, s
RATE_RANGE = (1.0, 1000.0)  # allowed nominal transition rates, rpm/s
BUILT_IN = "built-in"

# Fixed segments around the OCs, seconds.
START_RAMP = 20.0  # starter + light-up: 0 -> idle
IDLE_BEFORE = 15.0
IDLE_AFTER = 15.0
RUNDOWN = 30.0  # fuel off: command decays to 0, recorded until the spools have stopped
RUNDOWN_TAU = 5.0


@dataclass(frozen=True)
class Segment:
    """An OC as actually run: times in seconds from the run start."""

    name: str
    speed: float
    transition_start: float
    steady_start: float
    end: float


@dataclass(frozen=True)
class Profile:
    """One run's nB speed command on the 40 Hz grid and the OC timing."""

    t: np.ndarray  # (K,) seconds from run start
    command: np.ndarray  # (K,) nB command, rpm
    segments: tuple[Segment, ...]
    fuel_off: float  # time of fuel cut, s from run start


@dataclass(frozen=True)
class SimSchedule:
    """The OCs a campaign runs, in test order, with the steady tolerance and where they came from.

    source: ``"built-in"`` (DEFAULT_OCS) or the path of the schedule file.
    """

    ocs: tuple[OC, ...] = DEFAULT_OCS
    tolerance: float = TOLERANCE
    source: str = BUILT_IN

    @property
    def built_in(self) -> bool:
        return self.source == BUILT_IN

    def digest(self) -> str:
        """sha256 of what the simulation uses (OCs with their timing, tolerance), not the file's text."""
        body = {"switch": SWITCH, "tolerance": self.tolerance,
                "oc": [[o.name, o.speed, o.plateau, o.rate] for o in self.ocs]}
        return hashlib.sha256(json.dumps(body, sort_keys=True).encode()).hexdigest()

    def truth(self) -> dict:
        """The truth JSON's record of the schedule: origin, digest, the OCs with nominal timing."""
        return {
            "source": self.source,
            "sha256": self.digest(),
            "switch": SWITCH,
            "tolerance": self.tolerance,
            "oc": [{"name": o.name, "speed": o.speed, "plateau_s": o.plateau, "rate_rpm_s": o.rate}
                   for o in self.ocs],
        }

    def toml(self) -> str:
        """The schedule sidecar: the built-in one as always; a file's OCs with their timing keys."""
        if self.built_in:
            return schedule_toml(self.ocs)
        origin = " ".join(os.path.basename(self.source).split())  # one comment line
        return schedule_toml(self.ocs, self.tolerance, timing=True, origin=origin)


BUILT_IN_SCHEDULE = SimSchedule()


def _number(d: dict, key: str, where: str) -> float | None:
    if key not in d:
        return None
    v = d[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise OrdervibError(f"{where}: {key} must be a finite number, got {v!r}")
    return float(v)


def load_sim_schedule(path: str | os.PathLike) -> SimSchedule:
    """Read a contract schedule (docs/contract.md section 4) for the simulator; one-line errors.

    Each ``[[oc]]`` may add ``plateau`` (nominal plateau length, s; default DEFAULT_PLATEAU)
    and ``rate`` (nominal transition rate into it, rpm/s; default DEFAULT_RATE); the node's
    schedule loader ignores them. The switch must be ``nB`` and every speed within the
    simulated engine's range, idle (IDLE_NB) to the top speed (TOP_NB).
    """
    from node.contract.schedule import Schedule

    path = str(path)
    try:
        with open(path, "rb") as f:
            raw = tomllib.load(f)
    except FileNotFoundError:
        raise OrdervibError(f"schedule file not found: {path}") from None
    except IsADirectoryError:
        raise OrdervibError(f"schedule file is a directory: {path}") from None
    except tomllib.TOMLDecodeError as exc:
        raise OrdervibError(f"{path}: not valid TOML ({exc})") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise OrdervibError(f"{path}: cannot read the schedule ({exc})") from None
    if not isinstance(raw.get("oc"), list) or not all(isinstance(o, dict) for o in raw["oc"]):
        raise OrdervibError(f"{path}: not a pass-off schedule: no [[oc]] tables")
    try:  # the node's own checks: names, speeds, tolerance
        node_schedule = Schedule.from_dict(raw, path)
    except OrdervibError as exc:
        raise OrdervibError(str(exc) if path in str(exc) else f"{path}: {exc}") from None
    if node_schedule.switch != SWITCH:
        raise OrdervibError(f"{path}: switch is {node_schedule.switch!r}; the simulator runs its "
                            f"schedule on {SWITCH!r}")
    ocs = []
    for o, d in zip(node_schedule.ocs, raw["oc"], strict=True):
        where = f"{path}: OC {o.name!r}"
        if not IDLE_NB <= o.speed <= TOP_NB:
            raise OrdervibError(f"{where}: speed {o.speed:g} rpm is outside the simulated engine's "
                                f"range {IDLE_NB:g}-{TOP_NB:g} rpm (idle to top speed)")
        plateau = _number(d, "plateau", where)
        rate = _number(d, "rate", where)
        plateau = DEFAULT_PLATEAU if plateau is None else plateau
        rate = DEFAULT_RATE if rate is None else rate
        if not PLATEAU_RANGE[0] <= plateau <= PLATEAU_RANGE[1]:
            raise OrdervibError(f"{where}: plateau {plateau:g} s is outside "
                                f"{PLATEAU_RANGE[0]:g}-{PLATEAU_RANGE[1]:g} s")
        if not RATE_RANGE[0] <= rate <= RATE_RANGE[1]:
            raise OrdervibError(f"{where}: rate {rate:g} rpm/s is outside "
                                f"{RATE_RANGE[0]:g}-{RATE_RANGE[1]:g} rpm/s")
        ocs.append(OC(o.name, o.speed, plateau, rate))
    return SimSchedule(tuple(ocs), node_schedule.tolerance, path)


def fault_candidates(segments: tuple[Segment, ...]) -> list[Segment]:
    """The OCs a fault may start in: the middle of the test order.

    Positions ceil(n/3) .. n - ceil(n/4) - 1 of n OCs (the built-in 12: OC6..OC10), so the
    run has OCs before the fault (the run's own earlier behaviour) and after it; all OCs
    when that leaves none (n <= 2).
    """
    n = len(segments)
    mid = list(segments[math.ceil(n / 3): n - math.ceil(n / 4)])
    return mid or list(segments)


def make_profile(
    rng: np.random.Generator,
    ocs: tuple[OC, ...] = DEFAULT_OCS,
    plateau_scale: float = 1.0,
) -> Profile:
    """Draw one run's command: rates vary x0.6-1.7, plateaus x0.8-1.25 (times plateau_scale)."""
    knots_t = [0.0, START_RAMP, START_RAMP + IDLE_BEFORE]
    knots_v = [0.0, IDLE_NB, IDLE_NB]
    segments = []
    now, speed = knots_t[-1], IDLE_NB
    for oc in ocs:
        rate = oc.rate * rng.uniform(0.6, 1.7)
        ramp = max(abs(oc.speed - speed) / rate, 1.0)
        plateau = oc.plateau * plateau_scale * rng.uniform(0.8, 1.25)
        segments.append(Segment(oc.name, oc.speed, now, now + ramp, now + ramp + plateau))
        now += ramp + plateau
        speed = oc.speed
        knots_t += [now - plateau, now]
        knots_v += [oc.speed, oc.speed]
    down = abs(speed - IDLE_NB) / 150.0
    knots_t += [now + down, now + down + IDLE_AFTER]
    knots_v += [IDLE_NB, IDLE_NB]
    fuel_off = knots_t[-1]
    k_total = int(np.ceil((fuel_off + RUNDOWN) * FS))
    t = np.arange(k_total) * DT
    command = np.interp(t, knots_t, knots_v)
    after = t > fuel_off
    command[after] = IDLE_NB * np.exp(-(t[after] - fuel_off) / RUNDOWN_TAU)
    return Profile(t=t, command=command, segments=tuple(segments), fuel_off=fuel_off)


def schedule_toml(
    ocs: tuple[OC, ...] = DEFAULT_OCS,
    tolerance: float = TOLERANCE,
    timing: bool = False,
    origin: str | None = None,
) -> str:
    """The schedule in the contract's TOML form (docs/contract.md section 4).

    timing: also write each OC's nominal ``plateau`` (s) and ``rate`` (rpm/s), the
    simulator's extra keys (the node ignores them); origin: named in the header comment.
    """
    head = "# Pass-off schedule of the ordervib simulator (docs/contract.md section 4)"
    lines = [
        head + (f", from {origin}." if origin else "."),
        f'switch = "{SWITCH}"',
        f"tolerance = {tolerance!r}",
        "",
    ]
    for oc in ocs:
        lines += ["[[oc]]", f"name = {json.dumps(oc.name)}", f"speed = {oc.speed!r}"]
        if timing:
            lines += [f"plateau = {oc.plateau!r}", f"rate = {oc.rate!r}"]
        lines.append("")
    return "\n".join(lines)
