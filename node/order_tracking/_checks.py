"""Input validation shared by the order trackers; every failure is a ValueError."""

from __future__ import annotations

import numpy as np


def check_fs(fs: float) -> float:
    """Sampling rate in Hz: finite and > 0."""
    try:
        value = float(fs)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"fs must be a number in Hz, got {fs!r}") from exc
    if not np.isfinite(value) or value <= 0.0:
        raise ValueError(f"fs must be finite and > 0 Hz, got {fs!r}")
    return value


def check_signal(x: object, name: str = "x", min_len: int = 4) -> np.ndarray:
    """1-D finite float signal of at least ``min_len`` samples."""
    arr = np.asarray(x, dtype=float)
    if arr.ndim != 1:
        raise ValueError(f"{name} must be 1-D with shape (K,), got shape {arr.shape}")
    if arr.size < min_len:
        raise ValueError(f"{name} is too short: {arr.size} samples, need at least {min_len}")
    if not np.all(np.isfinite(arr)):
        bad = int(np.count_nonzero(~np.isfinite(arr)))
        raise ValueError(f"{name} contains {bad} NaN/inf value(s)")
    return arr


def check_orders(orders: object, distinct: bool = True) -> np.ndarray:
    """Non-empty 1-D array of finite, positive (and, if asked, distinct) orders."""
    arr = np.atleast_1d(np.asarray(orders, dtype=float))
    if arr.ndim != 1 or arr.size == 0:
        raise ValueError(f"orders must be a non-empty 1-D sequence, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)) or np.any(arr <= 0.0):
        raise ValueError(f"orders must be finite and > 0, got {arr.tolist()}")
    if distinct and np.unique(arr).size != arr.size:
        raise ValueError(f"orders must be distinct, got {arr.tolist()}")
    return arr


def check_rpm(rpm: object, k: int, n_orders: int | None = None,
              positive: bool = True) -> np.ndarray:
    """Speed in rev/min, shape (K,) or, if ``n_orders`` is given, also (K, n_orders)."""
    arr = np.asarray(rpm, dtype=float)
    shapes = [(k,)] + ([(k, n_orders)] if n_orders is not None else [])
    if arr.shape not in shapes:
        want = " or ".join(str(s) for s in shapes)
        raise ValueError(f"rpm must have shape {want} (same length as x), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        bad = int(np.count_nonzero(~np.isfinite(arr)))
        raise ValueError(f"rpm contains {bad} NaN/inf value(s)")
    if positive and np.any(arr <= 0.0):
        raise ValueError(f"rpm must be > 0 everywhere, minimum is {arr.min():g}")
    return arr


def check_below_nyquist(orders: np.ndarray, rpm: np.ndarray, fs: float) -> None:
    """Every order frequency (Hz) must stay below fs/2."""
    f_rot = np.abs(rpm) / 60.0
    f_max = f_rot.max(axis=0) * orders if f_rot.ndim == 2 else f_rot.max() * orders
    worst = int(np.argmax(f_max))
    if f_max[worst] >= fs / 2.0:
        raise ValueError(
            f"order {orders[worst]:g} reaches {f_max[worst]:g} Hz, at or above the "
            f"Nyquist frequency fs/2 = {fs / 2:g} Hz"
        )


def check_distinct_tracks(orders: np.ndarray, rpm: np.ndarray) -> None:
    """Two orders whose frequency histories coincide cannot be told apart."""
    freq = rpm * orders[None, :] if rpm.ndim == 2 else rpm[:, None] * orders[None, :]
    for i in range(orders.size):
        for j in range(i + 1, orders.size):
            if np.allclose(freq[:, i], freq[:, j], rtol=1e-12, atol=0.0):
                raise ValueError(
                    f"orders {i} and {j} have identical frequency histories "
                    "(same order on the same speed reference); they cannot be separated"
                )
