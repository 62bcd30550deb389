"""The fitted aids of a prediction (``node.training.prediction``), learned from training runs.

* :class:`InputFill`: the channels a profile lacks, as the training runs had them at the
  planned speed and OC.
* :class:`AmplitudeBound`: the upper bound of a predicted amplitude, from the largest the
  training runs measured near the speed in the same OC.
* :class:`IntervalWidths`: the interval of a prediction for a new run, from the chained
  prediction's residuals on training runs (or the OC models' CV residuals alone).
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from node.contract import FS
from node.contract.schedule import Schedule
from node.models.baseline import bin_sums
from node.models.bundle import Bundle, Model, as_model
from node.runtime.runcurve import hold_last
from node.training.dataset import Segment, segment_runs
from node.training.runs import Run

# -- filling inputs the profile lacks ------------------------------------------------------------
FILL_BIN_RPM = 50.0  # speed bins of the fill's curves, rpm
FILL_MIN_SAMPLES = 10  # training samples a bin of an OC's own curve needs (a quarter second)


def _binned(speed: np.ndarray, x: np.ndarray, min_samples: int) -> tuple[np.ndarray, np.ndarray] | None:
    """Mean of x per FILL_BIN_RPM bin of speed over bins holding ``min_samples`` or more finite
    pairs: (centres (B,) rpm, means (B,)); None when no bin does. speed, x: (K,)."""
    ok = np.isfinite(speed) & np.isfinite(x)
    if not ok.any():
        return None
    bins, sums, counts = bin_sums(speed[ok], x[ok], FILL_BIN_RPM)
    keep = counts >= min_samples
    if not keep.any():
        return None
    return (bins[keep] + 0.5) * FILL_BIN_RPM, sums[keep] / counts[keep]


def _along(speed: np.ndarray, own: tuple[np.ndarray, np.ndarray],
           whole: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """An OC's curve at ``speed`` (K,) rpm: interpolated within the speeds its training samples
    reached; beyond them, its value at the nearest such speed moved along the all-runs curve
    ``whole`` (so that it still follows the speed). Returns (values (K,), within (K,) bool)."""
    centres, means = own
    out = np.interp(speed, centres, means)
    lo, hi = float(centres[0]), float(centres[-1])
    below, above = speed < lo, speed > hi
    if below.any():
        out[below] += np.interp(speed[below], *whole) - float(np.interp(lo, *whole))
    if above.any():
        out[above] += np.interp(speed[above], *whole) - float(np.interp(hi, *whole))
    return out, ~(below | above)


@dataclass
class InputFill:
    """Channels a profile lacks, as the training runs had them at the planned speed and OC.

    A filled channel follows the plan's switch speed, never the time alone: inside an OC (as
    ``segment_runs`` cuts the profile), the OC's own curve of the channel against the switch
    speed (the training runs' mean in FILL_BIN_RPM bins over that OC's segments, interpolated;
    beyond the speeds they reached, moved along the all-runs curve), plus, on the plateau, the
    training runs' mean deviation from that curve at each whole second since the plateau's
    start (the thermal drift a plateau brings; held beyond the longest); outside every OC, the
    all-runs curve.

    speed_curves: per channel, its curve over every training sample (centres (B,) rpm, means
    (B,)); oc_curves: per channel, per OC index, the curve over that OC's segments; drifts: per
    channel, per OC index, the mean deviation (L,) at each second since the plateau's start;
    runs: the training runs it was learned from; source: where they came from (for the notes).
    """

    switch: str
    speed_curves: dict[str, tuple[np.ndarray, np.ndarray]]
    oc_curves: dict[str, dict[int, tuple[np.ndarray, np.ndarray]]] = dataclasses.field(default_factory=dict)
    drifts: dict[str, dict[int, np.ndarray]] = dataclasses.field(default_factory=dict)
    runs: int = 0
    source: str = "training runs"

    @property
    def channels(self) -> tuple[str, ...]:
        return tuple(self.speed_curves)

    @classmethod
    def fit(cls, runs: list[Run], schedule: Schedule, channels: Sequence[str],
            source: str = "training runs") -> InputFill:
        """From training runs holding the switch and ``channels`` (those some run lacks are left
        out: ``channels`` tells what was learned); ``source`` names them in the notes."""
        sw = schedule.switch
        have = [c for c in channels if c != sw and all(c in r.channels for r in runs)]
        segs = segment_runs(runs, schedule, min_samples=1)
        speeds = [hold_last(np.asarray(r.column(sw), float)) for r in runs]
        curves: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        oc_curves: dict[str, dict[int, tuple[np.ndarray, np.ndarray]]] = {}
        drifts: dict[str, dict[int, np.ndarray]] = {}
        by_oc: dict[int, list[Segment]] = {}
        for s in segs:
            by_oc.setdefault(s.oc, []).append(s)
        for c in have:
            vals = [np.asarray(r.column(c), float) for r in runs]
            whole = _binned(np.concatenate(speeds), np.concatenate(vals), 1)
            if whole is None:
                continue
            curves[c] = whole
            oc_curves[c], drifts[c] = {}, {}
            for oc, mine in by_oc.items():
                own = _binned(np.concatenate([speeds[s.run][s.start:s.stop] for s in mine]),
                              np.concatenate([vals[s.run][s.start:s.stop] for s in mine]), FILL_MIN_SAMPLES)
                if own is None:
                    continue
                oc_curves[c][oc] = own
                parts = []
                for s in mine:
                    if s.steady_start >= s.stop:
                        continue
                    sl = slice(s.steady_start, s.stop)
                    dev = vals[s.run][sl] - _along(speeds[s.run][sl], own, whole)[0]
                    parts.append(_per_second(dev))
                if parts:
                    drifts[c][oc] = _mean_track(parts)
        return cls(sw, curves, oc_curves, drifts, len(runs), source)

    def fill(self, run: Run, schedule: Schedule, channel: str) -> np.ndarray:
        """The channel over a run (K,) from its switch speed and OCs (as segment_runs cuts them)."""
        return self.fill_parts(run, schedule, channel)[0]

    def fill_parts(self, run: Run, schedule: Schedule, channel: str,
                   segments: list[Segment] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``fill`` and where each sample came from: (values (K,), own (K,) bool: from its OC's
        own curve within the speeds that OC's training samples reached). segments: the run's
        (``segment_runs([run], schedule, min_samples=1)``; None: cut here)."""
        speed = np.nan_to_num(hold_last(np.asarray(run.column(self.switch), float)), nan=0.0)
        whole = self.speed_curves[channel]
        out = np.interp(speed, *whole)
        own = np.zeros(speed.size, dtype=bool)
        segs = segment_runs([run], schedule, min_samples=1) if segments is None else segments
        for s in segs:
            curve = self.oc_curves.get(channel, {}).get(s.oc)
            if curve is None:
                continue
            sl = slice(s.start, s.stop)
            out[sl], own[sl] = _along(speed[sl], curve, whole)
            drift = self.drifts.get(channel, {}).get(s.oc)
            if drift is not None and drift.size and s.steady_start < s.stop:
                sec = np.minimum(np.arange(s.stop - s.steady_start) // int(FS), drift.size - 1)
                out[s.steady_start:s.stop] += drift[sec]
        return out, own

    def describe(self, channel: str) -> str:
        """How ``channel`` is filled, in a line (for the CSV's notes and the plot)."""
        return (f"from the {self.runs} {self.source}: in each OC, their mean at the planned {self.switch} "
                f"({FILL_BIN_RPM:g} rpm bins of that OC's samples) plus their mean drift on the plateau "
                f"by second since its start; outside the OCs, their mean at {self.switch} over all samples")


def _per_second(x: np.ndarray) -> np.ndarray:
    """Mean of x (K,) over each whole second (40 samples), NaN-aware: (ceil(K / 40),)."""
    sec = np.arange(x.size) // int(FS)
    ok = np.isfinite(x)
    n = np.bincount(sec[ok], minlength=int(sec[-1]) + 1)
    tot = np.bincount(sec[ok], weights=x[ok], minlength=int(sec[-1]) + 1)
    return np.where(n > 0, tot / np.maximum(n, 1), np.nan)


def _mean_track(parts: list[np.ndarray]) -> np.ndarray:
    """Mean over segments of per-second means (each (L_i,)), NaN-aware; held over gaps."""
    L = max(p.size for p in parts)
    stack = np.full((len(parts), L), np.nan)
    for i, p in enumerate(parts):
        stack[i, :p.size] = p
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a second no segment reached
        mean = np.nanmean(stack, axis=0)
    held = hold_last(mean)
    first = np.flatnonzero(np.isfinite(held))
    if first.size:
        held[: first[0]] = held[first[0]]
    return held


# -- predictions within physics: the bound and the interval ------------------------------------------
BOUND_FACTOR = 1.5  # the upper bound: this many times the training runs' largest amplitude ...
BOUND_WINDOW_RPM = 100.0  # ... in the same OC within this many rpm of the speed
BOUND_STEP_RPM = 5.0  # rpm: the resolution of the bound's speed window
INTERVAL_LEVEL = 0.90  # the interval's coverage for a new run


@dataclass(frozen=True)
class AmplitudeBound:
    """The upper bound of each target's predicted amplitude, from the training runs' measurements.

    The rule: ``factor`` x the largest amplitude the training runs measured in the same OC (as
    ``segment_runs`` cuts them) within ``window`` rpm of the speed (speeds taken in
    BOUND_STEP_RPM steps: rounded to 5 rpm, the window inclusive); where that OC's training
    samples never came that close, the largest of any training sample within the window;
    where none did, the OC's largest at any speed (an OC never trained: the largest of all).

    near (n, O + 1, S): the largest measured within the window of each BOUND_STEP_RPM speed step
    from 0 rpm (row O: of any OC; NaN: none there), mm/s; oc_top (n, O): each OC's largest,
    top (n,): the largest of all (NaN: never measured); runs: the training runs.
    """

    targets: tuple[str, ...]
    near: np.ndarray
    oc_top: np.ndarray
    top: np.ndarray
    factor: float = BOUND_FACTOR
    window: float = BOUND_WINDOW_RPM
    runs: int = 0

    @classmethod
    def fit(cls, runs: list[Run], schedule: Schedule, targets: Sequence[str], factor: float = BOUND_FACTOR,
            window: float = BOUND_WINDOW_RPM) -> AmplitudeBound:
        """From training runs (a target some run lacks is left out of those runs)."""
        sw, O = schedule.switch, len(schedule.names)
        speeds = [np.asarray(r.column(sw), float) for r in runs]
        labels = [np.full(len(r.t), O, dtype=np.int64) for r in runs]
        for s in segment_runs(runs, schedule):
            labels[s.run][s.start:s.stop] = s.oc
        w = int(round(window / BOUND_STEP_RPM))
        top_speed = max((float(np.nanmax(v)) for v in speeds if np.isfinite(v).any()), default=0.0)
        steps = int(max(top_speed, 0.0) // BOUND_STEP_RPM) + 2 + w
        near = np.full((len(targets), O + 1, steps), np.nan)
        for j, tg in enumerate(targets):
            raw = np.full((O + 1, steps), -np.inf)
            for r, run in enumerate(runs):
                if tg not in run.channels:
                    continue
                y = np.asarray(run.column(tg), float)
                ok = np.isfinite(y) & np.isfinite(speeds[r])  # a sample at an unknown speed is at none
                idx = np.clip((speeds[r][ok] / BOUND_STEP_RPM).round().astype(np.int64), 0, steps - 1)
                np.maximum.at(raw, (labels[r][ok], idx), y[ok])
                np.maximum.at(raw[O], idx, y[ok])
            padded = np.pad(raw, ((0, 0), (w, w)), constant_values=-np.inf)
            mx = np.lib.stride_tricks.sliding_window_view(padded, 2 * w + 1, axis=1).max(axis=2)
            near[j] = np.where(np.isfinite(mx), mx, np.nan)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # an OC never measured: NaN
            oc_top = np.nanmax(near[:, :O], axis=2) if steps else np.full((len(targets), O), np.nan)
            top = np.nanmax(near[:, O], axis=1) if steps else np.full(len(targets), np.nan)
        return cls(tuple(targets), near, oc_top, top, factor, window, len(runs))

    def limits(self, target: str, oc: int, speed: np.ndarray) -> np.ndarray:
        """The bound (K,) mm/s of ``target`` in OC ``oc`` (-1: outside every OC) at ``speed`` (K,)
        rpm, by the rule (NaN: the training runs never measured the target)."""
        j = self.targets.index(target)
        O = self.oc_top.shape[1]
        steps = self.near.shape[2]
        idx = (np.clip(np.nan_to_num(speed, nan=0.0), 0.0, None) / BOUND_STEP_RPM).round().astype(np.int64)
        beyond = idx >= steps  # faster than any training sample by more than the window
        idx = np.minimum(idx, steps - 1)
        mine = np.where(beyond, np.nan, self.near[j, oc if 0 <= oc < O else O, idx])
        anyone = np.where(beyond, np.nan, self.near[j, O, idx])
        last = self.oc_top[j, oc] if 0 <= oc < O and np.isfinite(self.oc_top[j, oc]) else self.top[j]
        return self.factor * np.where(np.isfinite(mine), mine, np.where(np.isfinite(anyone), anyone, last))

    def describe(self) -> str:
        """The rule in a line (for the CSV's notes and the plot)."""
        return (f"amplitudes >= 0 (a model of the 1x vector: its modulus), and <= {self.factor:g} x the "
                f"largest that {self.runs} training runs measured in the same OC within "
                f"{self.window:g} rpm (speeds in {BOUND_STEP_RPM:g} rpm steps; none there: of any OC within "
                f"{self.window:g} rpm; none either: the OC's largest)")


class _Chained(Protocol):
    """What ``IntervalWidths.from_recorded`` reads of a chained prediction
    (``node.training.prediction.Prediction``)."""

    @property
    def predicted(self) -> np.ndarray: ...  # (K, n) mm/s

    @property
    def oc(self) -> np.ndarray: ...  # (K,) the OC index (-1: none)


class Recorded(Protocol):
    """A recorded run's chained prediction against what it measured, as
    ``IntervalWidths.from_recorded`` reads it (``node.training.prediction.RecordedPrediction``)."""

    @property
    def prediction(self) -> _Chained: ...

    @property
    def measured(self) -> np.ndarray: ...  # (K, n) mm/s


@dataclass(frozen=True)
class IntervalWidths:
    """The interval of each target in each OC, mm/s: a prediction's interval is
    [max(0, pred + shift - half), min(pred + shift + half, the bound)], widened to hold pred.

    A plan's prediction starts each OC's model from the prediction before it, never from a
    measured level, so its error is mostly the run's own level (its imbalance, its bow), which
    a model seeded with the measured past (its cross-validation, ``Calibration.sigma``) never
    shows. ``from_recorded`` measures it on the chained prediction of each training run from its own
    profile, as a one-way random-effects model with the run as the unit: each run's residual in
    the OC is its level m_r (its mean residual there) plus a within-run part. Over the n runs
    that reached the OC (a second or more each): ``shift`` the mean of the m_r (the chain's
    bias there), ``between`` their SD (n - 1 degrees of freedom), ``within`` the pooled SD about
    each run's own level. A new run's residual is then shift + its level + its within part,
    and the half-width is t_{(1+level)/2, n-1} sqrt(between^2 (1 + 1/n) + within^2) (the
    Student-t prediction interval of a new group; before: the RMS residual about the
    prediction, which counts a bias as spread and the runs' own mean as known), at least
    the same factor times the CV sigma. ``from_cv``: the CV sigma times the normal quantile
    alone, no shift (no training runs at hand; narrower than a plan's error).

    half, shift, cv_sigma, chain_rms, between, within (n targets, O): mm/s (NaN: none;
    chain_rms: the RMS residual, for the record); runs (n, O): the training runs that reached
    each OC (0 with ``from_cv``).
    """

    targets: tuple[str, ...]
    half: np.ndarray
    cv_sigma: np.ndarray
    chain_rms: np.ndarray
    runs: np.ndarray
    level: float = INTERVAL_LEVEL
    shift: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 0)))
    between: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 0)))
    within: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 0)))

    @staticmethod
    def _sigmas(model: Model) -> np.ndarray:
        names = model.schedule.names
        out = np.full((len(model.bundles), len(names)), np.nan)
        for j, b in enumerate(model.bundles):
            for o, name in enumerate(names):
                r = b.oc(name)
                if r is not None and r.calibration is not None and r.model is not None:
                    out[j, o] = r.calibration.sigma
        return out

    @classmethod
    def from_cv(cls, model: Bundle | Model, level: float = INTERVAL_LEVEL) -> IntervalWidths:
        """The OC models' CV residual sigma times the normal quantile of ``level``."""
        from scipy.stats import norm

        m = as_model(model)
        sig = cls._sigmas(m)
        z = float(norm.ppf(0.5 + level / 2.0))
        nan = np.full_like(sig, np.nan)
        return cls(tuple(m.targets), z * sig, sig, nan, np.zeros(sig.shape, np.int64), level,
                   np.zeros_like(sig), nan, nan)

    @classmethod
    def from_recorded(cls, model: Bundle | Model, recs: Sequence[Recorded],
                      level: float = INTERVAL_LEVEL) -> IntervalWidths:
        """From recorded runs' chained predictions against what they measured
        (``node.training.prediction.predict_recorded_runs``; ``fit_interval_widths`` there
        predicts training runs and calls this)."""
        from scipy.stats import norm
        from scipy.stats import t as student

        m = as_model(model)
        sig = cls._sigmas(m)
        n, O = sig.shape
        levels: list[list[list[float]]] = [[[] for _ in range(O)] for _ in range(n)]
        ss_within, dof_within = np.zeros((n, O)), np.zeros((n, O))
        sq, count = np.zeros((n, O)), np.zeros((n, O))
        for rec in recs:
            p = rec.prediction
            for j in range(n):
                res = rec.measured[:, j] - p.predicted[:, j]
                ok = np.isfinite(res) & (p.oc >= 0)
                np.add.at(sq[j], p.oc[ok], res[ok] ** 2)
                np.add.at(count[j], p.oc[ok], 1)
                for o in np.unique(p.oc[ok]).tolist():
                    r = res[ok & (p.oc == o)]
                    if r.size < FS:  # a second or more
                        continue
                    levels[j][o].append(float(r.mean()))
                    ss_within[j, o] += float(np.sum((r - r.mean()) ** 2))
                    dof_within[j, o] += r.size - 1
        with np.errstate(invalid="ignore", divide="ignore"):
            rms = np.sqrt(sq / count)
            within = np.sqrt(ss_within / dof_within)
        reached = np.array([[len(levels[j][o]) for o in range(O)] for j in range(n)], np.int64).reshape(n, O)
        shift, between = np.zeros((n, O)), np.full((n, O), np.nan)
        for j in range(n):
            for o in range(O):
                if reached[j, o] >= 2:
                    shift[j, o] = float(np.mean(levels[j][o]))
                    between[j, o] = float(np.std(levels[j][o], ddof=1))
        few = reached < 2
        n_runs = np.maximum(reached, 2)
        factor = student.ppf(0.5 + level / 2.0, n_runs - 1)
        new_run = np.sqrt(between ** 2 * (1.0 + 1.0 / n_runs) + within ** 2)
        half = np.full((n, O), np.nan)
        half[~few] = (factor * np.fmax(new_run, sig))[~few]
        half[few] = float(norm.ppf(0.5 + level / 2.0)) * sig[few]
        shift[few] = 0.0
        return cls(tuple(m.targets), np.where(np.isfinite(sig), half, np.nan), sig, rms, reached, level,
                   np.where(np.isfinite(sig), shift, 0.0), between, within)

    def offsets(self) -> np.ndarray:
        """``shift`` (n, O), zeros where none was measured (a bundle of widths from before)."""
        return self.shift if self.shift.shape == self.half.shape else np.zeros(self.half.shape)

    def describe(self) -> str:
        """The rule in a line (for the CSV's notes and the plot)."""
        pct = f"{100 * self.level:g} %"
        if not self.runs.any():
            return (f"{pct} interval: prediction -/+ the normal quantile x the OC model's CV residual sigma "
                    "(no training runs at hand: narrower than a plan's error), at least 0")
        return (f"{pct} interval for a new run: the residuals of the chained prediction of the n training "
                "runs in that OC as run levels (each run's mean residual) plus a within-run part; centred on "
                "the prediction plus the runs' mean level, -/+ t_(n-1) x sqrt(SD of the run levels^2 "
                "(1 + 1/n) + within-run SD^2) (at least t_(n-1) x the OC model's CV residual sigma), widened "
                "to hold the prediction, at least 0, at most the bound")
