"""This run's plateau level per OC, for the OC models' plateau shifts (``node.models.plateau``).

``RunPlateaus`` is stepped with every sample's measured level (the target's 1x vector, or its
amplitude) and told of every OC switch. A visit's plateau level is the mean of its finite levels
from ``SETTLE_S`` after its switch on (at least ``MIN_SAMPLES`` of them), kept when the visit
ends; the level before a switch is the mean of the finite levels over the last second. The node
(``MonitorPipeline``) and training and evaluation (``plateau_visits``) step the very same
object, so they see the very same numbers.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from node.contract import FS
from node.models.plateau import SETTLE_S

MIN_SAMPLES = int(2 * FS)  # a plateau needs this many finite levels after settling
_NAN = complex(math.nan, math.nan)


class RunPlateaus:
    """Stateful, bounded (one level per OC, the last second of levels). OC indices from
    ``n_ocs`` on (the rundown, ``Schedule.rundown``) are visits that keep no plateau.

    >>> rp = RunPlateaus(2)
    >>> rp.switch(0)
    >>> for k in range(40 * 20):  # OC 0 for 20 s: 1 during its first 15 s, then 3
    ...     rp.step(1.0 if k < 40 * 15 else 3.0)
    >>> rp.switch(1)
    >>> rp.levels, rp.pre
    ([(3+0j), (nan+nanj)], (3+0j))
    """

    def __init__(self, n_ocs: int) -> None:
        self.n_ocs = n_ocs
        self._recent: deque[complex] = deque(maxlen=int(FS))
        self.reset()

    def reset(self) -> None:
        """A new run: every plateau forgotten."""
        self.levels: list[complex] = [_NAN] * self.n_ocs
        self._recent.clear()
        self._oc: int | None = None
        self._since = 0
        self._sum = 0j
        self._n = 0
        self.pre: complex = _NAN  # the level over the second before the last switch

    @property
    def current(self) -> complex:
        """The plateau level of the visit under way so far (NaN: fewer than ``MIN_SAMPLES``)."""
        return self._sum / self._n if self._n >= MIN_SAMPLES else _NAN

    def switch(self, oc: int | None) -> None:
        """The OC changed (None: none) before the next sample: the visit that ends keeps its
        plateau, the level before the switch is taken."""
        if self._oc is not None and self._oc < self.n_ocs and self._n >= MIN_SAMPLES:  # (the rundown: none)
            self.levels[self._oc] = self.current
        vals = [v for v in self._recent if v == v]
        self.pre = sum(vals, 0j) / len(vals) if vals else _NAN
        self._oc, self._since, self._sum, self._n = oc, 0, 0j, 0

    def step(self, level: complex) -> None:
        """One sample's measured level (NaN: not measured)."""
        level = complex(level)
        self._recent.append(level)
        if self._oc is not None:
            if self._since >= SETTLE_S * FS and level == level:
                self._sum += level
                self._n += 1
            self._since += 1


def plateau_visits(levels: np.ndarray, labels: np.ndarray, n_ocs: int
                   ) -> dict[int, tuple[complex, list[complex], complex]]:
    """A run's visits as the node sees them: per visit start (sample index), the level before its
    switch, the run's plateaus then (per OC), and the visit's own plateau (NaN: too short).

    levels: (K,) complex (or real) measured levels; labels: (K,) the OC of each sample (< 0:
    none), as ``node.training.dataset.label_runs`` gives them.

    >>> lv = np.r_[np.full(800, 2.0), np.full(800, 5.0)]
    >>> out = plateau_visits(lv, np.r_[np.zeros(800, int), np.ones(800, int)], 2)
    >>> out[800]
    ((2+0j), [(2+0j), (nan+nanj)], (5+0j))
    """
    rp = RunPlateaus(n_ocs)
    out: dict[int, tuple[complex, list[complex], complex]] = {}
    starts: dict[int, tuple[complex, list[complex]]] = {}  # per visit: the level before, the plateaus then
    visit: int | None = None  # the start of the visit under way
    prev: int | None = None
    for k, (oc_k, v) in enumerate(zip(np.asarray(labels).tolist(), np.asarray(levels, complex).tolist(),
                                      strict=True)):
        oc = oc_k if oc_k >= 0 else None
        if k == 0 or oc != prev:
            if visit is not None:  # the visit that ends: its own plateau
                out[visit] = (*starts[visit], rp.current)
            rp.switch(oc)
            visit = k if oc is not None else None
            if visit is not None:
                starts[k] = (rp.pre, list(rp.levels))
            prev = oc
        rp.step(v)
    if visit is not None:
        out[visit] = (*starts[visit], rp.current)
    return out
