"""Alarm calibration and the model-free sensor check, free of I/O.

Two rules flag a sample:

* residual: the smoothed standardized residual (EWMA of (measured - predicted) / sigma)
  stays beyond its OC's threshold for ``persist`` samples. Thresholds come from an
  alarm budget: the cross-validated segments' peak scores of *every* OC are pooled
  (they are in sigma units already), a Gumbel law is fitted to them, and the level a
  normal segment exceeds with chance ``budget / segments_per_hour`` is the threshold,
  never below ``THRESHOLD_MARGIN`` x the OC's own largest CV peak. Pooling a hundred
  peaks gives a far steadier tail than each OC's eight or so.
* flatline: the measured target repeats the very same value for ``flatline`` samples
  while the engine runs: a stuck sensor or a frozen acquisition. The limit is learnt
  from the training runs (``FLATLINE_FACTOR`` x the longest repeat seen, at least
  ``FLATLINE_MIN_S``), so coarse quantisation on another test bed raises it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

FALSE_ALARMS_PER_HOUR = 0.5  # residual-alarm budget on normal runs, per hour of OC time
THRESHOLD_MARGIN = 1.25  # never below margin x an OC's largest CV peak score
FLATLINE_MIN_S = 2.0  # a flat line shorter than this never alarms, s
FLATLINE_FACTOR = 4.0  # limit = factor x the longest repeat in the training runs
EULER_GAMMA = 0.5772156649


def gumbel_quantile(peaks: Sequence[float], p: float) -> float:
    """Level a Gumbel law fitted to ``peaks`` (method of moments) exceeds with chance ``p``."""
    x = np.asarray(peaks, dtype=float)
    beta = float(np.std(x)) * math.sqrt(6.0) / math.pi
    mu = float(np.mean(x)) - EULER_GAMMA * beta
    return mu - beta * math.log(-math.log(1.0 - p))


def pooled_thresholds(peaks: dict[str, list[float]], segments_per_hour: float,
                      budget: float = FALSE_ALARMS_PER_HOUR) -> dict[str, float]:
    """Per-OC thresholds (sigma units) from every OC's CV peak scores and the alarm budget.

    peaks: OC name -> peak |smoothed score| of each held-out CV segment.
    segments_per_hour: OC segments a normal hour of running holds (from the training runs).
    """
    every = [v for vals in peaks.values() for v in vals if math.isfinite(v)]
    if not every:
        return {}
    p = min(0.5, budget / max(segments_per_hour, 1e-9))
    common = gumbel_quantile(every, p) if len(every) > 1 else every[0]
    return {name: max(common, THRESHOLD_MARGIN * max(vals)) for name, vals in peaks.items() if vals}


def longest_repeat(y: np.ndarray, running: np.ndarray) -> int:
    """Longest run of identical consecutive finite values of ``y`` (K,) while ``running`` (K,).

    NaN (dropouts) neither extend nor break a run; samples not running break it.
    Counts repeats, so a value seen n times in a row gives n - 1.
    """
    best = cur = 0
    last = math.nan
    for v, on in zip(y.tolist(), running.tolist()):
        if not on:
            cur, last = 0, math.nan
            continue
        if v != v:
            continue
        cur = cur + 1 if v == last else 0
        last = v
        best = max(best, cur)
    return best


def flatline_limit(longest: int, fs: float) -> int:
    """Repeats that make a flat line (samples), from the longest repeat seen in training."""
    return max(int(round(FLATLINE_MIN_S * fs)), int(math.ceil(FLATLINE_FACTOR * max(longest, 1))))


class FlatlineCheck:
    """Stateful stuck-sensor check: ``step(value, running) -> True`` while the line is flat."""

    def __init__(self, limit: int) -> None:
        self.limit = limit
        self._last = math.nan
        self._count = 0

    def reset(self) -> None:
        self._last, self._count = math.nan, 0

    def step(self, value: float, running: bool) -> bool:
        if not running:
            self.reset()
            return False
        if value == value:  # NaN (dropout): keep the count as it is
            self._count = self._count + 1 if value == self._last else 0
            self._last = value
        return self._count >= self.limit


def running_mask(speed: np.ndarray, detector) -> np.ndarray:
    """(K,) bool: samples the OC detector (stepped afresh on ``speed`` (K,)) does not call off."""
    from node.ocdetect import Phase

    detector.reset()
    return np.array([detector.step(v).phase is not Phase.OFF for v in speed.tolist()])


class EpisodeLog:
    """Alarm episodes of a monitor stream: alarm samples less than ``gap_s`` apart are one.

    ``episodes``: list of dicts {"key", "start", "end", "reason"} (times in s, the first
    alarm sample's reason).
    """

    def __init__(self, gap_s: float = 1.0) -> None:
        self.gap_s = gap_s
        self.episodes: list[dict] = []
        self._open: dict[str, dict] = {}

    def add(self, key: str, msg: dict) -> None:
        if msg.get("flag") != "alarm":
            return
        t = float(msg["t"])
        ep = self._open.get(key)
        if ep is not None and t - ep["end"] <= self.gap_s:
            ep["end"] = t
            return
        ep = {"key": key, "start": t, "end": t, "reason": msg.get("reason")}
        self._open[key] = ep
        self.episodes.append(ep)
