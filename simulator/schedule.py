"""The pass-off schedule: 12 operating conditions (OCs) on the IP shaft speed ``nB``.

Also builds one run's speed command (rpm, on the 40 Hz grid) with run-to-run
variation of the transition rates and plateau lengths, and writes the schedule
as the contract's TOML (INTERFACE.md section 4).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

FS = 40.0  # sample rate, Hz
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
SWITCH = "nB"
TOLERANCE = 0.02

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


def schedule_toml(ocs: tuple[OC, ...] = DEFAULT_OCS) -> str:
    """The schedule in the contract's TOML form (INTERFACE.md section 4)."""
    lines = [
        "# Pass-off schedule of the ordervib simulator (INTERFACE.md section 4).",
        f'switch = "{SWITCH}"',
        f"tolerance = {TOLERANCE}",
        "",
    ]
    for oc in ocs:
        lines += ["[[oc]]", f'name = "{oc.name}"', f"speed = {oc.speed:.1f}", ""]
    return "\n".join(lines)
