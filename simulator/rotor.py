"""Modal rotor dynamics of one shaft: tracked order-1 amplitude in mm/s (peak).

Each mode m has a natural frequency w_m (softening with the metal temperature
and with a stiffness fault), damping ratio zeta_m, and participation factors
g_m (per imbalance plane) and h_m (thermal bow). Its steady order-1 velocity at
shaft speed W (rad/s) is

    q_m = W * (W**2 * sum_p g_mp U_p + w_m**2 h_m b) / (w_m**2 - W**2 + 2j zeta_m w_m W)

(U_p complex imbalance, mm; b complex bow, mm). The complex envelope of each
mode lags q_m with a first-order lag tau_m (slow-time envelope dynamics plus
the order tracker's bandwidth), so sweeping through a resonance depends on the
sweep rate. The tracked amplitude is |sum_m q_m + residual| passed through the
order tracker's smoothing lag; the tracked phase is the phase lag (degrees, from the
once-per-rev mark) of the same complex order passed through a lag of the same time
constant (a tracking filter of that bandwidth smooths the complex order).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from node.contract.vector import wrap_degrees
from simulator.lag import lag

T_REF = 15.0  # metal temperature at which the modes have their cold frequency, °C
TAU_TRACKER = 0.3  # order-tracker smoothing of the amplitude, s


@dataclass(frozen=True)
class Mode:
    """One rotor mode (cold values)."""

    rpm: float  # natural frequency at T_REF, as a shaft speed in rpm
    zeta: float  # damping ratio
    g: tuple[float, float]  # participation of imbalance planes 1 and 2
    h: float  # participation of the thermal bow
    kappa: float  # stiffness loss per kelvin of metal temperature above T_REF, 1/K
    tau: float  # envelope lag, s


@dataclass(frozen=True)
class Shaft:
    """The rotor model of one shaft's order-1 amplitude."""

    speed: str  # speed channel, e.g. "nB"
    out: str  # amplitude channel, e.g. "yB"
    modes: tuple[Mode, ...]
    residual: float  # mass-line residual (higher modes, casing), mm/s per (rad/s)^2 * |U| scale


def rad_s(rpm: np.ndarray | float) -> np.ndarray:
    """Shaft speed in rad/s from rpm."""
    return np.asarray(rpm) * (2.0 * np.pi / 60.0)


def mode_frequency(mode: Mode, metal: np.ndarray, stiffness: np.ndarray | float = 1.0) -> np.ndarray:
    """Natural frequency (rad/s) of a mode for metal temperature (°C) and a stiffness factor."""
    k = stiffness * (1.0 - mode.kappa * (metal - T_REF))
    return rad_s(mode.rpm) * np.sqrt(np.clip(k, 0.2, None))


def steady_modal(
    mode: Mode, w_shaft: np.ndarray, w_mode: np.ndarray, unbalance: np.ndarray, bow: np.ndarray
) -> np.ndarray:
    """Steady complex velocity (mm/s) of one mode; all arrays (K,), unbalance (K, 2) complex."""
    force = w_shaft**2 * (unbalance @ np.asarray(mode.g, dtype=complex)) + w_mode**2 * mode.h * bow
    return w_shaft * force / (w_mode**2 - w_shaft**2 + 2j * mode.zeta * w_mode * w_shaft)


def order(
    shaft: Shaft,
    speed_rpm: np.ndarray,
    metal: np.ndarray,
    unbalance: np.ndarray,
    bow: np.ndarray,
    stiffness: dict[int, np.ndarray] | None = None,
    steady: bool = False,
) -> np.ndarray:
    """Complex order-1 velocity (mm/s) before the order tracker, shape (K,).

    The sum of the lagged modal envelopes and the mass-line residual. speed_rpm,
    metal (°C), bow (complex mm): (K,); unbalance: (K, 2) complex mm; stiffness:
    optional per-mode stiffness factor (K,) (faults); steady: without the envelope lags
    (each sample's steady response).
    """
    w = rad_s(np.clip(speed_rpm, 0.0, None))
    total: np.ndarray = np.zeros(len(w), dtype=complex)
    for i, mode in enumerate(shaft.modes):
        k = 1.0 if stiffness is None or i not in stiffness else stiffness[i]
        q_ss = steady_modal(mode, w, mode_frequency(mode, metal, k), unbalance, bow)
        total += q_ss if steady else lag(q_ss, mode.tau, 0.0)
    total += shaft.residual * w**3 * unbalance.sum(axis=1)
    return total


def tracked_amplitude(total: np.ndarray) -> np.ndarray:
    """Tracked order-1 amplitude (mm/s peak), (K,), of the complex order ``total`` (K,)."""
    return lag(np.abs(total), TAU_TRACKER, 0.0)


def tracked_phase(total: np.ndarray) -> np.ndarray:
    """Tracked order-1 phase lag (degrees, in [-180, 180)), (K,), of the complex order (K,).

    The order smoothed by the tracker (complex lag of TAU_TRACKER, the amplitude's
    smoothing) and its angle negated: a response ``A cos(W t - phi)`` with the
    once-per-rev mark at ``W t = 0`` has the complex order ``A exp(-1j phi)`` and the
    phase ``phi``, which grows by about 180 degrees through a resonance. 0 where the
    order is 0 (shaft at rest; a unit gives no phase there).

    >>> tracked_phase(np.full(400, 2.0 * np.exp(-1j * np.pi / 3)))[-1].round(6)
    np.float64(60.0)
    """
    return wrap_degrees(-np.degrees(np.angle(lag(total, TAU_TRACKER, 0.0))))
