"""Calibration of the alarm rules (``node.runtime.alarms``) from training runs.

Training steps the very rule objects the node runs:

* residual: each cross-validated segment's peak |score| comes from a ``ResidualCheck``
  stepped over its held-out residual, divided by the ``RunScale`` the node would have
  had at the segment's start. Thresholds come from an alarm budget: the peaks of
  *every* OC are pooled (they are in sigma units already), a Gumbel law is fitted to
  them, and the level a normal segment exceeds with chance ``budget / segments_per_hour``
  is the threshold, never below ``THRESHOLD_MARGIN`` x the OC's own largest CV peak.
  Pooling a hundred peaks gives a far steadier tail than each OC's eight or so. That
  chance is further divided by ``CV_UNDERCOVERAGE``: normal runs in conditions the
  training runs never met exceed CV-calibrated levels several times more often than
  the CV runs themselves do.
* step: the ``StepCheck`` and ``OCDetector`` stepped over every training run; the
  steady plateaus' peak statistics, pooled, a Gumbel law and the same alarm budget.
* vector (recordings with the target's phase channel): the same on the order's 1x vector,
  twice: the sliding ``StepCheck`` (an abrupt change: an added imbalance, at any angle) and
  the one anchored at each plateau's start (a slow change: a mode's stiffness drifting in),
  each with half the rule's budget; the anchored one also per OC (``drift_thresholds``).
* flatline: ``FLATLINE_FACTOR`` x the longest repeat seen in training, at least
  ``FLATLINE_MIN_S``, so coarse quantisation on another test bed raises it.

>>> round(gumbel_quantile([1.0, 2.0, 3.0, 4.0], 0.01), 3)
6.007
>>> longest_repeat(np.array([1.0, 1.0, np.nan, 1.0, 2.0]), np.ones(5, dtype=bool))
2
>>> flatline_limit(30, FS)  # 4 x 30 repeats at 40 Hz, above the 2 s floor
120
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from node.contract import FS, Phase, phase_channel
from node.contract.vector import order_vectors
from node.models.config import RuntimeConfig
from node.models.result import Calibration, OCResult
from node.runtime.alarms import RUN_SCALE_PRIOR_OCS, ResidualCheck, RunScale, StepCheck
from node.runtime.ocdetect import OCDetector
from node.training.ocdata import OCData

FALSE_ALARMS_PER_HOUR = 0.5  # false-alarm budget on normal runs per hour (residual + step rules)
THRESHOLD_MARGIN = 1.25  # never below margin x an OC's largest CV peak score
# Leave-one-run-out CV over a handful of runs under-states how often a *new* run's residual
# peaks beyond a level: its held-out run is always close to the other training runs, while
# a new run may bring an ambient, a thermal state or an imbalance phase none of them had.
# New runs exceed a CV-calibrated level about 4 times as often as the CV runs do; the residual
# rule's per-segment chance is divided by it. (study: docs/tuning.md#cv_undercoverage)
CV_UNDERCOVERAGE = 4.0
# The anchored vector check's threshold per OC: DRIFT_OC_FACTOR x the largest peak of that OC's
# training plateaus (OCs with DRIFT_OC_MIN_PLATEAUS or more; others keep the pooled threshold).
# A plateau's normal drift differs much between OCs (the bow heals early in a run, the modes soften
# with the metal near a resonance): one pooled threshold is set by the driftiest OCs and is blind
# in the quiet ones. 2.5 is the most sensitive factor (stiffness onsets flagged within 60 s)
# whose normal plateaus flagged stay within the check's share of the false-alarm budget (0.125
# per hour, as ``calibrate_checks`` gives it). (study: docs/tuning.md#drift_oc_factor)
DRIFT_OC_FACTOR = 2.5
DRIFT_OC_MIN_PLATEAUS = 3
FLATLINE_MIN_S = 2.0  # a flat line shorter than this never alarms, s
FLATLINE_FACTOR = 4.0  # limit = factor x the longest repeat in the training runs
EULER_GAMMA = 0.5772156649
# The residual threshold's rule: "plug-in", a Gumbel law fitted to the CV segments' peaks; or
# "predictive", the level a new run's largest peak exceeds with the run's share of the budget,
# from the Gumbel law's posterior predictive over the training runs' largest CV peaks. Neither met
# the budget with 4 training runs; plug-in stays. (study: docs/tuning.md#threshold_rule)
THRESHOLD_RULE = "plug-in"  # or "predictive" (see above); plug-in: a Gumbel law on the segments' peaks


def gumbel_quantile(peaks: Sequence[float], p: float) -> float:
    """Level a Gumbel law fitted to ``peaks`` (method of moments) exceeds with chance ``p``."""
    x = np.asarray(peaks, dtype=float)
    beta = float(np.std(x)) * math.sqrt(6.0) / math.pi
    mu = float(np.mean(x)) - EULER_GAMMA * beta
    return mu - beta * math.log(-math.log(1.0 - p))


def predictive_gumbel_level(maxima: Sequence[float], alpha: float, grid: int = 80) -> float:
    """Level a new run's largest peak exceeds with chance ``alpha``, given the training runs'
    largest peaks (one a run): the Gumbel law's posterior predictive (prior 1 / beta, on a grid
    of location and log scale), so that few runs give a higher level than the plug-in fit.

    >>> m = [3.1, 3.6, 2.8, 4.0]
    >>> predictive_gumbel_level(m, 0.05) > gumbel_quantile(m, 0.05)
    True
    >>> predictive_gumbel_level(m * 10, 0.05) < predictive_gumbel_level(m, 0.05)  # more runs: lower
    True
    """
    x = np.asarray(maxima, dtype=float)
    x = x[np.isfinite(x)]
    if len(x) < 2:
        raise ValueError("a predictive level needs the maxima of at least two runs")
    sd = max(float(np.std(x)), 1e-6 * (abs(float(np.mean(x))) + 1.0))
    n = len(x)
    span = 8.0 * sd / math.sqrt(n) + 6.0 * sd
    mu = np.linspace(float(np.mean(x)) - span, float(np.mean(x)) + span, grid)
    log_beta = np.linspace(math.log(sd) - 4.0, math.log(sd) + 3.0 + 6.0 / math.sqrt(n), grid)
    M, LB = np.meshgrid(mu, log_beta, indexing="ij")
    B = np.exp(LB)
    z = (x[None, None, :] - M[..., None]) / B[..., None]
    logp = -n * LB - z.sum(axis=-1) - np.exp(-z).sum(axis=-1)  # + log prior 1/beta: d log_beta
    w = np.exp(logp - logp.max())
    w /= w.sum()
    mus, betas, ws = M.ravel(), B.ravel(), w.ravel()

    def exceed(level: float) -> float:
        return float(np.dot(ws, -np.expm1(-np.exp(-(level - mus) / betas))))

    top = float(x.max())
    lo, hi = float(x.min()), top + sd
    while exceed(hi) > alpha and hi < 1e6:
        hi = top + 2.0 * (hi - top)
    for _ in range(80):  # exceed() falls with the level
        mid = (lo + hi) / 2.0
        lo, hi = (mid, hi) if exceed(mid) > alpha else (lo, mid)
    return float(hi)


def pooled_thresholds(peaks: dict[str, list[float]], segments_per_hour: float,
                      budget: float = FALSE_ALARMS_PER_HOUR,
                      undercoverage: float = CV_UNDERCOVERAGE,
                      runs: dict[str, list[int]] | None = None,
                      hours_per_run: float | None = None) -> dict[str, float]:
    """Per-OC thresholds (sigma units) from every OC's CV peak scores and the alarm budget.

    peaks: OC name -> peak |smoothed score| of each held-out CV segment.
    segments_per_hour: OC segments a normal hour of running holds (from the training runs).
    undercoverage: how many times more often new runs exceed a CV-calibrated level.
    runs, hours_per_run: OC name -> the run of each peak, and the OC time of a run (h); given,
    the level is the one a new run's largest peak exceeds with chance
    budget x hours_per_run / undercoverage (``predictive_gumbel_level`` over the runs'
    largest peaks), else the plug-in level of a segment's peak.
    """
    every = [v for vals in peaks.values() for v in vals if math.isfinite(v)]
    if not every:
        return {}
    p = min(0.5, budget / max(segments_per_hour, 1e-9) / max(undercoverage, 1.0))
    if len(every) == 1:
        common = every[0]
    elif runs is not None and hours_per_run is not None and len(set(_flat(runs))) >= 2:
        largest: dict[int, float] = {}
        for name, vals in peaks.items():
            for v, r in zip(vals, runs[name]):
                if math.isfinite(v):
                    largest[r] = max(largest.get(r, -math.inf), v)
        alpha = min(0.5, budget * hours_per_run / max(undercoverage, 1.0))
        common = predictive_gumbel_level(list(largest.values()), alpha)
    else:
        common = gumbel_quantile(every, p)
    return {name: max(common, THRESHOLD_MARGIN * max(vals)) for name, vals in peaks.items() if vals}


def peak_score(residual: np.ndarray, sigma: float, alpha: float) -> float:
    """Peak |score| of the residual rule over one segment's residuals (K,), finite, K > 0.

    The node's ``ResidualCheck`` stepped from 0, at run scale 1.
    """
    chk = ResidualCheck(sigma, math.inf, alpha, persist=1, clear=0)
    return max(abs(chk.step(r)[0]) for r in residual.tolist())


def alarm_mask(residual: np.ndarray, res: OCResult) -> np.ndarray:
    """Samples (K,) where the residual rule of ``res`` is raised over one segment's residuals.

    The node's ``ResidualCheck``, but per segment, so without its run scale and off-delay:
    a quick per-OC view; the node's own figures come from ``ordervib replay``.
    """
    c = res.calibration
    assert c is not None
    chk = ResidualCheck(c.sigma, c.threshold, c.ewma_alpha, c.persist, clear=0)
    return np.array([chk.step(r)[1] for r in residual.tolist()], dtype=bool)


def run_scaled_peaks(calibs: dict[str, Calibration]) -> dict[str, list[float]]:
    """CV peaks divided by the run scale the node would have used at each segment's start.

    Within a held-out CV run, its segments (every OC) in time order feed ``RunScale``
    exactly as the node's pipeline does; an OC without calibrated segments is left as is.
    """
    by_run: dict[int, list[tuple[int, str, int]]] = {}
    for name, c in calibs.items():
        if len(c.segments) != len(c.peaks):
            continue
        for k, (run, at, _) in enumerate(c.segments):
            by_run.setdefault(run, []).append((at, name, k))
    out = {name: list(c.peaks) for name, c in calibs.items()}
    for segs in by_run.values():
        scale = RunScale()
        for _, name, k in sorted(segs):
            out[name][k] = calibs[name].peaks[k] / scale.factor
            scale.add(calibs[name].segments[k][2])
    return out


def set_thresholds(results: list[OCResult], datas: list[OCData], budget: float,
                   undercoverage: float = CV_UNDERCOVERAGE, rule: str | None = None) -> list[OCResult]:
    """The results with every calibrated OC's threshold set from the pooled CV peaks and the
    alarm budget (and its peaks scaled by the run, see ``run_scaled_peaks``)."""
    hours = sum(y.size - s for d in datas for y, s in zip(d.y, d.start)) / FS / 3600.0
    segments = sum(len(d.runs) for d in datas)
    calibs = {r.name: r.calibration for r in results if r.calibration is not None}
    calibs = threshold_levels(calibs, hours, segments, budget, undercoverage, rule)
    return [replace(r, calibration=calibs[r.name]) if r.calibration is not None else r
            for r in results]


def threshold_levels(calibs: dict[str, Calibration], hours: float, segments: int, budget: float,
                     undercoverage: float = CV_UNDERCOVERAGE, rule: str | None = None
                     ) -> dict[str, Calibration]:
    """Each OC's calibration with its threshold (and run-scaled peaks) for the alarm budget
    (per hour) over the CV's ``segments`` in ``hours`` of OC time. rule: ``THRESHOLD_RULE``'s
    choices ("predictive", "plug-in"); None: ``THRESHOLD_RULE``."""
    per_hour = segments / hours if hours > 0 else 1.0
    calibs = dict(calibs)
    for name, scaled in run_scaled_peaks(calibs).items():
        calibs[name] = replace(calibs[name], peaks=tuple(scaled))
    runs = {n: [seg[0] for seg in c.segments] for n, c in calibs.items() if len(c.segments) == len(c.peaks)}
    n_runs = len(set(_flat(runs)))
    predictive = (rule or THRESHOLD_RULE) == "predictive" and len(runs) == len(calibs) and n_runs
    levels = pooled_thresholds({n: list(c.peaks) for n, c in calibs.items()}, per_hour, budget,
                               undercoverage, runs if predictive else None,
                               hours / n_runs if predictive else None)
    return {name: replace(c, threshold=levels[name]) for name, c in calibs.items()}


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


def plateau_peaks(y: np.ndarray, phase: np.ndarray, config: RuntimeConfig | None, fs: float,
                  anchored: bool = False, oc: np.ndarray | None = None) -> list[tuple[int, float]]:
    """(OC, peak ``StepCheck`` statistic) of each steady plateau of one run long enough for it.

    y: (K,) the watched values (real, or complex 1x vectors); phase: (K,) ``Phase`` codes;
    oc: (K,) OC index per sample (``OCDetector.label``; None: every plateau's OC is -1).
    """
    chk, peak = StepCheck(math.inf, config, fs, anchored), None
    full = chk.n_settle + chk.n_short + chk.n_long  # samples before the statistic exists
    peaks: list[tuple[int, float]] = []
    ocs = np.full(len(y), -1, dtype=np.int64) if oc is None else oc
    n_steady, at = 0, -1
    for v, steady, o in zip(y.tolist(), (phase == Phase.STEADY.code).tolist(), ocs.tolist()):
        z = chk.step(v, steady)
        if steady:
            if peak is None:
                at = o
            n_steady += 1
            peak = z if peak is None else max(peak, z)
        elif peak is not None:
            if n_steady >= full:  # a plateau too short for the check says nothing
                peaks.append((at, peak))
            peak, n_steady = None, 0
    if peak is not None and n_steady >= full:
        peaks.append((at, peak))
    return peaks


def _budget_threshold(peaks: list[float], running_s: float, budget: float) -> float:
    """The level a plateau's peak exceeds with the budget's chance (Gumbel), at least margin x the largest."""
    p = min(0.5, budget / (len(peaks) / (running_s / 3600.0)))
    return max(gumbel_quantile(peaks, p), THRESHOLD_MARGIN * max(peaks))


def calibrate_checks(runs: Sequence, schedule, target: str, budget: float = FALSE_ALARMS_PER_HOUR,
                     fs: float = FS, config: RuntimeConfig | None = None, use_phase: bool = True,
                     labels: Sequence[tuple[np.ndarray, np.ndarray]] | None = None) -> dict:
    """The model-free checks' limits from training runs (objects with ``column(name)`` (K,)).

    Steps the very ``StepCheck`` and OC detector the node runs (with ``config``, default
    settings if None) over every run: the peak step statistic of each steady plateau,
    pooled, gives the step threshold for the alarm budget (per hour of running); the
    longest repeat gives the flatline limit. ``run_scale_prior_ocs`` tells the node the
    residual thresholds were calibrated with ``RunScale`` (bundles without it are run without).
    When every run holds the target's phase channel (and ``use_phase``), the vector rule's two
    checks (the sliding and the anchored ``StepCheck`` on the 1x vector) get their thresholds the
    same way, each with half the budget, and the anchored one also a threshold per OC
    (``vector_drift_thresholds``, see ``drift_thresholds``).

    labels: each run's (OC index, Phase code) arrays as this detector gives them
    (``node.training.dataset.label_runs`` with default settings); None: labelled here.
    """
    det = OCDetector(schedule, config, fs)
    peaks: list[float] = []
    vector_peaks: dict[bool, list[tuple[int, float]]] = {False: [], True: []}  # by anchored: (OC, peak)
    ph = phase_channel(target)
    with_phase = use_phase and bool(runs) and all(ph in getattr(run, "channels", ()) for run in runs)
    longest, running_s = 0, 0.0
    for i, run in enumerate(runs):
        y = run.column(target)
        if labels is None:
            det.reset()
            oc, phase = det.label(run.column(schedule.switch))  # OC indices, Phase codes
        else:
            oc, phase = labels[i]
        running = phase != Phase.OFF.code
        running_s += float(running.sum()) / fs
        longest = max(longest, longest_repeat(y, running))
        peaks += [p for _, p in plateau_peaks(y, phase, config, fs)]
        if with_phase:
            z = order_vectors(y, run.column(ph))
            for anchored, found in vector_peaks.items():
                found += plateau_peaks(z, phase, config, fs, anchored, oc)
    checks: dict = {"flatline_samples": flatline_limit(longest, fs), "longest_repeat_in_training": longest,
                    "run_scale_prior_ocs": RUN_SCALE_PRIOR_OCS}
    if len(peaks) >= 2 and running_s > 0:
        checks["step_threshold"] = _budget_threshold(peaks, running_s, budget)
        checks["step_peaks_in_training"] = {"n": len(peaks), "max": max(peaks),
                                            "median": float(np.median(peaks))}
    for anchored, found in vector_peaks.items():
        if len(found) >= 2 and running_s > 0:
            name = "vector_drift" if anchored else "vector_step"
            values = [p for _, p in found]
            checks[f"{name}_threshold"] = _budget_threshold(values, running_s, budget / 2)
            checks[f"{name}_peaks_in_training"] = {"n": len(values), "max": max(values),
                                                   "median": float(np.median(values))}
    if "vector_drift_threshold" in checks:
        checks["vector_drift_thresholds"] = drift_thresholds(vector_peaks[True], schedule.names)
    return checks


def drift_thresholds(found: Sequence[tuple[int, float]], names: Sequence[str]) -> dict[str, float]:
    """Per OC name: ``DRIFT_OC_FACTOR`` x the largest anchored-check peak of its training
    plateaus, for OCs with at least ``DRIFT_OC_MIN_PLATEAUS`` of them (others: none, the
    pooled threshold holds).

    >>> drift_thresholds([(0, 2.0), (0, 3.0), (0, 1.0), (1, 9.0)], ["OC1", "OC2"])
    {'OC1': 7.5}
    """
    by_oc: dict[int, list[float]] = {}
    for oc, p in found:
        if 0 <= oc < len(names):
            by_oc.setdefault(oc, []).append(p)
    return {names[oc]: DRIFT_OC_FACTOR * max(v) for oc, v in sorted(by_oc.items())
            if len(v) >= DRIFT_OC_MIN_PLATEAUS}


def _flat(runs: dict[str, list[int]]) -> list[int]:
    return [r for rs in runs.values() for r in rs]
