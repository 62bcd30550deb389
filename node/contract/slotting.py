"""Which 40 Hz slot a sample belongs to: the one rule of the live node, offline replay and training.

Slots lie on an absolute grid: slot k is the time k / FS, seconds since the epoch, so the
grid does not depend on which channel speaks first. A test bed samples each channel (or
group of channels) at its own clock phase within the period, plus jitter; ``ChannelPhase``
estimates one channel's phase phi (periods) from that channel's own timestamps, and a
sample at time t goes to slot ``round(t FS - phi)``, phi as estimated *before* the sample:

- the channel's first sample of a run sets phi to its own phase, frac(t FS) wrapped into
  [-0.5, 0.5) (to the nearest 1/Q period);
- the samples that follow are averaged as unit vectors e^(2 pi i frac(t FS)) (a circular
  mean, so phases near +-half a period average right), in blocks of ``BLOCK`` samples;
  each full block moves the estimate: a plain running mean up to ``N_MEAN`` samples, then
  an exponential one (``ALPHA`` per sample); phi follows the mean's angle continuously
  (unwrapped: a slow drift through half a period moves no sample to a neighbouring slot);
- a new run starts a new ``ChannelPhase``.

A sample's unit vector is looked up in an integer table (``Q`` phases), so a block's sum is
an exact integer whatever the order of additions: ``ChannelPhase.slot`` (one sample) and
``ChannelPhase.slots`` (many, with numpy) give bit-identical slots and states.

This module is in the contract (the bottom layer) because the node's aligner
(``node.runtime``) and training's ``read_runs`` (``node.training.runs``) must share it and neither
layer may import the other; and because it is part of what a test bed may rely on.

Guarantee (see docs/clock.md): if every sample of a channel lies within J < 1/4
period (6.25 ms at 40 Hz) of the channel's true phase, slowly drifting, each sample lands
in its own slot: the estimate is a mean of samples that are each within J of the truth,
so ``t FS - phi`` is within 2 J < 1/2 of an integer.

>>> p = ChannelPhase()
>>> [p.slot(t) for t in (100.0112, 100.0361, 100.0612)]  # phase 0.448 period, 11.2 ms
[4000, 4001, 4002]
>>> round(p.phase_ms, 1)
11.2
>>> q = ChannelPhase()
>>> q.slots(np.array([100.0112, 100.0361, 100.0612])).tolist()
[4000, 4001, 4002]
"""

from __future__ import annotations

import math

import numpy as np

from node.contract.keys import FS

Q = 4096  # phase resolution: 1/Q period (6 us at 40 Hz)
SCALE = 1 << 20  # the unit vectors' integer scale
BLOCK = 40  # samples averaged before the estimate moves
N_MEAN = 100  # a plain running mean up to this many samples...
ALPHA = 0.01  # ...then an exponential one, this weight per sample
_ALPHA_BLOCK = 1.0 - (1.0 - ALPHA) ** BLOCK  # that weight per block
_ANGLES = 2.0 * np.pi * np.arange(Q) / Q
COS = np.rint(np.cos(_ANGLES) * SCALE).astype(np.int64)  # (Q,) unit vector of each quantised phase
SIN = np.rint(np.sin(_ANGLES) * SCALE).astype(np.int64)
_COS, _SIN = COS.tolist(), SIN.tolist()


def _wrap(x: float) -> float:
    """x wrapped into [-0.5, 0.5)."""
    return x - math.floor(x + 0.5)


class ChannelPhase:
    """One channel's clock phase within a run, and the slot of each of its samples.

    Attributes:
        phi: the phase, periods (None before the first sample); ``phase_ms`` in ms.
        n: samples seen.
    """

    __slots__ = ("phi", "n", "_ex", "_ey", "_bx", "_by", "_bn", "_fs")

    def __init__(self, fs: float = FS) -> None:
        self.phi: float | None = None
        self.n = 0
        self._ex = self._ey = 0.0  # the mean unit vector (its angle: the phase)
        self._bx = self._by = self._bn = 0  # the current block: integer sums, count
        self._fs = fs

    @property
    def phase_ms(self) -> float | None:
        """The estimated phase, ms after the slot time (None before the first sample)."""
        return None if self.phi is None else self.phi * 1000.0 / self._fs

    def slot(self, t: float) -> int:
        """The slot of a sample at t (s); the sample then joins the estimate."""
        x = t * self._fs
        q = round((x - math.floor(x)) * Q) % Q
        if self.phi is None:
            return round(x - self._start(q))
        k = round(x - self.phi)
        self._bx += _COS[q]
        self._by += _SIN[q]
        self._bn += 1
        if self._bn == BLOCK:
            self._fold()
        return k

    def slots(self, t: np.ndarray) -> np.ndarray:
        """``[slot(t[i]) for i in range(len(t))]`` at once: t (n,) s, in arrival order; (n,) int64."""
        m = len(t)
        if not m:
            return np.zeros(0, dtype=np.int64)
        x = t * self._fs
        q = np.rint((x - np.floor(x)) * Q).astype(np.int64) % Q
        phis: list[float] = []  # the phase of each stretch of samples (constant within a block)
        lens: list[int] = []
        i = 0
        if self.phi is None:
            phis.append(self._start(int(q[0])))
            lens.append(1)
            i = 1
        if i < m:
            # the stretches [starts[j], ends[j]): the rest of the current block, then whole blocks
            starts = [i, *range(i + BLOCK - self._bn, m, BLOCK)]
            ends = [*starts[1:], m]
            bx = np.add.reduceat(COS[q], starts).tolist()  # exact integer sums
            by = np.add.reduceat(SIN[q], starts).tolist()
            for a, b, sx, sy in zip(starts, ends, bx, by, strict=True):
                phi = self.phi  # this block's (_fold moves it)
                assert phi is not None  # set by the first sample
                phis.append(phi)
                lens.append(b - a)
                self._bx += sx
                self._by += sy
                self._bn += b - a
                if self._bn == BLOCK:
                    self._fold()
        return np.rint(x - np.repeat(phis, lens)).astype(np.int64)

    def _start(self, q: int) -> float:
        """The first sample (quantised phase q): phi is its phase (returned)."""
        phi = self.phi = _wrap(q / Q)
        self._ex, self._ey = _COS[q] / SCALE, _SIN[q] / SCALE
        self.n = 1
        return phi

    def _fold(self) -> None:
        """A full block moves the mean vector, and phi follows its angle (continuously)."""
        b = self._bn
        w = b / (self.n + b) if self.n + b <= N_MEAN else _ALPHA_BLOCK
        self._ex += w * (self._bx / (b * SCALE) - self._ex)
        self._ey += w * (self._by / (b * SCALE) - self._ey)
        self.n += b
        self._bx = self._by = self._bn = 0
        assert self.phi is not None
        self.phi += _wrap(math.atan2(self._ey, self._ex) / (2.0 * math.pi) - self.phi)
