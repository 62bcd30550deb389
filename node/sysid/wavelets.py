"""MODWT for WDMD pseudo-states, two ways (Percival & Walden conventions).

* ``modwt_mra``: the dissertation's multiresolution analysis (eq. 4.22, 4.26):
  circular, any length, components D_1..D_J, S_J that sum to the signal. Each
  value at time k depends on samples after k (the synthesis filter is
  anti-causal), so it cannot run online.
* ``CausalMODWT``: the MODWT coefficients W_1..W_J, V_J computed by causal
  filtering only (the a-trous pyramid with each level's past kept as state).
  The value at sample k uses samples up to k only, so a live node computes it
  sample by sample; batch and step give identical numbers. Before the first
  sample the signal is taken as constant at its first value (edge extension).

MODWT filters are PyWavelets' reconstruction filters divided by sqrt(2):
for Haar h = (1/2, -1/2), g = (1/2, 1/2), so W_j + V_j = V_{j-1} and the
causal coefficients of every level also sum to the signal.
"""

from __future__ import annotations

import numpy as np
import pywt


def modwt_filters(wavelet: str) -> tuple[np.ndarray, np.ndarray]:
    """(h, g): MODWT wavelet and scaling filters of ``wavelet`` (length L each)."""
    try:
        w = pywt.Wavelet(wavelet)
    except ValueError as exc:
        raise ValueError(f"unknown wavelet {wavelet!r} (PyWavelets discrete wavelets only)") from exc
    if not w.orthogonal:
        raise ValueError(f"wavelet {wavelet!r} is not orthogonal; MODWT needs an orthogonal wavelet")
    return np.asarray(w.rec_hi) / np.sqrt(2.0), np.asarray(w.rec_lo) / np.sqrt(2.0)


def _level_responses(h: np.ndarray, g: np.ndarray, levels: int,
                     K: int) -> tuple[list[np.ndarray], np.ndarray]:
    """DFT (length K) of the equivalent level filters: H_1..H_J and G_J."""
    f = np.arange(K) / K
    def resp(filt: np.ndarray, scale: int) -> np.ndarray:
        # periodised, upsampled filter: sum_l filt_l exp(-i 2 pi f scale l)
        return np.exp(-2j * np.pi * np.outer(f * scale, np.arange(filt.size))) @ filt
    Hs, G = [], np.ones(K, dtype=complex)
    for j in range(1, levels + 1):
        s = 2 ** (j - 1)
        Hs.append(resp(h, s) * G)
        G = resp(g, s) * G
    return Hs, G


def modwt_mra(Y: np.ndarray, levels: int, wavelet: str = "haar") -> np.ndarray:
    """Circular MODWT multiresolution analysis of each column of Y (K, p).

    Returns (K, p, levels + 1): details D_1..D_J then the smooth S_J; the
    components of each channel sum to it (eq. 4.22).
    """
    Y = np.asarray(Y, dtype=float)
    if Y.ndim == 1:
        Y = Y[:, None]
    K = Y.shape[0]
    h, g = modwt_filters(wavelet)
    Hs, G = _level_responses(h, g, levels, K)
    F = np.fft.fft(Y, axis=0)
    comps = [np.fft.ifft(np.abs(Hj)[:, None] ** 2 * F, axis=0).real for Hj in Hs]
    comps.append(np.fft.ifft(np.abs(G)[:, None] ** 2 * F, axis=0).real)
    return np.stack(comps, axis=2)


class CausalMODWT:
    """Causal MODWT filter bank over p channels, stepped in blocks or sample by sample.

    State (bounded memory): for level j the last (L - 1) * 2**(j-1) samples of
    V_{j-1}, per channel. ``transform`` of a block continues from the state.

    Args:
        levels: J >= 1.
        wavelet: PyWavelets orthogonal wavelet name.
        n_channels: p.
    """

    def __init__(self, levels: int, wavelet: str = "haar", n_channels: int = 1) -> None:
        if int(levels) != levels or levels < 1:
            raise ValueError(f"levels must be a positive integer, got {levels}")
        self.levels = int(levels)
        self.wavelet = wavelet
        self.n_channels = int(n_channels)
        self.h, self.g = modwt_filters(wavelet)
        self._past: list[np.ndarray] | None = None  # per level, (span_j, p)

    @property
    def n_features(self) -> int:
        """J + 1 coefficients per channel."""
        return self.levels + 1

    def spans(self) -> list[int]:
        L = self.h.size
        return [(L - 1) * 2 ** (j - 1) for j in range(1, self.levels + 1)]

    def reset(self, first: np.ndarray | None = None) -> None:
        """Forget the past; with ``first`` (p,), pretend the signal was constant at it."""
        if first is None:
            self._past = None
            return
        self._past = self._constant_past(first)

    def _constant_past(self, first: np.ndarray) -> list[np.ndarray]:
        first = np.asarray(first, dtype=float).reshape(self.n_channels)
        # a constant signal c has V_j = c for Haar-like filters with sum(g) = 1
        return [np.tile(first, (s, 1)) for s in self.spans()]

    def transform(self, Y: np.ndarray) -> np.ndarray:
        """Coefficients of the block Y (K, p): returns (K, p, J + 1) = W_1..W_J, V_J.

        Continues from the current state (edge-extended from Y[0] if none).
        """
        Y = np.asarray(Y, dtype=float)
        if Y.ndim == 1:
            Y = Y[:, None]
        if Y.shape[1] != self.n_channels:
            raise ValueError(f"expected {self.n_channels} channel(s), got shape {Y.shape}")
        K = Y.shape[0]
        if self._past is None:
            if K == 0:
                return np.zeros((0, self.n_channels, self.n_features))
            self._past = self._constant_past(Y[0])
        past = self._past
        out = np.empty((K, self.n_channels, self.n_features))
        V = Y
        L = self.h.size
        for j, span in enumerate(self.spans()):
            s = 2 ** j
            ext = np.concatenate([past[j], V], axis=0)  # (span + K, p)
            W = np.zeros((K, self.n_channels))
            Vn = np.zeros((K, self.n_channels))
            for lag in range(L):  # fixed summation order: batch == step, bit for bit
                seg = ext[span - lag * s: span - lag * s + K]
                W += self.h[lag] * seg
                Vn += self.g[lag] * seg
            past[j] = ext[ext.shape[0] - span:] if span else ext[:0]
            out[:, :, j] = W
            V = Vn
        out[:, :, self.levels] = V
        return out

    def step(self, y: np.ndarray) -> np.ndarray:
        """One sample y (p,) -> coefficients (p, J + 1)."""
        return self.transform(np.asarray(y, dtype=float).reshape(1, self.n_channels))[0]


def causal_modwt(Y: np.ndarray, levels: int, wavelet: str = "haar") -> np.ndarray:
    """Causal MODWT coefficients of Y (K, p) from rest at Y[0]: (K, p, J + 1)."""
    Y = np.asarray(Y, dtype=float)
    if Y.ndim == 1:
        Y = Y[:, None]
    return CausalMODWT(levels, wavelet, Y.shape[1]).transform(Y)
