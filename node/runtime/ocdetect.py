"""Causal operating-condition detection from the switch speed (``nB``), with hysteresis.

One detector serves training (segments) and the live node (switches), so the
model of an OC is trained on exactly the samples it will be run on.

States, per sample:

* ``steady`` in OC i: the speed has held within ``tolerance`` of OC i's
  plateau for ``confirm_s`` with little spread;
* ``transition`` into OC i: the speed has left the speed it held (by half the
  tolerance and still moving away, for ``depart_s``) heading for OC i, the
  next OC of the schedule that lies in that direction; a transition that goes
  past its target's band is re-targeted the same way. The start is the first
  OC's transition: from the first speed above the off level (light-off), when
  it lies below the first OC's band, to that OC's plateau; a speed held on the
  way (idle) does not end it (light-off: the speed above the off level for ``depart_s``).
  Until it leaves that held speed (or, without one, reaches the plateau) the start has a
  model of its own (``segment``, ``Schedule.start``), the OC's model from there;
* ``transition`` in the rundown (index ``len(schedule.ocs)``, ``Schedule.rundown``):
  a departure downward with no later OC in that direction (fuel off), to standstill;
  a speed held on the way that is no scheduled plateau does not end it, a departure
  upward from it is a transition into the next OC ahead;
* ``off``: the engine is stopped (below the off level), or held at a speed that
  is no scheduled plateau outside the start and the rundown (a recording that
  begins mid-run, an upward departure with no OC ahead) (oc None).

A plateau reached that is not the expected one (an aborted or re-run OC, a
plateau held during the rundown) takes over once it has held
for ``settle_s``. Non-finite speeds hold the
previous state. All memory is a few seconds of smoothed speed.
"""

from __future__ import annotations

import itertools  # noqa: F401  (the doctest's)
import math
from collections import deque
from typing import NamedTuple

import numpy as np

from node.contract import FS, Phase, off_speed
from node.contract.schedule import Schedule
from node.models.config import RuntimeConfig


class OCState(NamedTuple):
    oc: int | None  # index into the schedule, None outside any OC
    phase: Phase


class _Extremes:
    """Max and min of the last ``n`` values pushed, in O(1) amortized per push (monotonic queues)."""

    def __init__(self, n: int) -> None:
        self.n = n
        self._i = 0
        self._hi: deque[tuple[int, float]] = deque()
        self._lo: deque[tuple[int, float]] = deque()

    def push(self, v: float) -> None:
        i = self._i = self._i + 1
        hi, lo = self._hi, self._lo
        while hi and hi[-1][1] <= v:
            hi.pop()
        hi.append((i, v))
        if hi[0][0] <= i - self.n:
            hi.popleft()
        while lo and lo[-1][1] >= v:
            lo.pop()
        lo.append((i, v))
        if lo[0][0] <= i - self.n:
            lo.popleft()

    @property
    def high(self) -> float:
        return self._hi[0][1]

    @property
    def low(self) -> float:
        return self._lo[0][1]


class OCDetector:
    """Stateful, causal OC detector (``step`` one sample at a time).

    Args:
        schedule: the pass-off schedule.
        config: run-time settings (default settings if None); the detector's are
            ``detector_smooth_s`` (causal moving average of the speed),
            ``detector_confirm_s`` (time within the band of the expected plateau to call it
            steady), ``detector_depart_s`` (time beyond half the band around the plateau to
            call a departure), ``detector_settle_s`` (time of near-constant speed to accept
            an unexpected plateau) and ``detector_off_fraction`` (below this fraction of the
            highest plateau the engine is off: the contract's engine-off rule, ``off_speed``, on
            the switch shaft, whose highest plateau stands for the maximum a causal detector
            cannot know yet).
        fs: sample rate, Hz.

    >>> from node.contract.schedule import OperatingCondition, Schedule
    >>> det = OCDetector(Schedule((OperatingCondition("A", 4000.0), OperatingCondition("B", 6000.0))))
    >>> speed = np.r_[np.linspace(0.0, 4000.0, 400), np.full(200, 4000.0), np.linspace(4000.0, 6000.0, 200),
    ...               np.full(200, 6000.0), np.linspace(6000.0, 0.0, 400)]
    >>> oc, phase = det.label(speed)
    >>> [(o, Phase.from_code(p).value) for (o, p), _ in itertools.groupby(zip(oc.tolist(), phase.tolist()))]
    ... # doctest: +NORMALIZE_WHITESPACE
    [(-1, 'off'), (0, 'transition'), (0, 'steady'), (1, 'transition'), (1, 'steady'),
     (2, 'transition'), (-1, 'off')]
    """

    def __init__(self, schedule: Schedule, config: RuntimeConfig | None = None, fs: float = FS) -> None:
        c = config or RuntimeConfig()
        self.schedule = schedule
        self.config = c
        self.speeds = np.array([oc.speed for oc in schedule.ocs])
        self._nominal = self.speeds.tolist()  # the same floats, without a numpy scalar per step
        self.tol = schedule.tolerance
        self.n_smooth = max(1, round(c.detector_smooth_s * fs))
        self.n_confirm = max(1, round(c.detector_confirm_s * fs))
        self.n_depart = max(1, round(c.detector_depart_s * fs))
        self.n_settle = max(self.n_confirm, round(c.detector_settle_s * fs))
        self.off_level = off_speed(float(self.speeds.max()), c.detector_off_fraction)  # rpm
        self.rundown = schedule.rundown  # the rundown's OC index (len(schedule.ocs))
        self.start = schedule.start  # the start's model index (``segment``)
        self._start_below = float(self.speeds[0]) * (1.0 - self.tol)  # a light-off below it starts OC 0
        self.reset()

    def reset(self) -> None:
        self.state = OCState(None, Phase.OFF)
        self._raw: deque[float] = deque(maxlen=self.n_smooth)
        self._hist: deque[float] = deque(maxlen=self.n_settle)
        self._ext = {n: _Extremes(n) for n in (self.n_settle, self.n_confirm)}  # for _held
        self._anchor: float | None = None  # speed of the plateau last held
        self._last: int = -1  # last OC reached steady in this run
        self._away = 0  # consecutive samples away from the anchor
        self._direction = 1.0  # of the transition under way: +1 up, -1 down
        self._since = 0  # samples since the state last changed
        self._on = False  # the speed has been above the off level since the last off
        self._above = 0  # samples above the off level since the last off, up to depart_s
        self._start = False  # in the start (OC 0's transition from light-off)

    # -- helpers --------------------------------------------------------------
    def _held(self, n: int, centre: float, band: float) -> bool:
        """The last n smoothed speeds all lie within centre +- band."""
        if len(self._hist) < n:
            return False
        ext = self._ext.get(n)
        if ext is not None:
            return ext.high <= centre + band and ext.low >= centre - band
        recent = list(self._hist)[-n:]
        return max(recent) <= centre + band and min(recent) >= centre - band

    def _target(self, direction: float) -> int | None:
        """The OC a departure from the anchor heads for."""
        anchor = self._anchor
        assert anchor is not None
        ahead = [j for j in range(len(self.speeds))
                 if direction * (self.speeds[j] - anchor) > self.tol * anchor]
        if not ahead:
            return None
        later = [j for j in ahead if j > self._last]
        return later[0] if later else None

    # -- the step ---------------------------------------------------------------
    def step(self, speed: float) -> OCState:
        """Advance by one sample of the switch speed (rpm); returns the state in force."""
        if not math.isfinite(speed):
            return self.state
        self._raw.append(float(speed))
        self._since += 1
        s = sum(self._raw) / len(self._raw)
        self._hist.append(s)
        for ext in self._ext.values():
            ext.push(s)
        oc, phase = self.state

        if speed < self.off_level:
            self._anchor, self._last, self._away, self._on, self._above = None, -1, 0, False, 0
            self._set(OCState(None, Phase.OFF))
            return self.state
        if not self._on:  # light-off (or a recording that begins with the engine running)
            self._above += 1  # (held above the off level for depart_s: noise at the crossing is no start)
            if self._above < self.n_depart:
                return self.state
            self._on = True
            if phase is Phase.OFF and speed < self._start_below:
                self._direction = 1.0
                self._set(OCState(0, Phase.TRANSITION))
                self._start = True
                return self.state

        if phase is Phase.STEADY:
            assert oc is not None and self._anchor is not None  # set on arrival
            nominal = self._nominal[oc]
            before = self._hist[-1 - self.n_depart] if len(self._hist) > self.n_depart else s
            if abs(s - nominal) < abs(before - nominal) or abs(s - nominal) <= 0.25 * self.tol * nominal:
                # still settling onto the plateau: the held speed follows
                self._anchor += (s - self._anchor) / self.n_confirm
                self._anchor = min(max(self._anchor, nominal * (1 - self.tol)), nominal * (1 + self.tol))
            self._count_away(s, nominal)
            return self.state

        if phase is Phase.TRANSITION and oc != self.rundown:
            assert oc is not None  # a transition heads for an OC
            target = self._nominal[oc]
            band = self.tol * target
            if self._held(self.n_confirm, target, band):
                self._arrive(oc)
                return self.state
            if (s - target) * self._direction > band:  # went past the target
                self._anchor = s
                self._depart(s, self._direction)
                return self.state
        # transition to an unexpected plateau, or off / idle / held elsewhere
        if self._since >= self.n_settle and self._held(self.n_settle, s, 0.25 * self.tol * s):
            near = np.flatnonzero(np.abs(self.speeds - s) <= self.tol * self.speeds)
            if near.size:
                later = [int(j) for j in near if j > self._last]
                self._arrive(later[0] if later else int(near[0]))
            else:
                self._anchor = s  # held there: the start and the rundown go on, anything else is off
                if oc != self.rundown and not self._start:
                    self._set(OCState(None, Phase.OFF))
            return self.state
        if (phase is Phase.OFF or oc == self.rundown or self._start) and self._anchor is not None:
            self._count_away(s, self._anchor)  # (from the rundown: up, into the OC ahead)
        return self.state

    def _count_away(self, s: float, nominal: float) -> None:
        """Departure: beyond half the band around the held speed and moving away from it.

        The held speed (anchor) follows the speed while it settles onto the plateau
        (approaching it, or within a quarter band), never beyond the plateau's band,
        so a ramp away cannot drag it along.
        """
        assert self._anchor is not None
        before = self._hist[-1 - self.n_depart] if len(self._hist) > self.n_depart else s
        off = s - self._anchor
        if abs(off) > 0.5 * self.tol * self._anchor and (s - before) * off > 0:
            self._away += 1
        else:
            self._away = 0
        if self._away >= self.n_depart:
            self._depart(s)

    def _arrive(self, j: int) -> None:
        self._last = j
        recent = list(self._hist)[-self.n_confirm:]
        self._anchor = sum(recent) / len(recent)
        self._away = 0
        self._set(OCState(j, Phase.STEADY))

    def _depart(self, s: float, direction: float | None = None) -> None:
        assert self._anchor is not None
        self._start = False  # (a start's departure from its hold: the first OC's model from here)
        self._direction = math.copysign(1.0, s - self._anchor) if direction is None else direction
        target = self._target(self._direction)
        self._away = 0
        if target is None:  # none ahead: down, the rundown (fuel off); up, no OC
            self._anchor = None
            down = self._direction < 0
            self._set(OCState(self.rundown, Phase.TRANSITION) if down else OCState(None, Phase.OFF))
        else:
            self._set(OCState(target, Phase.TRANSITION))

    def _set(self, state: OCState) -> None:
        if state != self.state:
            self._since = 0
            self._start = False  # (set again by a light-off)
        self.state = state

    @property
    def segment(self) -> int | None:
        """The model in force (``Schedule.models``): the OC's (or the rundown's), but the start's
        (``Schedule.start``) in the first OC's transition from light-off until it leaves the
        speed it held (or reaches the plateau)."""
        return self.start if self._start else self.state.oc

    def label(self, speed: np.ndarray, models: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Run over a speed series (K,): OC index per sample (-1: none) and phase codes.

        Phase codes: 0 off, 1 transition, 2 steady. Continues from the current state.
        models: the model index (``segment``) instead of the OC's: the start's apart.
        """
        oc = np.empty(len(speed), dtype=np.int64)
        ph = np.empty(len(speed), dtype=np.int8)
        for k, v in enumerate(np.asarray(speed, dtype=float)):
            st = self.step(v)
            seg = self.segment if models else st.oc
            oc[k] = -1 if seg is None else seg
            ph[k] = st.phase.code
        return oc, ph
