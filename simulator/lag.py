"""First-order lags on the 40 Hz grid, vectorised with ``scipy.signal.lfilter``."""

from __future__ import annotations

import numpy as np
from scipy.signal import lfilter

from simulator.schedule import DT


def lag(u: np.ndarray, tau: float, y0: complex | float | None = None) -> np.ndarray:
    """First-order lag ``tau dy/dt = u - y`` (exact for u held over a sample).

    u: (K,) or (K, n) real or complex input, time-major; tau in seconds;
    y0: state before the first sample (default: u[0], i.e. starting settled).
    Returns an array of u's shape.
    """
    a = float(np.exp(-DT / tau))
    u = np.asarray(u)
    start = u[0] if y0 is None else np.broadcast_to(np.asarray(y0, dtype=u.dtype), u[0].shape)
    zi = (a * start)[np.newaxis, ...] if u.ndim > 1 else np.atleast_1d(a * start)
    y, _ = lfilter([1.0 - a], [1.0, -a], u, axis=0, zi=zi)
    return y


def lag_varying(u: np.ndarray, tau: np.ndarray, y0: float) -> np.ndarray:
    """First-order lag with a time constant that changes at known switch times.

    tau: (K,) seconds, piecewise constant; solved segment by segment (few segments).
    """
    out = np.empty_like(u, dtype=float)
    edges = np.flatnonzero(np.diff(tau)) + 1
    bounds = np.concatenate([[0], edges, [len(u)]])
    state = y0
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        out[a:b] = lag(u[a:b], float(tau[a]), state)
        state = out[b - 1]
    return out
