"""The pass-off verdict of one target in one run (``monitor/verdict``, docs/contract.md section 2).

``RunVerdict.step`` takes every sample of the run (cheap: a few comparisons): the smallest
margin (limit minus measured) so far and where it fell, whether any sample was over its limit,
and the run's peak of the target and peak over the limit in each segment. ``switch`` and
``end`` give the verdict message at an OC switch (``pending``, with the forecast of the
remaining segments: ``node.models.forecast``, computed there, off the per-sample path) and at
the end of the run (``pass`` or ``fail``). A run starts at its first sample in a segment (the
start, from light-off). Training steps the very same object over its runs for the peaks it keeps
(``peaks``, ``ratios``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from node.contract import Status
from node.models.forecast import Forecaster

PASS, FAIL, PENDING = Status.PASS.value, Status.FAIL.value, Status.PENDING.value
_NAN = float("nan")


class RunVerdict:
    """One target's verdict over a run, its segments ``segments`` (``Schedule.segments``); the
    forecast from ``forecaster`` (None: the bundle keeps no training peaks: no forecast).

    >>> v = RunVerdict("yB", ("A", "rundown"))
    >>> for t, oc, y in [(0.0, None, 0.1), (1.0, "A", 2.0), (2.0, "A", 5.0), (3.0, "rundown", 1.0)]:
    ...     v.step(t, oc, 4000.0, y, 4.0 if oc else None)
    >>> v.peaks, v.ratios
    ([5.0, 1.0], [1.25, 0.25])
    >>> m = v.end(3.0)
    >>> m["status"], m["run"], m["margin"], m["margin_oc"], v.run
    ('fail', 1.0, -1.0, 'A', None)
    """

    def __init__(self, target: str, segments: Sequence[str], forecaster: Forecaster | None = None) -> None:
        self.target = target
        self.segments = tuple(segments)
        self.forecaster = forecaster
        self._index = {name: i for i, name in enumerate(self.segments)}
        self.reset()

    def reset(self) -> None:
        """A new run: nothing seen."""
        self.run: float | None = None  # the run's start time, s (None: no run going on)
        self.failed = False
        self.margin = math.inf
        self.margin_oc: str | None = None
        self.margin_speed: float | None = None
        self.peaks = [_NAN] * len(self.segments)  # this run's peak of the target per segment
        self.ratios = [_NAN] * len(self.segments)  # its largest measured / limit per segment
        self.last: int | None = None  # the last segment it was in
        self.t = _NAN  # its last sample's time

    def step(self, t: float, oc: str | None, speed: float, measured: float, limit: float | None) -> None:
        """One sample: its time, segment (None: off), switch speed, measured value (NaN: none)
        and the limit in force (None: none)."""
        if self.run is None:
            if oc is None:
                return
            self.run = t
        self.t = t
        i = self._index.get(oc) if oc is not None else None
        if i is not None:
            self.last = i
        if measured != measured:
            return
        if i is not None and not measured <= self.peaks[i]:
            self.peaks[i] = measured
        if limit is None:
            return
        if i is not None:
            r = measured / limit
            if not r <= self.ratios[i]:
                self.ratios[i] = r
        m = limit - measured
        if m < self.margin:
            self.margin, self.margin_oc, self.margin_speed = m, oc, speed if speed == speed else None
        if measured > limit:
            self.failed = True

    def switch(self, t: float, oc: str | None) -> dict | None:
        """The verdict at a switch into segment ``oc`` (None: off, the engine held at no plateau):
        ``pending``, or ``fail`` once a sample was over its limit, with the forecast of the
        remaining segments; None before the run started."""
        if self.run is None:
            return None
        i = self._index.get(oc) if oc is not None else None
        start = i if i is not None else (self.last + 1 if self.last is not None else 0)
        done = {s: p for s, p in enumerate(self.peaks) if s != i and p == p}
        return self._message(t, FAIL if self.failed else PENDING, range(start, len(self.segments)), done)

    def end(self, t: float | None = None) -> dict | None:
        """The verdict at the end of the run (``pass`` or ``fail``; at ``t``, default its last
        sample's time), and a new run begins; None when no run was going on."""
        if self.run is None:
            return None
        msg = self._message(self.t if t is None else t, FAIL if self.failed else PASS, (), {})
        self.reset()
        return msg

    def _message(self, t: float, status: str, remaining: Sequence[int], done: dict[int, float]) -> dict:
        finite = self.margin < math.inf
        msg = {"t": t, "target": self.target, "run": self.run, "status": status,
               "margin": self.margin if finite else None, "margin_oc": self.margin_oc,
               "margin_speed": self.margin_speed, "p_fail": None, "forecast": [],
               "first_exceedance": None}
        if self.forecaster is not None:
            if remaining:
                forecast, p_fail, first = self.forecaster.forecast(done, list(remaining))
                msg["forecast"], msg["p_fail"], msg["first_exceedance"] = forecast, p_fail, first
            else:
                msg["p_fail"] = 0.0
        return msg
