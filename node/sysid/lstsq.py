"""Least squares through a truncated pseudo-inverse (the dissertation's beta)."""

from __future__ import annotations

import numpy as np


def truncated_lstsq(R: np.ndarray, T: np.ndarray, rcond: float,
                    scale_columns: bool = True, ridge: float = 0.0) -> tuple[np.ndarray, int]:
    """Solve min ||R W - T||_F (+ ridge s_max^2 ||W||_F^2) with singular values of R below
    ``rcond * s_max`` cut.

    Args:
        R: (K, q) regressors, one row per snapshot.
        T: (K, r) targets.
        rcond: relative singular-value tolerance (beta in eq. 4.13).
        scale_columns: scale every regressor to unit norm before the SVD, so
            that the cut does not depend on the units of states and inputs.
        ridge: Tikhonov weight relative to the largest squared singular value (0: none):
            each kept direction is shrunk by s^2 / (s^2 + ridge s_max^2).

    Returns:
        W (q, r) and the rank kept.
    """
    if not rcond > 0:
        raise ValueError(f"rcond must be positive, got {rcond}")
    if not ridge >= 0:
        raise ValueError(f"ridge must be >= 0, got {ridge}")
    scale = np.linalg.norm(R, axis=0) if scale_columns else np.ones(R.shape[1])
    scale[scale == 0] = 1.0
    Rs = R / scale
    if Rs.shape[0] > 2 * Rs.shape[1]:  # tall: SVD of the triangular factor only
        Q, Rt = np.linalg.qr(Rs)
        Ut, s, Vh = np.linalg.svd(Rt)
        QtT = Ut.T @ (Q.T @ T)
    else:
        Ut, s, Vh = np.linalg.svd(Rs, full_matrices=False)
        QtT = Ut.T @ T
    if s.size == 0 or s[0] == 0:
        return np.zeros((R.shape[1], T.shape[1])), 0
    keep = int(np.sum(s > rcond * s[0]))
    if ridge > 0:
        W = (Vh[:keep].T * (s[:keep] / (s[:keep] ** 2 + ridge * s[0] ** 2))) @ QtT[:keep]
    else:
        W = (Vh[:keep].T / s[:keep]) @ QtT[:keep]
    return W / scale[:, None], keep


def pod_basis(X: np.ndarray, rank: int | None) -> np.ndarray | None:
    """Leading ``rank`` right singular vectors of snapshots X (K, n) as (n, rank), or None."""
    if rank is None or rank >= X.shape[1]:
        return None
    if rank < 1:
        raise ValueError(f"rank must be at least 1, got {rank}")
    _, _, Vh = np.linalg.svd(X, full_matrices=False)
    return Vh[:rank].T
