"""Input checks shared by the identification methods: one clear one-line error each."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import sparse


def as_matrix(a: object, name: str, cols: int | None = None, min_rows: int = 0,
              min_cols: int = 0, allow_1d: bool = True) -> np.ndarray:
    """Return ``a`` as a finite float64 (K, c) array; a 1-D array becomes (K, 1) if ``allow_1d``.

    Raises ValueError naming ``name`` (one line) on sparse or complex input, values that are
    not real numbers (TypeError for objects that are not numbers or strings), a wrong number
    of dimensions, columns (or fewer than ``min_cols``), too few rows, or non-finite values.
    """
    if sparse.issparse(a):
        raise ValueError(f"{name} is a sparse {type(a).__name__}: sparse input is not supported, "
                         f"pass a dense array (e.g. .toarray())")
    try:
        raw = np.asarray(a)
        is_complex = np.iscomplexobj(raw)
        arr = raw if is_complex else raw.astype(float, copy=False)
    except (TypeError, ValueError) as exc:  # kept: TypeError for objects that are no numbers
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise type(exc)(f"{name} must be an array of real numbers ({first})") from None
    if is_complex:
        raise ValueError(f"Complex data not supported in {name}: pass real arrays (e.g. the real "
                         f"and imaginary parts as separate channels)")
    if arr.ndim == 1:
        if not allow_1d:
            raise ValueError(f"{name} must be a 2-D time-major (samples, channels) array, got "
                             f"shape {arr.shape}: use .reshape(-1, 1) for one channel")
        arr = arr[:, None]
    if arr.ndim != 2:
        raise ValueError(f"{name} must be a time-major (samples, channels) array, got shape {arr.shape}")
    if cols is not None and arr.shape[1] != cols:
        raise ValueError(f"{name} must have {cols} column(s), got shape {arr.shape}")
    if arr.shape[1] < min_cols:
        raise ValueError(f"{name} has {arr.shape[1]} feature(s) (shape={arr.shape}) while a "
                         f"minimum of {min_cols} is required (one column per channel)")
    if arr.shape[0] < min_rows:
        raise ValueError(f"{name} has {arr.shape[0]} samples; at least {min_rows} are needed")
    if not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[0]
        raise ValueError(f"{name} holds NaN or inf (first at sample {bad[0]}, channel {bad[1]})")
    return arr


def as_trajectories(Y: object, U: object | None, name_y: str = "Y", name_u: str = "U",
                    strict_outputs: bool = False) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Normalise (Y, U) or lists of them into matching lists of (K_i, p) and (K_i, m).

    ``U=None`` means no inputs (m = 0). Every trajectory must agree on p and m.
    ``strict_outputs``: Y must be 2-D with at least one column (scikit-learn's rule for the
    data ``fit`` learns from); otherwise a 1-D Y is one channel.
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
        ya = as_matrix(y, f"{name_y}{tag}", min_cols=int(strict_outputs),
                       allow_1d=not strict_outputs)
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
