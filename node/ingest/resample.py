"""One channel's samples on the 40 Hz grid of the sensor clock: pure numerics, no I/O.

The grid is the node's absolute one (``node.contract.slotting``): slot k is the time k / FS,
seconds since the epoch. A slot between two source samples at most ``max_gap`` s apart gets
the linear interpolation between them; a phase (degrees) is interpolated along the shorter
arc between the two (so 170 and -170 give 180, not 0) and wrapped into [-180, 180). A slot
next to a source dropout (NaN) is NaN (a null sample); a slot on a source sample takes that
sample as it is. Slots outside the source's span, or between two samples further apart than
``max_gap``, get nothing: the source had no data there (a gap of 60 s or more therefore stays
a gap, and separates two runs as the contract says). No smoothing, no anti-alias filter: the
contract's channels are slow (speeds, tracked order amplitudes, temperatures, pressures).

>>> k, x = to_grid(np.array([100.0, 100.1]), np.array([0.0, 4.0]), max_gap=1.0)
>>> (k / FS).tolist(), x.round(9).tolist()
([100.0, 100.025, 100.05, 100.075, 100.1], [0.0, 1.0, 2.0, 3.0, 4.0])
>>> k, x = to_grid(np.array([100.0, 100.05]), np.array([170.0, -170.0]), max_gap=1.0, phase=True)
>>> x.round(9).tolist()
[170.0, -180.0, -170.0]
"""

from __future__ import annotations

import math

import numpy as np

from node.contract import FS
from node.contract.vector import wrap_degrees


def to_grid(t: np.ndarray, v: np.ndarray, *, max_gap: float, phase: bool = False,
            fs: float = FS) -> tuple[np.ndarray, np.ndarray]:
    """The samples (t (n,) s, strictly increasing; v (n,), NaN for a dropout) on the grid:
    (k (m,) int64 ascending slots, x (m,) float64 values, NaN for null). See the module."""
    t = np.asarray(t, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    if len(t) == 0:
        return np.empty(0, np.int64), np.empty(0)
    cuts = np.flatnonzero(np.diff(t) > max_gap) + 1
    ks, xs = [], []
    for a, b in zip(np.concatenate([[0], cuts]).tolist(), np.concatenate([cuts, [len(t)]]).tolist(),
                    strict=True):
        k, x = _stretch(t[a:b], v[a:b], phase, fs)
        ks.append(k)
        xs.append(x)
    return np.concatenate(ks), np.concatenate(xs)


def grid_size(t: np.ndarray, *, max_gap: float, fs: float = FS) -> int:
    """An upper bound of the slots ``to_grid`` gives (exact but for one slot per stretch),
    computed without building them: checked before the arrays are made.

    >>> grid_size(np.array([100.0, 100.1, 200.0, 201.0]), max_gap=1.0)
    46
    """
    t = np.asarray(t, dtype=np.float64)
    if len(t) == 0:
        return 0
    cuts = np.flatnonzero(np.diff(t) > max_gap) + 1
    first, last = t[np.concatenate([[0], cuts])], t[np.concatenate([cuts - 1, [len(t) - 1]])]
    return int(np.sum(np.ceil((last - first) * fs) + 1))


def _stretch(t: np.ndarray, v: np.ndarray, phase: bool, fs: float) -> tuple[np.ndarray, np.ndarray]:
    """``to_grid`` of samples no further apart than the largest gap interpolated over."""
    k = np.arange(math.ceil(t[0] * fs) - 1, math.floor(t[-1] * fs) + 2, dtype=np.int64)
    tau = k / fs  # the very floats the recording's payloads carry
    keep = (tau >= t[0]) & (tau <= t[-1])
    k, tau = k[keep], tau[keep]
    i = np.clip(np.searchsorted(t, tau, side="right") - 1, 0, max(len(t) - 2, 0))
    exact = t[i] == tau
    if len(t) > 1:
        j = i + 1
        exact_j = t[j] == tau
        frac = (tau - t[i]) / (t[j] - t[i])
        step = v[j] - v[i]
        if phase:
            step = wrap_degrees(step)
        x = v[i] + frac * step
        x = np.where(exact_j, v[j], x)
    else:
        x = np.full(len(k), np.nan)
    x = np.where(exact, v[i], x)
    if phase:
        x = wrap_degrees(x)
    return k, x
