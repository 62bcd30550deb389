"""The simulated engine: its three rotor models and its seed-dependent build.

One ``Engine`` is one physical engine (fixed modal properties, a base
imbalance per shaft); what changes from run to run is drawn in ``campaign``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from simulator.rotor import Mode, Shaft

# IP shaft (yB): a broad low mode and the two resonances of the dissertation,
# cold at 8350 and 9650 rpm; hot (metal ~300 °C) at about 0.83 and 0.955 of 9800 rpm.
IP_SHAFT = Shaft(
    speed="nB",
    out="yB",
    modes=(
        Mode(rpm=4500.0, zeta=0.20, g=(0.6, 0.6), h=0.3, kappa=2.0e-4, tau=1.5),
        Mode(rpm=8350.0, zeta=0.05, g=(1.0, 0.7), h=1.0, kappa=2.0e-4, tau=1.0),
        Mode(rpm=9650.0, zeta=0.03, g=(0.45, -0.55), h=0.3, kappa=2.0e-4, tau=1.2),
    ),
    residual=1.0e-6,
)
# LP shaft (yA): fan mode near 0.82 of the top LP speed.
LP_SHAFT = Shaft(
    speed="nA",
    out="yA",
    modes=(
        Mode(rpm=1500.0, zeta=0.15, g=(0.5, 0.4), h=0.2, kappa=1.0e-4, tau=2.0),
        Mode(rpm=2750.0, zeta=0.06, g=(1.0, 0.5), h=0.6, kappa=1.0e-4, tau=1.5),
    ),
    residual=2.0e-5,
)
# HP shaft (yC): a mode inside the running range and one above it.
HP_SHAFT = Shaft(
    speed="nC",
    out="yC",
    modes=(
        Mode(rpm=11700.0, zeta=0.04, g=(1.0, 0.6), h=0.8, kappa=2.5e-4, tau=0.8),
        Mode(rpm=15000.0, zeta=0.05, g=(0.6, -0.8), h=0.3, kappa=2.5e-4, tau=0.8),
    ),
    residual=2.0e-7,
)
SHAFTS = (LP_SHAFT, IP_SHAFT, HP_SHAFT)

# Imbalance scale per shaft (mm of modal displacement per unit participation).
UNBALANCE_SCALE = {"yA": 2.4e-3, "yB": 1.3e-3, "yC": 3.0e-4}
BOW_SCALE = {"yA": 1.5e-3, "yB": 3.0e-3, "yC": 8.0e-4}  # max bow after a hot shutdown, mm


@dataclass(frozen=True)
class Engine:
    """One engine's fixed properties."""

    unbalance: dict[str, np.ndarray]  # per amplitude channel: (2,) complex base imbalance, mm
    bow_max: dict[str, float]  # per amplitude channel, mm


def build_engine(rng: np.random.Generator) -> Engine:
    """Draw an engine: base imbalance of each plane (magnitude x0.7-1.3, random phase)."""
    unbalance = {}
    bow = {}
    for shaft in SHAFTS:
        mag = UNBALANCE_SCALE[shaft.out] * rng.uniform(0.7, 1.3, size=2)
        unbalance[shaft.out] = mag * np.exp(1j * rng.uniform(0, 2 * np.pi, size=2))
        bow[shaft.out] = BOW_SCALE[shaft.out] * rng.uniform(0.8, 1.2)
    return Engine(unbalance=unbalance, bow_max=bow)
