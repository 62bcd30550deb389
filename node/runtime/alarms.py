"""The alarm rules of a monitor stream, and alarm episodes; free of I/O.

Three rules flag a sample (the monitor message's ``reason``); their limits come from
training (``node.training.calibrate``), their timings from the bundle's ``RuntimeConfig``:

* residual (``ResidualCheck``): the smoothed standardized residual (EWMA of
  (measured - predicted) / sigma) stays beyond its OC's threshold for ``persist``
  samples; the alarm clears after ``residual_clear_s`` back under it. The residual's
  sigma is scaled per run by ``RunScale`` (how far this run's earlier OCs strayed
  from their models), in calibration and in the node alike.
* step (``StepCheck``): during a steady plateau (after ``step_settle_s``), the mean of
  the measured target over the last ``step_short_s`` departs from its mean over the
  ``step_long_s`` before by more than a threshold in units of the local noise (a clipped
  EWMA of the first differences). Model-free: an abrupt change of an order amplitude
  while the operating point holds (added imbalance, a loose part) shows at once,
  however poorly the OC's model does.
* flatline (``FlatlineCheck``): the measured target repeats the very same value for
  ``limit`` samples while the engine runs: a stuck sensor or a frozen acquisition.
"""

from __future__ import annotations

import math
from collections import deque

from node.contract import FS, Flag
from node.models.config import RuntimeConfig

RUN_SCALE_PRIOR_OCS = 3.0  # a run counts as typical with the weight of this many OCs


class RunScale:
    """How unusual this run is so far: the residual rule's sigma is multiplied by ``factor``.

    The same engine vibrates differently from run to run (thermal state, re-seated
    imbalance), and an OC model's error carries that run's mark into every OC.
    After each OC segment, its mean squared standardized residual m_j is added;
    factor = max(1, sqrt((n0 + sum m_j) / (n0 + J))), n0 = ``prior``:
    1 for a typical run, never below 1 (never more sensitive than the calibration).
    Training calibrates with the very same rule over each held-out CV run.

    >>> s = RunScale(prior=3.0)
    >>> s.add(0.5); s.factor  # a typical OC: no change
    1.0
    >>> s.add(12.0); round(s.factor, 3)  # sqrt((3 + 12.5) / 5)
    1.761
    """

    def __init__(self, prior: float = RUN_SCALE_PRIOR_OCS) -> None:
        self.prior = prior
        self.reset()

    def reset(self) -> None:
        """A new run: typical until its OCs say otherwise."""
        self.total = 0.0
        self.count = 0
        self.factor = 1.0

    def add(self, mean_sq: float) -> None:
        """One finished OC segment's mean squared standardized residual (NaN, inf: ignored)."""
        if mean_sq == mean_sq and mean_sq != math.inf:
            self.total += mean_sq
            self.count += 1
            self.factor = max(1.0, math.sqrt((self.prior + self.total) / (self.prior + self.count)))


class ResidualCheck:
    """The residual rule over one OC segment (stateful, O(1) memory).

    ``step(residual) -> (score, raised)``: score e_k = (1 - alpha) e_(k-1) + alpha z_k / run_scale,
    z = residual / sigma (from e = 0); raised once |e| has stayed beyond ``threshold`` for
    ``persist`` samples (on-delay), lowered once it has stayed under for ``clear``
    samples (off-delay against chatter). A NaN residual (no measurement or no
    prediction) changes nothing. ``mean_sq``: mean z^2 of the segment so far (of the OC model's
    own residuals), for ``RunScale``.

    Args:
        sigma: the OC's residual sd (target unit).
        threshold: on |score| (sigma units).
        alpha: EWMA weight of the newest sample.
        persist: samples beyond the threshold that raise the alarm.
        clear: samples under it that lower the alarm (0: at once).
        run_scale: the run's ``RunScale.factor`` when the segment began.

    >>> chk = ResidualCheck(sigma=2.0, threshold=1.0, alpha=0.5, persist=2, clear=3)
    >>> [chk.step(r) for r in (4.0, 4.0, 4.0)]  # z = 2: scores 1, 1.5, 1.75
    [(1.0, False), (1.5, False), (1.75, True)]
    >>> [chk.step(r)[1] for r in (0.0, float("nan"), 0.0, 0.0, 0.0)]  # 3 samples under: cleared
    [True, True, True, False, False]
    >>> chk.mean_sq == (3 * 2.0 ** 2 + 4 * 0.0) / 7  # the seven residuals measured
    True
    """

    def __init__(self, sigma: float, threshold: float, alpha: float, persist: int, clear: int,
                 run_scale: float = 1.0) -> None:
        self.sigma = sigma
        self.threshold = threshold
        self.alpha = alpha
        self.persist = persist
        self.clear = clear
        self.run_scale = run_scale
        self.band = threshold * sigma * run_scale  # the alarm's half-width around the prediction
        self.reset()

    def reset(self) -> None:
        self.score = 0.0
        self.raised = False
        self._beyond = self._below = 0
        self._zsum, self.count = 0.0, 0

    @property
    def mean_sq(self) -> float:
        """Mean squared standardized residual of the samples stepped so far (NaN before any)."""
        return self._zsum / self.count if self.count else math.nan

    def step(self, residual: float, model_residual: float | None = None) -> tuple[float, bool]:
        """One sample's residual (NaN: nothing changes); ``model_residual``: the OC model's own
        where the node predicted with something else (the curve guard's curve), which is what
        ``mean_sq`` measures for ``RunScale`` (training calibrates on the models' residuals)."""
        if residual != residual:
            return self.score, self.raised
        z = residual / self.sigma
        zm = z if model_residual is None else model_residual / self.sigma
        self._zsum += zm * zm
        self.count += 1
        self.score = (1.0 - self.alpha) * self.score + self.alpha * z / self.run_scale
        if abs(self.score) > self.threshold:
            self._beyond, self._below = self._beyond + 1, 0
        else:
            self._beyond, self._below = 0, self._below + 1
        if self._beyond >= self.persist:
            self.raised = True
        elif self._below >= self.clear:
            self.raised = False
        return self.score, self.raised


def _isnan(z: complex) -> bool:
    """Whether z (a float or complex, numpy's too) is NaN in either part: ``z != z`` as a bool
    (numpy's scalars answer that with a ``numpy.bool``)."""
    return math.isnan(z.real) or math.isnan(z.imag)


class StepCheck:
    """Stateful step detector on one channel during steady plateaus (bounded memory).

    ``step(value, steady) -> z``: |mean(last short) - mean(long before)| / noise sd, 0
    until both windows lie inside the current plateau, after its settling time;
    ``anchored``: the long window stays the plateau's first one (the change since the
    plateau settled, slow ones too: a stiffness loss drifting in over seconds), instead of
    sliding along. Values may be complex (an order's 1x vector: |.| of the mean difference,
    the noise variance the mean of |first difference|^2 / 2 over both components);
    ``flagged`` is True once z has stayed beyond ``threshold`` for ``persist`` samples,
    and stays True to the end of the plateau (the operating point has not changed, so
    the new level is not normal). NaN values hold the last one. Windows and timings:
    ``config.step_*``.

    >>> chk = StepCheck(threshold=8.0)
    >>> (chk.n_settle, chk.n_short, chk.n_long, chk.persist)  # samples, at 40 Hz
    (120, 40, 160, 10)
    >>> y = [5.0 + 0.1 * (-1) ** k + (3.0 if k >= 600 else 0.0) for k in range(700)]
    >>> flags = [(chk.step(v, True), chk.flagged)[1] for v in y]
    >>> flags.index(True) - 600, flags[-1]  # samples after the step; held
    (24, True)
    >>> chk.step(5.0, False), chk.flagged  # the plateau ends: a new one starts afresh
    (0.0, False)
    """

    def __init__(self, threshold: float = math.inf, config: RuntimeConfig | None = None,
                 fs: float = FS, anchored: bool = False) -> None:
        c = config or RuntimeConfig()
        self.threshold = threshold
        self.anchored = anchored
        self.n_settle = int(round(c.step_settle_s * fs))
        self.n_short = max(1, int(round(c.step_short_s * fs)))
        self.n_long = max(1, int(round(c.step_long_s * fs)))
        self.alpha = 2.0 / (c.step_noise_s * fs + 1.0)
        self.persist = max(1, int(round(c.step_persist_s * fs)))
        self.reset()

    def reset(self) -> None:
        self._win: deque[complex] = deque()
        self._frozen = False  # anchored, and the plateau's first long window is complete
        self._age = 0
        self._sum_short: complex = 0.0
        self._sum_long: complex = 0.0
        self._last: complex = math.nan
        self._var = 0.0
        self._ndiff = 0
        self._beyond = 0
        self.flagged = False

    def step(self, value: complex, steady: bool) -> float:
        if not steady:
            if self._age:
                self.reset()
            return 0.0
        self._age += 1
        if self._age <= self.n_settle:
            return 0.0
        if _isnan(value):
            value = self._last
            if _isnan(value):
                return 0.0
        if not _isnan(self._last):
            d = value - self._last  # squared by products: a huge value gives inf, where ** raises
            d2 = 0.5 * (d.real * d.real + d.imag * d.imag)
            if self._ndiff >= self.n_long:  # clip outliers (the step itself) out of the noise
                d2 = min(d2, 25.0 * self._var)
            self._ndiff += 1
            a = max(self.alpha, 1.0 / self._ndiff)
            self._var += a * (d2 - self._var)
        self._last = value
        win = self._win
        win.append(value)
        self._sum_short += value
        if len(win) > self.n_short:
            moved = win[-self.n_short - 1]
            self._sum_short -= moved
            if not self._frozen:
                self._sum_long += moved
        if len(win) > self.n_short + self.n_long:
            old = win.popleft()
            if not self._frozen:
                self._sum_long -= old
        if self.anchored and len(win) == self.n_short + self.n_long:
            self._frozen = True
        z = 0.0
        if len(win) == self.n_short + self.n_long and self._var > 0.0:
            diff = self._sum_short / self.n_short - self._sum_long / self.n_long
            z = abs(diff) / math.sqrt(self._var)
        self._beyond = self._beyond + 1 if z > self.threshold else 0
        self.flagged = self.flagged or self._beyond >= self.persist  # holds to the plateau's end
        return z


class FlatlineCheck:
    """Stateful stuck-sensor check: ``step(value, running) -> True`` while the line is flat.

    Flat: the same value repeated ``limit`` times in a row while the engine runs; NaN
    (dropouts) neither extend nor break the line, stopping the engine does.

    >>> chk = FlatlineCheck(limit=3)
    >>> [chk.step(v, True) for v in (1.0, 2.0, 2.0, float("nan"), 2.0, 2.0, 3.0)]
    [False, False, False, False, False, True, False]
    """

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


class EpisodeLog:
    """Alarm episodes of a monitor stream: alarm samples of one rule less than ``gap_s`` apart.

    ``episodes``: list of dicts {"key", "start", "end", "reason"} (times in s, the first
    alarm sample's reason).

    >>> from node.contract import Reason
    >>> log = EpisodeLog(gap_s=1.0)
    >>> for t in (10.0, 10.5, 12.0):
    ...     log.add("k", {"t": t, "flag": Flag.ALARM, "reason": Reason.STEP})
    >>> [(e["start"], e["end"]) for e in log.episodes]
    [(10.0, 10.5), (12.0, 12.0)]
    """

    def __init__(self, gap_s: float = RuntimeConfig.episode_gap_s) -> None:
        self.gap_s = gap_s
        self.episodes: list[dict] = []
        self._open: dict[str, dict] = {}

    def add(self, key: str, msg: dict) -> None:
        if msg.get("flag") != Flag.ALARM:
            return
        t = float(msg["t"])
        ep = self._open.get(key)
        if ep is not None and t - ep["end"] <= self.gap_s and ep["reason"] == msg.get("reason"):
            ep["end"] = t
            return
        ep = {"key": key, "start": t, "end": t, "reason": msg.get("reason")}
        self._open[key] = ep
        self.episodes.append(ep)
