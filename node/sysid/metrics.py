"""Fit metrics of section 4.4: eps_td (also pooled over segments), eps_fd (eq. 4.39) and MAC; R^2."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np


def _error_energy(pairs: Iterable[tuple[np.ndarray, np.ndarray]]) -> tuple[float, float]:
    """(sum ||y - yhat||^2, sum ||y||^2) over (y, yhat) pairs of matching shapes."""
    pairs = list(pairs)
    num = sum(float(np.sum((y - p) ** 2)) for y, p in pairs)
    den = sum(float(np.sum(y ** 2)) for y, _ in pairs)
    return num, den


def eps_td(Y: np.ndarray, Yhat: np.ndarray) -> float:
    """Relative time-domain error sqrt(sum ||y - yhat||^2 / sum ||y||^2); Y, Yhat (K, p).

    >>> eps_td(np.array([3.0, 4.0]), np.array([3.0, 4.5]))
    0.1
    """
    Y = np.asarray(Y, float)
    Yhat = np.asarray(Yhat, float)
    if Y.shape != Yhat.shape:
        raise ValueError(f"shapes differ: {Y.shape} vs {Yhat.shape}")
    num, den = _error_energy([(Y, Yhat)])
    if den == 0:
        raise ValueError("reference signal is identically zero")
    return float(np.sqrt(num / den))


def pooled_eps(pairs: Iterable[tuple[np.ndarray, np.ndarray]]) -> float:
    """eps_td pooled over several segments (y, yhat): inf if any prediction is not finite
    or the reference is zero.

    >>> y = np.array([3.0, 4.0])
    >>> pooled_eps([(y, y), (y, y + 0.5)]) == eps_td(np.r_[y, y], np.r_[y, y + 0.5])
    True
    """
    num, den = _error_energy(pairs)
    if not np.isfinite(num) or den == 0:
        return float("inf")
    return float(np.sqrt(num / den))


def pooled_r2(pairs: Iterable[tuple[np.ndarray, np.ndarray]]) -> float:
    """Coefficient of determination 1 - sum ||y - yhat||^2 / sum ||y - mean(y)||^2 pooled over
    segments (y, yhat), the mean over every y; nan without spread, -inf for a non-finite prediction.

    >>> y = np.array([1.0, 2.0, 3.0])
    >>> pooled_r2([(y, y)]), pooled_r2([(y, np.full(3, 2.0))])
    (1.0, 0.0)
    """
    pairs = list(pairs)
    if not pairs:
        return float("nan")
    mean = float(np.mean(np.concatenate([np.ravel(y) for y, _ in pairs])))
    num, _ = _error_energy(pairs)
    _, den = _error_energy([(y - mean, y) for y, _ in pairs])
    if den == 0:
        return float("nan")
    return float(1.0 - num / den) if np.isfinite(num) else float("-inf")


def eps_fd(H: np.ndarray, Hhat: np.ndarray) -> float:
    """Relative frequency-domain error over frequency points; H, Hhat (L, p, m) complex."""
    H = np.asarray(H)
    Hhat = np.asarray(Hhat)
    if H.shape != Hhat.shape:
        raise ValueError(f"shapes differ: {H.shape} vs {Hhat.shape}")
    return float(np.sqrt(np.sum(np.abs(H - Hhat) ** 2) / np.sum(np.abs(H) ** 2)))


def mac(Phi1: np.ndarray, Phi2: np.ndarray) -> np.ndarray:
    """Modal assurance criterion matrix between mode-shape columns: (p, r1), (p, r2) -> (r1, r2)."""
    P1 = np.asarray(Phi1)
    P2 = np.asarray(Phi2)
    num = np.abs(P1.conj().T @ P2) ** 2
    den = np.outer(np.sum(np.abs(P1) ** 2, axis=0), np.sum(np.abs(P2) ** 2, axis=0))
    return num / den
