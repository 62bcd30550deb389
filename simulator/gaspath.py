"""Spools and gas path: speeds, temperatures, pressures, throttle and fuel.

Static maps of the normalised IP speed x = nB / NB_TOP followed by first-order
lags. All arrays are on the run's 40 Hz grid, shape (K,).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from simulator.lag import lag, lag_varying
from simulator.schedule import DT, IDLE_NB, TOP_NB

NB_TOP = TOP_NB  # top IP speed of the schedule, 9800 rpm (normalisation of the maps)
NA_TOP = 3300.0  # LP speed at NB_TOP, rpm
NC_TOP = 13200.0  # HP speed at NB_TOP, rpm

TAU_NB, TAU_NA, TAU_NC = 1.2, 2.5, 0.8  # spool lags behind the lever, s
RUNDOWN_TAU_NA, RUNDOWN_TAU_NC = 9.0, 3.0  # windmilling rundown after fuel cut, s

# Gas-path temperatures: T = T_amb + c0 + c1 * x**e, lagged by tau (s).
# tA is the controlled, fast one; tF and tI are cavity temperatures that lag.
TEMPS: dict[str, tuple[float, float, float, float]] = {
    #        c0     c1     e    tau
    "tA": (60.0, 480.0, 2.0, 1.5),
    "tB": (15.0, 160.0, 1.5, 6.0),
    "tC": (35.0, 390.0, 2.0, 8.0),
    "tD": (280.0, 690.0, 1.8, 3.0),
    "tE": (230.0, 440.0, 2.0, 12.0),
    "tF": (50.0, 270.0, 2.0, 90.0),
    "tG": (20.0, 65.0, 1.0, 25.0),
    "tH": (4.0, 38.0, 2.0, 4.0),
    "tI": (70.0, 340.0, 2.0, 150.0),
}
# Channels whose heat survives a shutdown (they start a run from the cooled state).
SLOW_TEMPS = ("tF", "tG", "tI")
TAU_COOL_GAS = 2.0 * 3600.0  # cooling of those cavities during a shutdown, s

# Pressures: p = p_amb * (1 + c1 * x**e), lagged by tau (s).
PRESSURES: dict[str, tuple[float, float, float]] = {
    "pA": (-0.04, 2.0, 0.3),
    "pB": (1.8, 2.0, 0.5),
    "pC": (24.0, 2.3, 0.7),
    "pD": (0.6, 2.0, 1.0),
}


@dataclass(frozen=True)
class Ambient:
    """Run-to-run ambient conditions."""

    temperature: float  # °C
    pressure: float  # kPa


def lever(command: np.ndarray) -> np.ndarray:
    """Throttle lever angle M2 (deg) for an nB command (rpm): 20° at idle, 85° at NB_TOP."""
    return np.where(
        command >= IDLE_NB,
        20.0 + 65.0 * (command - IDLE_NB) / (NB_TOP - IDLE_NB),
        20.0 * command / IDLE_NB,
    )


def spools(command: np.ndarray, fuel_off_index: int) -> dict[str, np.ndarray]:
    """Shaft speeds nA, nB, nC (rpm) following the nB command through lags."""
    nb = lag(command, TAU_NB, 0.0)
    x = np.clip(nb / NB_TOP, 0.0, None)
    na_ss = NA_TOP * x**1.6
    nc_ss = NC_TOP * x**0.55
    tau_a = np.where(np.arange(len(command)) < fuel_off_index, TAU_NA, RUNDOWN_TAU_NA)
    tau_c = np.where(np.arange(len(command)) < fuel_off_index, TAU_NC, RUNDOWN_TAU_NC)
    return {
        "nA": lag_varying(na_ss, tau_a, 0.0),
        "nB": nb,
        "nC": lag_varying(nc_ss, tau_c, 0.0),
    }


def gas_path(
    command: np.ndarray,
    nb: np.ndarray,
    ambient: Ambient,
    slow_start: dict[str, float],
) -> dict[str, np.ndarray]:
    """Temperatures tA..tI (°C), pressures pA..pD (kPa), fuel M1 (kg/s), lever M2 (deg).

    slow_start: the temperatures of SLOW_TEMPS at the start of the run (after cooling).
    """
    x = np.clip(nb / NB_TOP, 0.0, None)
    running = (nb > 0.05 * NB_TOP).astype(float)  # no combustion heat once stopped
    out: dict[str, np.ndarray] = {}
    for name, (c0, c1, e, tau) in TEMPS.items():
        target = ambient.temperature + running * (c0 + c1 * x**e)
        y0 = slow_start.get(name, ambient.temperature)
        out[name] = lag(target, tau, y0)
    for name, (c1, e, tau) in PRESSURES.items():
        out[name] = lag(ambient.pressure * (1.0 + c1 * x**e), tau, ambient.pressure)
    m2 = lever(command)
    # Fuel flow leads the speed: it follows the lever, with an acceleration spike.
    dm2 = np.gradient(m2, DT)
    xl = np.clip((m2 - 20.0) / 65.0, 0.0, None) * (1.0 - 0.265) + 0.265
    fuel = (0.08 + 2.1 * xl**2.8 + 0.004 * dm2) * (ambient.pressure / 101.325)
    fuel = np.where(command > 0.9 * IDLE_NB, fuel, 0.0)
    out["M1"] = lag(np.clip(fuel, 0.0, None), 0.3, 0.0)
    out["M2"] = m2
    return out


def metal_drive(gas: dict[str, np.ndarray]) -> np.ndarray:
    """Gas temperature that heats the IP rotor discs (°C): mix of the compressor and cavity air."""
    return 0.6 * gas["tC"] + 0.4 * gas["tA"]
