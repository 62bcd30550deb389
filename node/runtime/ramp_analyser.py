"""The transient analysis sample by sample: ``RampAnalyser`` finds a target's ramps (run-ups,
coast-downs, ramps between plateaus) as its samples come and analyses each once it has ended
with the whole-ramp numerics of ``node.runtime.transient`` (``analyse``). The node drives one
per bed and target (``node.runtime.transient_watch``).
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from node.contract import FS
from node.runtime.transient import MIN_SPAN, Transient, analyse, filled


class RampAnalyser:
    """One target's ramps analysed as its samples come, one at a time (a run-up, a coast-down,
    the ramp between two plateaus): ``step`` returns the ramp's ``Transient`` once it has
    ended (``pad_s`` of settling after the speed stops moving), else None.

    The speed rate is that of a ``smooth_s`` moving average over the last ``smooth_s``; a ramp
    starts where it exceeds ``min_rate`` rpm/s and ends after ``gap_s`` + ``pad_s`` below it
    (or moving the other way); it keeps the ``smooth_s`` + ``pad_s`` before its start. A ramp
    shorter than ``min_span`` of its top speed gives nothing; one longer than ``max_s`` is
    dropped (bounded memory) and counted (``dropped``). ``analysis``: ``analyse``'s keywords
    (tracker_tau, velocity, min_amplitude, ...). State: a few seconds of samples and the ramp's
    own. ``aux``: further values carried with each sample (a time, another channel's speed);
    ``take`` and ``step_ramp`` give a ramp's samples unanalysed, (K, 3 + len(aux)): speed,
    amplitude, phase, aux; ``analysis_of`` analyses them.
    ``end()``: the ramp in progress analysed now (the data ended: a run's last coast-down).

    >>> speed = np.concatenate([np.full(200, 3000.0), np.linspace(3000, 9000, 2400),
    ...                         np.full(400, 9000.0)])
    >>> r = speed / 6000
    >>> v = speed * r**2 / (1 - r**2 + 0.1j * r) * 1e-3
    >>> ra = RampAnalyser()
    >>> got = [ra.step(s, a, p) for s, a, p in zip(speed, np.abs(v), -np.degrees(np.angle(v)))]
    >>> [(t.direction, round(t.criticals[0].speed)) for t in got if t is not None]
    [('up', 6000)]
    """

    def __init__(self, fs: float = FS, min_rate: float = 20.0, min_span: float = MIN_SPAN,
                 smooth_s: float = 1.0, gap_s: float = 1.0, pad_s: float = 2.0, max_s: float = 900.0,
                 **analysis: float | complex | None) -> None:
        self.fs = fs
        self.min_rate = min_rate
        self.min_span = min_span
        self.smooth_s = smooth_s
        self.gap_s = gap_s
        self.pad_s = pad_s
        self.max_s = max_s
        self.analysis = analysis
        self._n = max(1, int(round(smooth_s * fs)))
        self._recent: deque[tuple[float, ...]] = deque(maxlen=self._n + int(round(pad_s * fs)))
        self._window: deque[float] = deque(maxlen=self._n)
        self._means: deque[float] = deque(maxlen=self._n + 1)
        self._ramp: list[tuple[float, ...]] | None = None
        self._sign = 0
        self._quiet = 0
        self.dropped = 0  # ramps longer than max_s, dropped

    def _rate(self, speed: float) -> float:
        """rpm/s of the moving average over the last ``smooth_s`` (0 until it has that history)."""
        if math.isfinite(speed):
            self._window.append(speed)
        if not self._window:
            return 0.0
        self._means.append(sum(self._window) / len(self._window))
        if len(self._means) <= self._n:
            return 0.0
        return (self._means[-1] - self._means[0]) / self.smooth_s

    def step(self, speed: float, amplitude: float, phase: float | None = None,
             aux: tuple[float, ...] = ()) -> Transient | None:
        """Take one sample (rpm, amplitude, phase lag in degrees or None; NaN for missing; aux:
        values carried along, see the class docstring)."""
        ramp = self.step_ramp(speed, amplitude, phase, aux)
        return None if ramp is None else self.analysis_of(ramp)

    def step_ramp(self, speed: float, amplitude: float, phase: float | None = None,
                  aux: tuple[float, ...] = ()) -> np.ndarray | None:
        """``step`` without the analysis: the ramp that ended with this sample, unanalysed
        (``take``'s), else None."""
        sample = (float(speed), float(amplitude), math.nan if phase is None else float(phase), *aux)
        rate = self._rate(sample[0])
        if self._ramp is None:
            self._recent.append(sample)
            if abs(rate) > self.min_rate:
                self._ramp, self._sign, self._quiet = list(self._recent), 1 if rate > 0 else -1, 0
            return None
        self._ramp.append(sample)
        self._recent.append(sample)
        self._quiet = 0 if self._sign * rate > self.min_rate else self._quiet + 1
        if len(self._ramp) > self.max_s * self.fs:
            self._ramp = None  # longer than any ramp: dropped
            self.dropped += 1
            return None
        if self._quiet <= (self.gap_s + self.pad_s) * self.fs:
            return None
        return self.take()

    def end(self) -> Transient | None:
        """The ramp in progress (if any) analysed now (None: none, too short, too few samples),
        and forgotten (``reset`` forgets the history before it too)."""
        ramp = self.take()
        return None if ramp is None else self.analysis_of(ramp)

    def take(self) -> np.ndarray | None:
        """The ramp in progress (if any) ended now, unanalysed: its samples (K, 3 + len(aux)), or
        None (none, too short); forgotten. ``analysis_of`` analyses it."""
        if self._ramp is None:
            return None
        ramp, self._ramp = np.asarray(self._ramp), None
        s = filled(ramp[:, 0])
        if not np.isfinite(s).all() or abs(s[-1] - s[0]) < self.min_span * max(abs(s[0]), abs(s[-1]), 1e-9):
            return None
        return ramp

    def analysis_of(self, ramp: np.ndarray) -> Transient | None:
        """A ramp ``take`` or ``step_ramp`` gave, analysed (None: too few samples with speed and
        amplitude). Reads the ramp and the settings alone, changes nothing: it may run later, in
        another thread or process (the live node analyses in a process of its own)."""
        phases = None if np.isnan(ramp[:, 2]).all() else ramp[:, 2]
        try:
            return analyse(ramp[:, 0], ramp[:, 1], phases, fs=self.fs, **self.analysis)  # type: ignore[arg-type]
        except ValueError:
            return None  # too few samples with speed and amplitude

    def reset(self) -> None:
        """Forget everything but the counters (a new run: its first ramp starts afresh)."""
        self._recent.clear()
        self._window.clear()
        self._means.clear()
        self._ramp, self._sign, self._quiet = None, 0, 0
