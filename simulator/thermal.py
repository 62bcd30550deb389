"""Rotor thermal state: metal temperature, cooling during a shutdown, thermal bow.

Metal (disc) temperature lags the gas temperature that heats it (minutes).
During a shutdown it cools towards ambient. A rotor left standing hot bends
(hotter on top): the bow grows during the first minutes after shutdown and
fades over hours as the rotor soaks evenly (dissertation, appendix A.2.5: the
shutdown time is a history parameter). Once running, the bow straightens as
the rotor heats evenly, with the cumulative energy int (nB / NB_TOP) dt.
"""

from __future__ import annotations

import numpy as np

from simulator.lag import lag
from simulator.schedule import DT

TAU_METAL = 240.0  # metal temperature lag behind its driving gas temperature, s
TAU_COOL_METAL = 1.5 * 3600.0  # cooling of the rotor during a shutdown, s
TAU_BOW_RISE = 5.0 * 60.0  # bow builds up after shutdown, s
TAU_BOW_DECAY = 3.0 * 3600.0  # bow fades as the standing rotor soaks, s
ENERGY_HEAL = 90.0  # full-speed-equivalent seconds that halve the bow e-fold, s


def metal_temperature(drive: np.ndarray, start: float) -> np.ndarray:
    """Metal temperature (°C), shape (K,), from the driving gas temperature (K,)."""
    return lag(drive, TAU_METAL, start)


def cooled(temperature: float, ambient: float, shutdown: float, tau: float) -> float:
    """Temperature (°C) after ``shutdown`` seconds of cooling towards ``ambient``."""
    return ambient + (temperature - ambient) * float(np.exp(-shutdown / tau))


def bow_at_start(bow_max: float, shutdown: float) -> float:
    """Bow magnitude (mm) at a restart after ``shutdown`` seconds (0 for a cold engine)."""
    if not np.isfinite(shutdown):
        return 0.0
    rise = 1.0 - np.exp(-shutdown / TAU_BOW_RISE)
    return float(bow_max * rise * np.exp(-shutdown / TAU_BOW_DECAY))


def bow_decay(nb_norm: np.ndarray) -> np.ndarray:
    """Fraction of the start bow left, shape (K,), from nB / NB_TOP (K,)."""
    energy = np.cumsum(np.clip(nb_norm, 0.0, None)) * DT
    return np.exp(-energy / ENERGY_HEAL)
