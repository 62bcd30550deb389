"""Held-out evaluation of a trained switching model, the way the node runs it:
per OC segment, seeded from the measured past, free run across the OC.

Every segment is scored, the start (the first OC's transition from light-off) and the
rundown included: a sample without a prediction (no model for the segment, or its inputs
not yet seen) is a miss, its error its measured value (``SegmentPrediction.scored``), and
each OC's coverage (the share of its samples predicted) is reported beside its eps_td.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from node.contract import FS
from node.contract.errors import OrdervibError
from node.contract.schedule import Schedule
from node.models.baseline import CharacteristicCurve
from node.models.config import RuntimeConfig
from node.models.envelope import OUTSIDE
from node.models.ocmodel import Trajectory
from node.models.result import OCResult
from node.runtime.chirp import CHIRP_RATE, add_chirp_rate, chirp_rate_column
from node.runtime.guard import guard_of, guard_segment
from node.runtime.history import HISTORY_CHANNELS
from node.runtime.runcurve import RUN_CURVE, add_run_curve, hold_last
from node.sysid.metrics import pooled_eps
from node.training.calibrate import alarm_mask
from node.training.dataset import (
    first_seen,
    label_runs,
    run_arrays,
    segment_runs,
    target_vectors,
    with_history,
)
from node.training.plateau_fit import shifted, visit_tables
from node.training.runs import Run


@dataclass
class SegmentPrediction:
    run: int
    oc: int
    t: np.ndarray  # (K,) s
    measured: np.ndarray  # (K,)
    predicted: np.ndarray  # (K,)
    envelope: np.ndarray | None = None  # (K,) the model's envelope value (None: the model has none)
    guarded: np.ndarray | None = None  # (K,) bool: predicted with the curve (None: no guard)

    @property
    def scored(self) -> np.ndarray:
        """(K,) the prediction as scored: a sample without one (NaN) a miss, predicted 0."""
        return np.where(np.isfinite(self.predicted), self.predicted, 0.0)

    @property
    def covered(self) -> int:
        """Samples with a prediction."""
        return int(np.count_nonzero(np.isfinite(self.predicted)))

    def widened(self, res: OCResult) -> np.ndarray:
        """(K,) the residual over the band's widening (``Envelope.band_factor`` where outside)."""
        r = self.measured - self.predicted
        if self.envelope is None or res.envelope is None:
            return r
        return np.where(self.envelope > OUTSIDE, r / res.envelope.band_factor, r)


@dataclass
class OCEvaluation:
    name: str
    eps: float  # pooled over every sample of the segments evaluated (a miss: see the module); nan: none
    n_segments: int
    alarm_samples: int  # samples flagged (persistent smoothed score beyond threshold)
    samples: int
    outside: int = 0  # samples beyond the model's envelope (predicted with its inputs held at the edge)
    guarded: int = 0  # samples the curve guard predicted with the characteristic curve
    predicted: int = 0  # samples with a prediction

    @property
    def coverage(self) -> float:
        """The share of the samples with a prediction (nan: no sample)."""
        return self.predicted / self.samples if self.samples else float("nan")


def derived_runs(runs: list[Run], schedule: Schedule, target: str, channels: list[str],
                 fleet: tuple[np.ndarray, np.ndarray] | None, config: RuntimeConfig) -> list[Run]:
    """``runs`` with the derived channels among ``channels`` appended as the node derives them:
    ``run_curve`` (needs the bundle's characteristic curve ``fleet``), the engine history
    (``HISTORY_CHANNELS``: ``runs`` are one engine's, see ``with_history``) and ``chirp_rate``."""
    if RUN_CURVE in channels:
        if fleet is None:
            raise OrdervibError("the model takes run_curve but has no characteristic curve")
        runs = [add_run_curve(r, schedule, target, fleet) for r in runs]
    if any(c in HISTORY_CHANNELS for c in channels):
        runs = with_history(runs, schedule, config)
    if CHIRP_RATE in channels:
        runs = [add_chirp_rate(r, schedule.switch) for r in runs]
    return runs


def predict_segments(results: list[OCResult], runs: list[Run], schedule: Schedule,
                     target: str, fleet: tuple[np.ndarray, np.ndarray] | None = None,
                     config: RuntimeConfig | None = None) -> list[SegmentPrediction]:
    """Free-run predictions of every segment found in ``runs`` (each OC's, the rundown's, the
    start's: ``Schedule.models``, ``oc`` their index), predicted NaN where its OC has no model
    (a miss when scored).

    fleet: the bundle's characteristic curve, needed when a model takes ``run_curve``.
    config: the bundle's settings (the measured past seeding each segment, ``history_s``;
    the engine history's cooling, when a model takes its channels: ``runs`` are then one
    engine's, in time order, its history derived from them as the node derives it; the curve
    guard, ``node.runtime.guard``, stepped as the node steps it, on ``fleet``).
    """
    config = config or RuntimeConfig()
    by_oc = {schedule.index(r.name): r for r in results if r.model is not None}
    out = []
    hist = int(config.history_s * FS)
    inputs_needed = sorted({c for r in by_oc.values() for c in r.inputs})
    runs = derived_runs(runs, schedule, target, inputs_needed, fleet, config)
    arrays = [run_arrays(run, target, inputs_needed) for run in runs]
    vectors = [target_vectors(run, target) for run in runs]
    guard = guard_of(fleet, config)
    if guard is not None:  # what the node sees: the target as measured, the switch speed held
        seen = [(run.column(target), hold_last(run.column(schedule.switch))) for run in runs]
    labels = label_runs(runs, schedule, models=True)  # (as the node switches its models)
    shifts = [r.plateau for r in by_oc.values() if r.plateau is not None]
    visits = visit_tables(runs, [codes for codes, _ in labels], target, len(schedule.names),
                          shifts[0].vector) if shifts else None  # the run's plateaus, as the node's
    for s in segment_runs(runs, schedule, labels=labels):
        res = by_oc.get(s.oc)
        ra = arrays[s.run]
        if res is None or res.model is None:
            out.append(SegmentPrediction(s.run, s.oc, runs[s.run].t[s.start:s.stop], ra.y[s.start:s.stop],
                                         np.full(s.stop - s.start, np.nan)))
            continue
        cols = [inputs_needed.index(c) for c in res.inputs]
        # the measured past as the node seeds from it: from the first row holding every channel
        lo = min(max(0, s.start - hist, first_seen(runs[s.run], [target, *res.inputs])), s.start)
        z = vectors[s.run]
        U = ra.U[lo:s.stop][:, cols]
        env = None
        if res.envelope is not None:  # as the node: from the switch on, inputs held at its edge
            seg = U[s.start - lo:]
            env = res.envelope.distances(seg, np.arange(len(seg)) / FS)
            U = np.concatenate([U[:s.start - lo], res.envelope.clamp_rows(seg)])
        traj = Trajectory(ra.y[lo:s.stop], U, s.start - lo, None if z is None else z[lo:s.stop])
        with np.errstate(all="ignore"):
            pred = res.model.predict(traj)
        if visits is not None and res.plateau is not None and (v := visits[s.run].get(s.start)) is not None:
            pred = shifted(pred, res.plateau.shift(v[0], v[1]))
        if res.settle is not None:  # on the target as measured (NaN in a gap), as the node
            pred = res.settle.moved(runs[s.run].column(target)[s.start:s.stop], pred)
        # as the node: no prediction (nor guard) before every input has been seen in the run
        k0 = min(max(0, first_seen(runs[s.run], res.inputs) - s.start), s.stop - s.start)
        if k0:
            pred = np.concatenate([np.full(k0, np.nan), pred[k0:]])
        used = None
        if guard is not None:
            y, speed = seen[s.run]
            guarded, on = guard_segment(guard, y[s.start + k0:s.stop], pred[k0:], speed[s.start + k0:s.stop])
            pred = np.concatenate([pred[:k0], guarded])
            used = np.concatenate([np.zeros(k0, dtype=bool), on])
        out.append(SegmentPrediction(s.run, s.oc, runs[s.run].t[s.start:s.stop], traj.seg_y, pred, env,
                                     used))
    return out


def evaluate(results: list[OCResult], runs: list[Run], schedule: Schedule,
             target: str, fleet: tuple[np.ndarray, np.ndarray] | None = None,
             config: RuntimeConfig | None = None
             ) -> tuple[list[OCEvaluation], list[SegmentPrediction]]:
    """Per-OC eps and alarm samples over ``runs`` (``score_segments``), and the predictions
    (see ``predict_segments``)."""
    preds = predict_segments(results, runs, schedule, target, fleet, config)
    return score_segments(results, schedule, preds), preds


def score_segments(results: list[OCResult], schedule: Schedule, preds: list[SegmentPrediction]
                   ) -> list[OCEvaluation]:
    """Per OC (schedule order), then the rundown (``Schedule.segments``): eps pooled over every
    sample of the segments of ``preds`` (a sample without a prediction a miss: ``scored_pairs``;
    the first OC's with its start's, ``pooled``), the share predicted, and the samples the alarm
    rule flags there, each by its own model's rule (e.g. only the held-out runs' predictions:
    see ``node.training.provenance``)."""
    by_name = {r.name: r for r in results}
    out = []
    for j, name in enumerate(schedule.segments):
        mine = [p for p in preds if p.oc in pooled(schedule, j)]
        res = by_name.get(name)
        samples = sum(p.t.size for p in mine)
        covered = sum(p.covered for p in mine)
        eps = pooled_eps(scored_pairs(mine)) if mine else float("nan")
        if not mine or res is None or res.calibration is None:
            out.append(OCEvaluation(name, eps, len(mine), 0, samples, predicted=covered))
            continue
        alarms = _alarm_samples(by_name, schedule, mine)
        outside = sum(int(np.sum(p.envelope > OUTSIDE)) for p in mine if p.envelope is not None)
        guarded = sum(int(np.sum(p.guarded)) for p in mine if p.guarded is not None)
        out.append(OCEvaluation(name, eps, len(mine), alarms, samples, outside, guarded, covered))
    return out


def pooled(schedule: Schedule, j: int) -> tuple[int, ...]:
    """The model indices (``Schedule.models``) whose segments segment ``j`` (``Schedule.segments``)
    pools: the first OC's with its start's (the contract's first OC holds its start).

    >>> from node.contract.schedule import OperatingCondition
    >>> s = Schedule((OperatingCondition("A", 4000.0), OperatingCondition("B", 6000.0)))
    >>> pooled(s, 0), pooled(s, 2)
    ((0, 3), (2,))
    """
    return (j, schedule.start) if j == 0 else (j,)


def start_evaluation(results: list[OCResult], schedule: Schedule, preds: list[SegmentPrediction]
                     ) -> OCEvaluation | None:
    """The start's part of the first OC (its own model, ``Schedule.start``) scored alone, as
    ``score_segments`` scores an OC; None: no start in ``preds``."""
    mine = [p for p in preds if p.oc == schedule.start]
    if not mine:
        return None
    alarms = _alarm_samples({r.name: r for r in results}, schedule, mine)
    return OCEvaluation(schedule.models[schedule.start], pooled_eps(scored_pairs(mine)), len(mine), alarms,
                        sum(p.t.size for p in mine), predicted=sum(p.covered for p in mine))


def _alarm_samples(by_name: dict[str, OCResult], schedule: Schedule, preds: list[SegmentPrediction]) -> int:
    """The samples of ``preds`` the alarm rule flags, each segment by its own model's rule."""
    n = 0
    for p in preds:
        res = by_name.get(schedule.models[p.oc])
        if res is not None and res.calibration is not None:
            n += int(alarm_mask(p.widened(res), res).sum())
    return n


def scored_pairs(preds: list[SegmentPrediction]) -> list[tuple[np.ndarray, np.ndarray]]:
    """(measured, prediction as scored) of each of ``preds`` over its measured samples: the one
    rule of scoring, a sample without a prediction a miss (``SegmentPrediction.scored``)."""
    out = []
    for p in preds:
        ok = np.isfinite(p.measured)
        out.append((p.measured, p.scored) if ok.all() else (p.measured[ok], p.scored[ok]))
    return out


def coverage(runs: list[Run], schedule: Schedule, preds: list[SegmentPrediction],
             config: RuntimeConfig | None = None) -> tuple[int, int]:
    """(samples predicted, samples) from light-off to standstill: each run's samples from the
    first to the last whose switch speed is at or above the off level (the OC detector's,
    ``config``'s), and of them those with a prediction in ``preds`` (predictions of ``runs``)."""
    from node.runtime.ocdetect import OCDetector

    off = OCDetector(schedule, config).off_level
    done = [np.zeros(len(r.t), dtype=bool) for r in runs]
    for p in preds:
        k0 = int(np.searchsorted(runs[p.run].t, p.t[0])) if p.t.size else 0
        done[p.run][k0:k0 + p.t.size] |= np.isfinite(p.predicted)
    predicted = total = 0
    for run, d in zip(runs, done):
        on = np.flatnonzero(np.nan_to_num(run.column(schedule.switch), nan=-np.inf) >= off)
        if on.size:
            predicted += int(d[on[0]:on[-1] + 1].sum())
            total += int(on[-1] + 1 - on[0])
    return predicted, total


def baseline_eps(train_runs: list[Run], test_runs: list[Run], schedule: Schedule,
                 target: str) -> list[float]:
    """Per-OC eps_td of the characteristic-curve baseline fitted on the training runs (every OC,
    then the rundown: ``Schedule.segments``)."""
    sw = schedule.switch
    tr = [run_arrays(r, target, [sw]) for r in train_runs]
    cc = CharacteristicCurve().fit(np.concatenate([a.U[:, 0] for a in tr]),
                                   np.concatenate([a.y for a in tr]))
    te = [run_arrays(r, target, [sw]) for r in test_runs]
    segs = segment_runs(test_runs, schedule)  # (by OC: the first's with its start)
    out = []
    for j in range(len(schedule.segments)):
        pairs = [(te[s.run].y[s.start:s.stop], cc.predict(te[s.run].U[s.start:s.stop, 0]))
                 for s in segs if s.oc == j]
        out.append(pooled_eps(pairs) if pairs else float("nan"))
    return out


def curve_predictions(curve: tuple[np.ndarray, np.ndarray], runs: list[Run],
                      preds: list[SegmentPrediction], switch: str, target: str) -> list[np.ndarray]:
    """A bundle's characteristic curve ``(speeds, means)`` over each prediction's segment, at the
    switch speed the run measured there: one (K,) array per prediction."""
    cc = CharacteristicCurve()
    cc.centres_, cc.means_ = curve
    arrays = [run_arrays(r, target, [switch]) for r in runs]
    out = []
    for p in preds:
        k0 = int(np.searchsorted(runs[p.run].t, p.t[0]))
        out.append(cc.predict(arrays[p.run].U[k0:k0 + p.t.size, 0]))
    return out


def curve_eps(curve: tuple[np.ndarray, np.ndarray], runs: list[Run], preds: list[SegmentPrediction],
              schedule: Schedule, target: str) -> list[float]:
    """Per OC (schedule order, then the rundown) the eps_td of a bundle's characteristic curve over
    the segments of ``preds`` (the same samples as the model's, see ``curve_predictions``); nan
    where none."""
    base = curve_predictions(curve, runs, preds, schedule.switch, target)
    return baseline_segment_eps(schedule, preds, base)


DIRECTION_RPM_S = 10.0  # a sample is on a rising (falling) speed above (below) +- this rate, rpm/s


@dataclass(frozen=True)
class DirectionCurves:
    """The characteristic curve by direction: the training runs' mean target per switch speed
    over their samples on a rising speed (``up``), on a falling one (``down``), and over every
    sample (``every``: for a steady sample, and where a direction's curve has no bin within
    ``reach`` rpm). The direction is the chirp rate's (``node.runtime.chirp``, causal, 1 s)
    beyond ``DIRECTION_RPM_S``: a run-up and a coast-down differ (the tracker's lag, the bow).

    >>> speed = np.r_[np.linspace(0.0, 1000.0, 400), np.linspace(1000.0, 0.0, 400)]
    >>> y = np.r_[np.full(400, 1.0), np.full(400, 3.0)]
    >>> run = Run(np.arange(800) / FS, np.column_stack([speed, y]), ("nB", "yB"), "bed1", None)
    >>> c = DirectionCurves.fit([run], "nB", "yB")
    >>> c.predict(np.array([500.0, 500.0, 500.0]), np.array([100.0, -100.0, 0.0])).round(2).tolist()
    [1.0, 3.0, 2.0]
    """

    up: CharacteristicCurve | None
    down: CharacteristicCurve | None
    every: CharacteristicCurve
    reach: float = 100.0

    @classmethod
    def fit(cls, runs: list[Run], switch: str, target: str, bin_width: float = 25.0) -> DirectionCurves:
        """From training ``runs`` holding ``switch`` and ``target``."""
        speed, y, rate = [], [], []
        for r in runs:
            a = run_arrays(r, target, [switch])
            speed.append(a.U[:, 0])
            y.append(np.where(a.valid, a.y, np.nan))
            rate.append(chirp_rate_column(r.column(switch)))
        s, v, d = np.concatenate(speed), np.concatenate(y), np.concatenate(rate)

        def curve(mask: np.ndarray) -> CharacteristicCurve | None:
            ok = mask & np.isfinite(v) & np.isfinite(s)
            return CharacteristicCurve(bin_width).fit(s[ok], v[ok]) if ok.sum() >= 2 else None

        with np.errstate(invalid="ignore"):
            up, down = curve(d > DIRECTION_RPM_S), curve(d < -DIRECTION_RPM_S)
        every = curve(np.ones(s.size, dtype=bool))
        if every is None:
            raise OrdervibError(f"no finite ({switch}, {target}) pairs to fit a characteristic curve")
        return cls(up, down, every, 4 * bin_width)

    def predict(self, speed: np.ndarray, rate: np.ndarray) -> np.ndarray:
        """The curve of each sample's direction at its speed: speed, rate (K,) rpm, rpm/s -> (K,)."""
        s = np.asarray(speed, float)
        out = self.every.predict(s)
        with np.errstate(invalid="ignore"):
            for c, mine in ((self.up, rate > DIRECTION_RPM_S), (self.down, rate < -DIRECTION_RPM_S)):
                if c is None:
                    continue
                use = mine & (_gap(c.centres_, s) <= self.reach)
                out = np.where(use, c.predict(s), out)
        return out

    def over(self, runs: list[Run], preds: list[SegmentPrediction], switch: str) -> list[np.ndarray]:
        """The curve by direction over each prediction's segment (the samples of ``preds``, of
        ``runs``): one (K,) array per prediction."""
        rates = [chirp_rate_column(r.column(switch)) for r in runs]
        speeds = [hold_last(r.column(switch)) for r in runs]
        out = []
        for p in preds:
            k0 = int(np.searchsorted(runs[p.run].t, p.t[0]))
            part = slice(k0, k0 + p.t.size)
            out.append(self.predict(speeds[p.run][part], rates[p.run][part]))
        return out


def _gap(centres: np.ndarray, speed: np.ndarray) -> np.ndarray:
    """(K,) rpm from each ``speed`` (K,) to the nearest of the sorted ``centres`` (B,), B >= 1."""
    i = np.searchsorted(centres, speed)
    below = centres[np.clip(i - 1, 0, centres.size - 1)]
    above = centres[np.clip(i, 0, centres.size - 1)]
    return np.minimum(np.abs(speed - below), np.abs(above - speed))


def baseline_segment_eps(schedule: Schedule, preds: list[SegmentPrediction], base: list[np.ndarray]
                         ) -> list[float]:
    """Per segment (``Schedule.segments``: the first OC's with its start's) the eps_td of a
    baseline ``base`` (one (K,) array per prediction of ``preds``) over the measured samples."""
    out = []
    for j in range(len(schedule.segments)):
        mine = [(p.measured, b) for p, b in zip(preds, base) if p.oc in pooled(schedule, j)]
        num = sum(float(np.sum((m - b) ** 2)) for m, b in mine)
        den = sum(float(np.sum(m ** 2)) for m, _ in mine)
        out.append(float(np.sqrt(num / den)) if den else float("nan"))
    return out
