"""Input checks shared by the identification methods: one clear ValueError each."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def as_matrix(a: object, name: str, cols: int | None = None, min_rows: int = 0) -> np.ndarray:
    """Return ``a`` as a finite float64 (K, c) array; a 1-D array becomes (K, 1).

    Raises ValueError naming ``name`` on a wrong number of dimensions, columns,
    too few rows, or non-finite values.
    """
    arr = np.asarray(a, dtype=float)
    if arr.ndim == 1:
        arr = arr[:, None]
    if arr.ndim != 2:
        raise ValueError(f"{name} must be a time-major (samples, channels) array, got shape {arr.shape}")
    if cols is not None and arr.shape[1] != cols:
        raise ValueError(f"{name} must have {cols} column(s), got shape {arr.shape}")
    if arr.shape[0] < min_rows:
        raise ValueError(f"{name} has {arr.shape[0]} samples; at least {min_rows} are needed")
    if not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[0]
        raise ValueError(f"{name} holds NaN or inf (first at sample {bad[0]}, channel {bad[1]})")
    return arr


def as_trajectories(Y: object, U: object | None, name_y: str = "Y", name_u: str = "U",
                    ) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Normalise (Y, U) or lists of them into matching lists of (K_i, p) and (K_i, m).

    ``U=None`` means no inputs (m = 0). Every trajectory must agree on p and m.
    """
    many = isinstance(Y, (list, tuple))
    Ys: Sequence[object] = list(Y) if isinstance(Y, (list, tuple)) else [Y]
    if U is None:
        Us: Sequence[object | None] = [None] * len(Ys)
    else:
        if isinstance(U, (list, tuple)) != many:
            raise ValueError(f"{name_y} and {name_u} must both be arrays or both be lists")
        Us = list(U) if isinstance(U, (list, tuple)) else [U]
    if len(Ys) != len(Us):
        raise ValueError(f"{len(Ys)} output trajectories but {len(Us)} input trajectories")
    if not Ys:
        raise ValueError("no trajectories given")
    ys, us = [], []
    for i, (y, u) in enumerate(zip(Ys, Us)):
        tag = f"[{i}]" if many else ""
        ya = as_matrix(y, f"{name_y}{tag}")
        ua = np.zeros((ya.shape[0], 0)) if u is None else as_matrix(u, f"{name_u}{tag}")
        if ua.shape[0] != ya.shape[0]:
            raise ValueError(f"{name_y}{tag} has {ya.shape[0]} samples but {name_u}{tag} has {ua.shape[0]}")
        ys.append(ya)
        us.append(ua)
    p, m = ys[0].shape[1], us[0].shape[1]
    for i, (y, u) in enumerate(zip(ys, us)):
        if y.shape[1] != p or u.shape[1] != m:
            raise ValueError(f"trajectory {i} has {y.shape[1]} outputs and {u.shape[1]} inputs; "
                             f"trajectory 0 has {p} and {m}")
    return ys, us
