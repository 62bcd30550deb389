"""An order's 1x vector and its phase (``docs/contract.md`` section 1, the ``<order>_ph`` channels).

A phase channel gives the tracked order-1 phase as a lag from the shaft's once-per-rev
mark, in degrees, in [-180, 180). The 1x vector of amplitude A and phase lag phi is
A exp(-j phi): a lag turns it clockwise (90 degrees points it down, -Im). The node,
training, the views, the simulator and the benchmarks take the vector and the lag from here.
"""

from __future__ import annotations

import cmath
import math

import numpy as np

NAN_VECTOR = complex(math.nan, math.nan)  # the 1x vector of a sample without amplitude or phase


def order_vector(amplitude: float, phase_deg: float) -> complex:
    """An order's 1x vector from its amplitude and phase lag (degrees): A exp(-j phase); NaN if either is.

    >>> order_vector(2.0, 90.0)
    (1.2246467991473532e-16-2j)
    """
    if not math.isfinite(phase_deg):  # (math.cos raises on inf; the payload rule lets none through)
        return NAN_VECTOR
    rad = math.radians(phase_deg)
    return amplitude * complex(math.cos(rad), -math.sin(rad))


def lag_degrees(v: complex) -> float:
    """The phase lag (degrees, in [-180, 180)) of a 1x vector A exp(-j phase); NaN for NaN or 0.

    >>> lag_degrees(order_vector(2.0, 90.0)), lag_degrees(-1 + 0j), lag_degrees(0j)
    (90.0, -180.0, nan)
    """
    if not (cmath.isfinite(v) and v != 0):
        return math.nan
    lag = -math.degrees(cmath.phase(v))
    return lag - 360.0 if lag >= 180.0 else lag


def order_vectors(amplitude: np.ndarray, phase_deg: np.ndarray) -> np.ndarray:
    """(K,) complex 1x vectors A exp(-j phase) (the phase a lag: ``Trajectory.z``); NaN where either is.

    >>> order_vectors(np.array([2.0, 1.0]), np.array([90.0, np.nan])).round(12)
    array([ 0. -2.j, nan+nanj])
    """
    rad = np.radians(phase_deg)
    out: np.ndarray = amplitude * (np.cos(rad) - 1j * np.sin(rad))
    return np.where(np.isfinite(out), out, NAN_VECTOR)


def order_lags(v: np.ndarray) -> np.ndarray:
    """(K,) phase lags (degrees, in [-180, 180)) of 1x vectors v (K,) A exp(-j phase): ``lag_degrees``
    over an array, to the bit; NaN where a vector is NaN or 0 (no phase).

    >>> order_lags(np.array([order_vector(2.0, 90.0), -1 - 0j, 0j, NAN_VECTOR])).tolist()
    [90.0, -180.0, nan, nan]
    """
    v = np.asarray(v, dtype=complex)
    lag = -np.degrees(np.angle(v))
    lag = np.where(lag >= 180.0, lag - 360.0, lag)
    return np.where(np.isfinite(v) & (v != 0), lag, np.nan)


def wrap_degrees(x: np.ndarray) -> np.ndarray:
    """Angles (degrees) wrapped into [-180, 180), the shape of x.

    >>> wrap_degrees(np.array([180.0, -180.0, 190.0, -190.5, 359.0])).tolist()
    [-180.0, -180.0, -170.0, 169.5, -1.0]
    """
    out = np.mod(np.asarray(x, dtype=float) + 180.0, 360.0) - 180.0
    return np.where(out >= 180.0, out - 360.0, out)  # np.mod gives 360 for tiny negative inputs
