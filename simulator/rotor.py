"""Modal rotor dynamics of one shaft: the tracked order-1 vector (amplitude mm/s peak, phase).

The standard unbalance response of a rotor with a few modes. Mode m has a critical speed
w_m (rad/s; softening with the metal temperature and with a stiffness fault), a damping
ratio zeta_m and a signed participation phi_m at the shaft's sensor. The shaft's order-1
velocity at speed W (rad/s) is one forcing vector times the sum of the modal receptances:

    v(W) = W * G(W) * (W**2 U + w_b**2 B),   G(W) = sum_m phi_m / (w_m**2 - W**2 + 2j zeta_m w_m W)

(+ a mass-line residual of the modes above the range in G). U is the run's complex imbalance
(mm), B the complex thermal bow (mm), acting like a runout: its force does not grow with
speed, so it weighs w_b**2 / W**2 against the imbalance (w_b: the shaft's first cold
critical). In r_m = W / w_m each mode's term is phi_m r_m**2 / (1 - r_m**2 + 2j zeta_m r_m)
/ w_m**2: its amplitude peaks at r_m ~ 1 and its phase lag grows by 180 degrees through it,
and nowhere else (the participations alternate in sign, so the modes add without an
anti-resonance between them).

Envelope dynamics: a mode's complex envelope settles in 1 / (zeta_m w_m) = 20-100 ms, far
faster than a ramp crosses its half-power band (seconds), so each sample takes the steady
response (a quasi-steady sweep). What lags is the vibration unit's order tracker: a
tracking filter that smooths the complex order with a first-order lag of TAU_TRACKER
seconds; the tracked amplitude is the modulus of the tracked vector and the tracked phase
its phase lag. On a ramp of rate dN/dt the tracked curve trails the steady one by about
dN/dt * TAU_TRACKER in speed (run-up: the peak shows above the critical; coast-down: below).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from node.contract.vector import order_lags
from simulator.lag import lag

T_REF = 15.0  # metal temperature at which the modes have their cold critical speed, °C
TAU_TRACKER = 1.0  # order tracker: first-order lag of the complex order, s
TRACKER_RANGE = (0.5, 2.0)  # s: the lags drawn per engine where asked (``tracker="drawn"``)


@dataclass(frozen=True)
class Mode:
    """One rotor mode (cold values)."""

    rpm: float  # critical speed at T_REF, as a shaft speed in rpm
    zeta: float  # damping ratio
    phi: float  # signed participation at the shaft's sensor (imbalance and bow alike)
    kappa: float  # stiffness loss per kelvin of metal temperature above T_REF, 1/K


@dataclass(frozen=True)
class Shaft:
    """The rotor model of one shaft's order-1 vector."""

    speed: str  # speed channel, e.g. "nB"
    out: str  # amplitude channel, e.g. "yB"
    modes: tuple[Mode, ...]
    residual: float  # mass-line residual of the modes above the range, per (rad/s)^2 like phi / w^2

    @property
    def bow_rpm(self) -> float:
        """w_b as rpm: the first cold critical (the bow's force is that of an imbalance there)."""
        return min(m.rpm for m in self.modes)


def rad_s(rpm: np.ndarray | float) -> np.ndarray:
    """Shaft speed in rad/s from rpm."""
    return np.asarray(rpm) * (2.0 * np.pi / 60.0)


def stiffness_factor(mode: Mode, metal: np.ndarray | float, stiffness: np.ndarray | float = 1.0
                     ) -> np.ndarray:
    """Stiffness of a mode relative to its cold value, for metal temperature (°C) and a fault factor."""
    k = np.asarray(stiffness) * (1.0 - mode.kappa * (np.asarray(metal) - T_REF))
    return np.clip(k, 0.2, None)


def mode_frequency(mode: Mode, metal: np.ndarray | float, stiffness: np.ndarray | float = 1.0
                   ) -> np.ndarray:
    """Critical speed (rad/s) of a mode: the cold one times sqrt(stiffness factor)."""
    return rad_s(mode.rpm) * np.sqrt(stiffness_factor(mode, metal, stiffness))


def critical_rpm(mode: Mode, metal: np.ndarray | float, stiffness: np.ndarray | float = 1.0
                 ) -> np.ndarray:
    """Critical speed (rpm) of a mode at metal temperature (°C) and fault stiffness factor."""
    return mode.rpm * np.sqrt(stiffness_factor(mode, metal, stiffness))


def receptance(shaft: Shaft, w_shaft: np.ndarray, w_modes: list[np.ndarray]) -> np.ndarray:
    """G(W) (K,) complex: the sum of the modal receptances and the residual.

    w_shaft: (K,) rad/s; w_modes: one (K,) array of critical speeds (rad/s) per mode.
    """
    g: np.ndarray = np.full(len(w_shaft), shaft.residual, dtype=complex)
    for mode, wm in zip(shaft.modes, w_modes, strict=True):
        g += mode.phi / (wm**2 - w_shaft**2 + 2j * mode.zeta * wm * w_shaft)
    return g


def order(
    shaft: Shaft,
    speed_rpm: np.ndarray,
    metal: np.ndarray,
    unbalance: np.ndarray,
    bow: np.ndarray,
    stiffness: dict[int, np.ndarray] | None = None,
) -> np.ndarray:
    """Steady complex order-1 velocity (mm/s) before the order tracker, shape (K,).

    speed_rpm, metal (°C): (K,); unbalance, bow: (K,) complex mm (the run's imbalance, the
    thermal bow); stiffness: optional per-mode stiffness factor (K,) (faults).
    """
    w = rad_s(np.clip(speed_rpm, 0.0, None))
    w_modes = [mode_frequency(m, metal, 1.0 if stiffness is None or i not in stiffness
                              else stiffness[i]) for i, m in enumerate(shaft.modes)]
    w_bow = float(rad_s(shaft.bow_rpm))
    return w * receptance(shaft, w, w_modes) * (w**2 * unbalance + w_bow**2 * bow)


def tracked(total: np.ndarray, tau: float = TAU_TRACKER) -> np.ndarray:
    """The order tracker's vector (K,) complex: ``total`` (K,) through a first-order lag of tau s."""
    return lag(total, tau, 0.0)


def tracked_amplitude(vector: np.ndarray) -> np.ndarray:
    """Tracked order-1 amplitude (mm/s peak), (K,): the modulus of the tracked vector (K,)."""
    return np.abs(vector)


def tracked_phase(vector: np.ndarray) -> np.ndarray:
    """Tracked order-1 phase lag (degrees, in [-180, 180)), (K,), of the tracked vector (K,).

    A response ``A cos(W t - phi)`` with the once-per-rev mark at ``W t = 0`` has the complex
    order ``A exp(-1j phi)`` and the phase ``phi``, which grows by about 180 degrees through
    each critical speed. ``order_lags``: NaN where the vector is 0 (shaft at rest; a unit gives
    no phase there).

    >>> tracked_phase(tracked(np.full(400, 2.0 * np.exp(-1j * np.pi / 3))))[-1].round(6)
    np.float64(60.0)
    """
    return order_lags(vector)
