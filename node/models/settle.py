"""The visit's own level as it settles: a learned re-anchor of the OC model's prediction
(``bench generalise``: the first OC after a start, where a bowed rotor's vector is, misses its plateau's
level most, and nothing earlier in the run tells it).

At ``AT_S`` after an OC switch, when the transition has ended, the prediction's mean residual
over the ``WINDOW_S`` before is what the model has missed of this visit so far. Across the
training runs' held-out visits, part of it stays for the rest of the plateau (the run's
imbalance and bow the switch did not show) and part fades (noise, a bow still healing): the
OC's ``gain`` is that part, learned from its cross-validation (``node.training.plateau_fit``,
``choose_settle``). From ``AT_S`` on, the prediction is moved by ``gain`` x that mean
residual. A fault whose onset falls within the visit's first ``AT_S`` is partly absorbed by
it, as an anchored model absorbs one present at the switch; the step and vector rules watch
the plateau itself.

The node (``node.runtime.pipeline``) and training and evaluation (``SettleAnchor.moved``)
compute the very same numbers: the window's residuals summed in order, one sample at a time.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from node.contract import FS
from node.models.plateau import SETTLE_S

AT_S = SETTLE_S  # s after the switch: the re-anchor takes effect (the transitions last 10-15 s)
WINDOW_S = 2.0  # s: the residual's mean over this long before AT_S
AT = int(AT_S * FS)  # samples
WINDOW = int(WINDOW_S * FS)
MIN_FINITE = WINDOW // 2  # finite residuals the window needs, else no re-anchor
MAX_GAIN = 1.0  # the whole residual at most: never more than what was seen


@dataclass(frozen=True)
class SettleAnchor:
    """One OC's re-anchor (see the module): ``gain`` in [0, ``MAX_GAIN``].

    >>> s = SettleAnchor(0.5)
    >>> y, p = np.full(AT + 40, 3.0), np.full(AT + 40, 2.0)  # 1 mm/s missed throughout
    >>> q = s.moved(y, p)
    >>> float(q[AT - 1]), float(q[AT])  # before AT_S as predicted, then half the miss made good
    (2.0, 2.5)
    >>> SettleAnchor.from_dict(s.to_dict()) == s
    True
    """

    gain: float

    def __post_init__(self) -> None:
        if not (isinstance(self.gain, float) and 0.0 <= self.gain <= MAX_GAIN):
            raise ValueError(f"a settle anchor's gain must be a number in [0, {MAX_GAIN:g}]")

    def offset(self, residuals: Sequence[float]) -> float:
        """The move (mm/s) from the window's residuals (measured - predicted, in time order, NaN
        where either is unknown): ``gain`` x their mean, summed in order; 0 with fewer than
        ``MIN_FINITE`` finite."""
        total, n = 0.0, 0
        for r in residuals:
            if r - r == 0.0:
                total += r
                n += 1
        return self.gain * (total / n) if n >= MIN_FINITE else 0.0

    def moved(self, measured: np.ndarray, predicted: np.ndarray) -> np.ndarray:
        """A visit's prediction (K,) from its switch on, moved as the node moves it (a copy when
        moved; visits shorter than ``AT_S`` unchanged)."""
        if len(predicted) <= AT:
            return predicted
        with np.errstate(invalid="ignore"):
            r = (np.asarray(measured, float)[AT - WINDOW:AT] - predicted[AT - WINDOW:AT]).tolist()
        s = self.offset(r)
        if s == 0.0:
            return predicted
        out = np.array(predicted, float, copy=True)
        out[AT:] += s
        return out

    def to_dict(self) -> dict:
        """For the bundle's manifest."""
        return {"gain": self.gain}

    @classmethod
    def from_dict(cls, d: object) -> SettleAnchor:
        """``to_dict``'s inverse, checked (``ValueError``, one line)."""
        if not isinstance(d, dict) or set(d) != {"gain"}:
            raise ValueError("a settle anchor must be an object of gain")
        g = d["gain"]
        if not isinstance(g, (int, float)) or isinstance(g, bool) or not math.isfinite(g):
            raise ValueError("a settle anchor's gain must be a finite number")
        return cls(float(g))
