"""Residues of given poles fitted to a sample's data by output-error least squares.

A parametric ROM keeps a few matched modes of each sample's identified model; their residues,
copied from that model, are the identification's (equation error, which output noise biases),
and the modes it drops (noise modes, fast poles) leave a part of the response unexplained.
Given the kept poles, the response to the measured inputs is linear in the residues and D: they
are the least-squares fit of the outputs on the inputs filtered by each pole, regressors that
hold no output noise (unbiased), fitted to the response the ROM is judged on. Each run adds
each pole's free response (its unknown initial state).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.signal import lfilter

RCOND = 1e-12  # relative singular value (of the column-scaled regressors) below which a direction is dropped


def fit(z: np.ndarray, pair: np.ndarray, runs: Sequence[tuple[np.ndarray, np.ndarray]],
        ) -> tuple[np.ndarray, np.ndarray] | None:
    """Discrete residues (r, p, m) and D (p, m) of the poles z (r,) (``pair`` (r,): z and its
    conjugate, residues R and conj(R); else a real pole) that fit ``runs`` ((Y (K, p), U (K, m))
    pairs): H(z) = sum_j R_j / (z - z_j) + D. None when a pole is on or outside the unit circle or
    the data give no fit."""
    if not len(z) or np.any(np.abs(z) >= 1.0) or not runs or runs[0][1].shape[1] == 0:
        return None
    m = runs[0][1].shape[1]
    rows, targets = [], []
    for r, (Y, U) in enumerate(runs):
        K = len(U)
        cols = []
        for zj, pj in zip(z, pair):  # forced response: x_{k+1} = z x_k + u_k, y += R x (+ conj)
            x = lfilter([0.0, 1.0], [1.0, -zj], U.astype(complex), axis=0)
            cols += [2 * x.real, -2 * x.imag] if pj else [x.real]
        cols.append(U)
        k = np.arange(K)[:, None]
        free = np.hstack([part for zj, pj in zip(z, pair)
                          for part in ((zj ** k).real, (zj ** k).imag)[:1 + int(pj)]])
        blocks = [np.zeros((K, free.shape[1]))] * len(runs)
        blocks[r] = free  # this run's own initial state
        rows.append(np.hstack([*cols, *blocks]))
        targets.append(Y)
    Phi, Yall = np.vstack(rows), np.vstack(targets)
    if not (np.all(np.isfinite(Phi)) and np.all(np.isfinite(Yall))):
        return None
    norm = np.linalg.norm(Phi, axis=0)
    norm[norm == 0] = 1.0
    theta = np.linalg.lstsq(Phi / norm, Yall, rcond=RCOND)[0] / norm[:, None]
    R = np.empty((len(z), Yall.shape[1], m), dtype=complex)
    i = 0
    for j, pj in enumerate(pair):
        R[j] = (theta[i:i + m] + 1j * theta[i + m:i + 2 * m]).T if pj else theta[i:i + m].T
        i += 2 * m if pj else m
    return R, theta[i:i + m].T
