"""MS-DPCCA (dissertation eq. 3.3-3.10): multi-scale detrended partial cross-correlation.

Ranks candidate input channels by their intrinsic (partial) correlation with
the target at several time scales, with the influence of every other channel
removed. Used per OC to pick the model inputs (``--inputs auto``).
"""

from __future__ import annotations

import numpy as np

DEFAULT_SCALES = (10, 20, 40, 80, 160, 320)  # box sizes s, samples (0.25-8 s at 40 Hz)


def detrended_covariance(X: np.ndarray, s: int) -> np.ndarray:
    """F^2(s) of eq. 3.5 for all channel pairs: X (K, N) -> (N, N).

    Profiles (eq. 3.3) are detrended linearly in each of the K - s overlapping
    boxes of s + 1 samples (eq. 3.4). Computed in closed form: the residual
    Gram of a box is P'P - (Q'P)'(Q'P) with Q an orthonormal basis of
    {1, t}, and the box sums come from moving sums.
    """
    K, N = X.shape
    if s < 2 or s >= K:
        raise ValueError(f"scale {s} must be in [2, {K - 1}] for {K} samples")
    P = np.cumsum(X - X.mean(axis=0), axis=0)
    L = s + 1
    n_boxes = K - s
    # each sample k is in min(k+1, L, K-k, n_boxes) boxes
    k = np.arange(K)
    w = np.minimum.reduce([k + 1, np.full(K, L), K - k, np.full(K, n_boxes)]).astype(float)
    gram = (P * w[:, None]).T @ P
    t = np.arange(L, dtype=float)
    q0 = np.ones(L) / np.sqrt(L)
    q1 = t - t.mean()
    q1 /= np.linalg.norm(q1)
    # moving weighted sums over boxes: c_j[i] = sum_a q_j[a] P[i + a]
    from numpy.lib.stride_tricks import sliding_window_view
    win = sliding_window_view(P, L, axis=0)  # (n_boxes, N, L)
    c0 = win @ q0
    c1 = win @ q1
    resid = gram - c0.T @ c0 - c1.T @ c1
    return resid / (n_boxes * L)


def dpcca(X: np.ndarray, s: int) -> np.ndarray:
    """Partial detrended cross-correlation matrix at scale s (eq. 3.7-3.10): (N, N) in [-1, 1]."""
    F2 = detrended_covariance(X, s)
    d = np.sqrt(np.clip(np.diag(F2), 1e-300, None))
    rho = F2 / d[:, None] / d[None, :]
    C = np.linalg.pinv(rho, rcond=1e-10, hermitian=True)
    dc = np.sqrt(np.clip(np.abs(np.diag(C)), 1e-300, None))
    out = -C / dc[:, None] / dc[None, :]
    np.fill_diagonal(out, 1.0)
    return np.clip(out, -1.0, 1.0)


Term = tuple[np.ndarray, np.ndarray, int]  # one segment's share of rank_inputs: (cols, K x score, K)


def segment_term(X: np.ndarray, target_col: int, scales: tuple[int, ...] = DEFAULT_SCALES) -> Term | None:
    """One segment's share of :func:`rank_inputs`: the columns that vary in it, their mean
    |rho_DPCCA| with the target over the usable scales times the segment's length, and the
    length; None when the target is constant or no scale fits. Per segment and independent of
    the others, so cross-validation folds share them (``combine_terms``)."""
    sd = X.std(axis=0)
    live = sd > 1e-12 * (np.abs(X).max(axis=0) + 1e-300)
    if not live[target_col] or live.sum() < 2:
        return None
    cols = np.flatnonzero(live)
    Xl = (X[:, cols] - X[:, cols].mean(axis=0)) / sd[cols]
    t = int(np.flatnonzero(cols == target_col)[0])
    usable = [s for s in scales if 2 <= s < X.shape[0] // 4]
    if not usable:
        return None
    score = np.mean([np.abs(dpcca(Xl, s)[t]) for s in usable], axis=0)
    return cols, X.shape[0] * score, X.shape[0]


def combine_terms(terms: list[Term | None], n_channels: int, target_col: int) -> np.ndarray:
    """:func:`rank_inputs` from its segments' terms, summed in the order given: (N,) scores."""
    total = np.zeros(n_channels)
    weight = 0.0
    for term in terms:
        if term is None:
            continue
        cols, score, k = term
        total[cols] += score
        weight += k
    out = total / weight if weight else total
    out[target_col] = -np.inf
    return out


def rank_inputs(segments: list[np.ndarray], target_col: int,
                scales: tuple[int, ...] = DEFAULT_SCALES) -> np.ndarray:
    """Mean |rho_DPCCA(target, j)| over scales and segments, weighted by segment length.

    segments: list of (K_i, N) arrays (finite), column ``target_col`` the target.
    Returns (N,) scores (the target's own score is set to -inf). Channels that
    are constant in every segment score 0.
    """
    return combine_terms([segment_term(X, target_col, scales) for X in segments], segments[0].shape[1],
                         target_col)
