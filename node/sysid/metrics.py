"""Fit metrics of section 4.4: eps_td, eps_fd (eq. 4.39) and MAC."""

from __future__ import annotations

import numpy as np


def eps_td(Y: np.ndarray, Yhat: np.ndarray) -> float:
    """Relative time-domain error sqrt(sum ||y - yhat||^2 / sum ||y||^2); Y, Yhat (K, p)."""
    Y = np.asarray(Y, float)
    Yhat = np.asarray(Yhat, float)
    if Y.shape != Yhat.shape:
        raise ValueError(f"shapes differ: {Y.shape} vs {Yhat.shape}")
    den = np.sum(Y ** 2)
    if den == 0:
        raise ValueError("reference signal is identically zero")
    return float(np.sqrt(np.sum((Y - Yhat) ** 2) / den))


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
