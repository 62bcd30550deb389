"""Output-error re-estimation of (B, D): the noise-robust estimator.

Plain least squares on noisy outputs is biased (errors in the regressors).
Given A and C, the free-run output of every trajectory is *linear* in B and
D (the initial states being fixed):

    y[k] = C A^k x0 + sum_{i<k} C A^(k-1-i) B u[i] + D u[k]

so minimising the free-run output error over (B, D) is a linear least-squares
problem. The regressors are built from the Markov parameters C A^i with FFT
convolutions: O(K p n log K) per input, no per-parameter simulation.
"""

from __future__ import annotations

import numpy as np
from scipy import signal


def markov_parameters(A: np.ndarray, C: np.ndarray, K: int) -> np.ndarray:
    """C A^i for i = 0..K-1, shape (K, p, n)."""
    p, n = C.shape
    H = np.empty((K, p, n))
    M = C.copy()
    for i in range(K):
        H[i] = M
        M = M @ A
    return H


def refit_bd(A: np.ndarray, C: np.ndarray, Ys: list[np.ndarray], Us: list[np.ndarray],
             x0s: list[np.ndarray], rcond: float = 1e-10) -> tuple[np.ndarray, np.ndarray]:
    """(B, D) minimising sum over trajectories of ||Y - free_run(A, B, C, D, x0, U)||^2.

    Args:
        A: (n, n), C: (p, n) fixed.
        Ys, Us: per-trajectory outputs (K_i, p) and inputs (K_i, m).
        x0s: per-trajectory initial states (n,).
        rcond: relative singular-value cut of the (B, D) regression.

    Returns:
        B (n, m), D (p, m).
    """
    n, p, m = A.shape[0], C.shape[0], Us[0].shape[1]
    K_max = max(y.shape[0] for y in Ys)
    H = markov_parameters(A, C, K_max).reshape(K_max, p * n)
    rows_x, rows_y = [], []
    for Y, U, x0 in zip(Ys, Us, x0s):
        K = Y.shape[0]
        free = np.einsum("kpn,n->kp", H[:K].reshape(K, p, n), x0)
        blocks = []
        for j in range(m):
            u_shift = np.concatenate([[0.0], U[:K - 1, j]])  # u[k-1]: the response starts one step later
            conv = signal.fftconvolve(H[:K], u_shift[:, None], mode="full", axes=0)[:K]
            blocks.append(conv.reshape(K, p, n))
        # design: rows (k, output), columns: B[:, j] entries for each j, then D[out, j]
        cols_b = [b.reshape(K * p, n) for b in blocks]  # (K p, n) each
        eye_p = np.eye(p)
        cols_d = [(U[:, j][:, None, None] * eye_p[None]).reshape(K * p, p) for j in range(m)]
        rows_x.append(np.hstack(cols_b + cols_d))
        rows_y.append((Y - free).reshape(K * p))
    X = np.vstack(rows_x)
    y = np.concatenate(rows_y)
    scale = np.linalg.norm(X, axis=0)
    scale[scale == 0] = 1.0
    theta, *_ = np.linalg.lstsq(X / scale, y, rcond=rcond)
    theta = theta / scale
    B = theta[: n * m].reshape(m, n).T
    D = theta[n * m:].reshape(m, p).T
    return B, D
