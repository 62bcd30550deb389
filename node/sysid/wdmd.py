"""Wavelet-based DMD (eq. 4.26-4.36): MODWT coefficients of the outputs as pseudo-states."""

from __future__ import annotations

from enum import StrEnum

import numpy as np

from node.sysid.base import LinearDMD
from node.sysid.wavelets import CausalMODWT, modwt_mra


class Components(StrEnum):
    """Which MODWT quantities form the pseudo-state."""

    CAUSAL = "causal"  # coefficients W_1..W_J, V_J from past samples only (online)
    MRA = "mra"        # the dissertation's MRA details D_1..D_J, S_J (look ahead)


class WDMD(LinearDMD):
    """WDMD with ``levels`` (J) of the ``wavelet`` MODWT: state dimension p (J + 1).

    Args:
        levels: J.
        wavelet: PyWavelets orthogonal wavelet (Haar by default).
        components: ``"causal"`` (default, computable sample by sample) or
            ``"mra"`` (eq. 4.26, circular and non-causal; for comparison).
        rcond, rank, estimator, dt, warmup, seed_window: as :class:`LinearDMD`.

    Pseudo-state order: channel-major, [W_1 .. W_J, V_J] of output 1, then
    output 2, ... (eq. 4.30).

    With one Haar level the pseudo-state [W_1, V_1] = [y[k] - y[k-1], y[k] + y[k-1]] / 2
    realises any second-order autonomous system, here y[k] = 0.95^k cos(0.3 k):

    >>> from node.sysid import eps_td
    >>> k = np.arange(400)
    >>> y = (0.95 ** k * np.cos(0.3 * k))[:, None]
    >>> m = WDMD(levels=1, warmup=1).fit(y[:300])
    >>> np.round(np.abs(m.model_.poles()), 6), np.round(np.abs(np.angle(m.model_.poles())), 6)
    (array([0.95, 0.95]), array([0.3, 0.3]))
    >>> bool(eps_td(y[300:], m.simulate(np.zeros((100, 0)), history=y[:300])) < 1e-8)
    True
    """

    def __init__(self, levels: int = 4, wavelet: str = "haar", components: str = "causal",
                 rcond: float = 1e-10, rank: int | None = None, estimator: str = "oe",
                 dt: float = 1.0, warmup: int = 0, seed_window: int | None = None,
                 ridge: float = 0.0) -> None:
        super().__init__(rcond=rcond, rank=rank, estimator=estimator, dt=dt, warmup=warmup,
                         seed_window=seed_window, ridge=ridge)
        self.levels = levels
        self.wavelet = wavelet
        self.components = components

    def _components(self) -> Components:
        try:
            return Components(self.components)
        except ValueError:
            raise ValueError(f"components must be one of {[c.value for c in Components]}, "
                             f"got {self.components!r}") from None

    def _check_params(self):
        if int(self.levels) != self.levels or self.levels < 1:
            raise ValueError(f"levels must be a positive integer, got {self.levels!r}")
        self._components()
        return super()._check_params()

    def memory(self) -> int:
        return sum(CausalMODWT(int(self.levels), self.wavelet).spans())

    def _lift(self, Y: np.ndarray, U: np.ndarray) -> np.ndarray:
        K, p = Y.shape
        if self._components() is Components.MRA:
            Z = modwt_mra(Y, int(self.levels), self.wavelet)
        else:
            Z = CausalMODWT(int(self.levels), self.wavelet, p).transform(Y)
        return Z.reshape(K, p * (int(self.levels) + 1))

    def filter_bank(self) -> CausalMODWT:
        """A fresh causal filter bank matching this model (for online stepping)."""
        return CausalMODWT(int(self.levels), self.wavelet, self.n_outputs_)
