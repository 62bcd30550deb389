"""The simulated engine: its three rotor models and its seed-dependent build.

One ``Engine`` is one physical engine (fixed modal properties, a base
imbalance per shaft); what changes from run to run is drawn in ``campaign``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from simulator.rotor import TAU_TRACKER, TRACKER_RANGE, Mode, Shaft

# Participations alternate in sign from mode to mode, so the modes add without an
# anti-resonance between them: the phase lag grows by 180 degrees through each critical and
# stays put between them (tests/test_simulator.py checks it from cold to hot metal). The
# residual continues the pattern (the mass line of the modes above the range).
# IP shaft (yB): a low mode and the two resonances of the dissertation, cold at 8350 and
# 9650 rpm; hot (metal ~300 °C) at about 0.83 and 0.955 of 9800 rpm.
IP_SHAFT = Shaft(
    speed="nB",
    out="yB",
    modes=(
        Mode(rpm=4500.0, zeta=0.07, phi=0.6, kappa=2.0e-4),
        Mode(rpm=8350.0, zeta=0.035, phi=-1.0, kappa=2.0e-4),
        Mode(rpm=9650.0, zeta=0.03, phi=0.5, kappa=2.0e-4),
    ),
    residual=-5.0e-7,
)
# LP shaft (yA): fan mode near 0.82 of the top LP speed.
LP_SHAFT = Shaft(
    speed="nA",
    out="yA",
    modes=(
        Mode(rpm=1500.0, zeta=0.10, phi=0.5, kappa=1.0e-4),
        Mode(rpm=2750.0, zeta=0.06, phi=-1.0, kappa=1.0e-4),
    ),
    residual=5.0e-6,
)
# HP shaft (yC): a mode inside the running range and one above it.
HP_SHAFT = Shaft(
    speed="nC",
    out="yC",
    modes=(
        Mode(rpm=11700.0, zeta=0.04, phi=1.0, kappa=2.5e-4),
        Mode(rpm=15000.0, zeta=0.05, phi=-0.8, kappa=2.5e-4),
    ),
    residual=1.0e-7,
)
SHAFTS = (LP_SHAFT, IP_SHAFT, HP_SHAFT)

# Imbalance scale per shaft (mm of modal displacement per unit participation).
UNBALANCE_SCALE = {"yA": 2.4e-3, "yB": 1.3e-3, "yC": 3.0e-4}
BOW_SCALE = {"yA": 3.0e-3, "yB": 3.0e-3, "yC": 8.0e-4}  # max bow after a hot shutdown, mm


@dataclass(frozen=True)
class Engine:
    """One engine's fixed properties."""

    # per amplitude channel: (2,) complex base imbalance of two planes (e.g. two discs), mm;
    # the shaft's imbalance is their sum (every mode sees it alike)
    unbalance: dict[str, np.ndarray]
    bow_max: dict[str, float]  # per amplitude channel, mm
    shafts: tuple[Shaft, ...] = SHAFTS  # this engine's rotors (its modes scatter about SHAFTS')
    tracker_s: float = TAU_TRACKER  # its vibration unit's order-tracker lag, s

    def shaft(self, out: str) -> Shaft:
        """The rotor of amplitude channel ``out``."""
        return next(s for s in self.shafts if s.out == out)

    def modes_truth(self) -> dict[str, list[dict]]:
        """Per amplitude channel its modes (cold critical rpm, zeta, participation, kappa)."""
        return {s.out: [{"rpm_cold": round(m.rpm, 3), "zeta": round(m.zeta, 6), "phi": m.phi,
                         "kappa_per_K": m.kappa, "af": round(1.0 / (2.0 * m.zeta), 4)}
                        for m in s.modes] for s in self.shafts}


# Engine-to-engine scatter of the modes (build tolerances): critical speed x (1 + N(0, 1.5 %),
# clipped to +-3 %), damping ratio x U(0.8, 1.25).
CRITICAL_SCATTER = 0.015
DAMPING_SCATTER = (0.8, 1.25)


def scatter_modes(rng: np.random.Generator) -> tuple[Shaft, ...]:
    """One engine's rotors: SHAFTS with each mode's critical speed and damping drawn about theirs."""
    out = []
    for shaft in SHAFTS:
        modes = []
        for m in shaft.modes:
            f = 1.0 + float(np.clip(rng.normal(0.0, CRITICAL_SCATTER), -0.03, 0.03))
            modes.append(dataclasses.replace(m, rpm=m.rpm * f, zeta=m.zeta * rng.uniform(*DAMPING_SCATTER)))
        out.append(dataclasses.replace(shaft, modes=tuple(modes)))
    return tuple(out)


def drawn_tracker(seed: int) -> float:
    """An engine's order-tracker lag (s) drawn uniformly in TRACKER_RANGE from a stream of its
    own (seeded by the engine's seed alone: every other draw stays as it was)."""
    return float(np.random.default_rng(np.random.SeedSequence([seed, 0x7AC4])).uniform(*TRACKER_RANGE))


def build_engine(rng: np.random.Generator, modal_rng: np.random.Generator | None = None) -> Engine:
    """Draw an engine: base imbalance of each plane (magnitude x0.7-1.3, random phase).

    modal_rng: draws the engine's modes about the nominal ones (``scatter_modes``; default
    the nominal modes). A stream of its own, so the imbalance draws stay those of ``rng``.
    """
    unbalance = {}
    bow = {}
    for shaft in SHAFTS:
        mag = UNBALANCE_SCALE[shaft.out] * rng.uniform(0.7, 1.3, size=2)
        unbalance[shaft.out] = mag * np.exp(1j * rng.uniform(0, 2 * np.pi, size=2))
        bow[shaft.out] = BOW_SCALE[shaft.out] * rng.uniform(0.8, 1.2)
    shafts = SHAFTS if modal_rng is None else scatter_modes(modal_rng)
    return Engine(unbalance=unbalance, bow_max=bow, shafts=shafts)
