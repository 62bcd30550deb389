"""Training the switching model: per OC, leave-one-run-out cross-validation of the
hyper-parameters (and of the MS-DPCCA input choice), a final fit on every run,
and residual calibration from the held-out folds.

Each model is evaluated the way the node runs it: seeded from the measured
samples before the OC switch, then free-running across the OC.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import os
import signal
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from contextlib import contextmanager

import numpy as np

from node.contract import FS, is_phase_channel, phase_channel
from node.contract.errors import OrdervibError
from node.contract.schedule import Schedule
from node.models.average import average_params, mean_in_order
from node.models.baseline import CharacteristicCurve
from node.models.config import RuntimeConfig
from node.models.curve import CurveModel, CurvePart, Variant
from node.models.kinds import fit_oc_model
from node.models.ocmodel import RUN_CURVE, Method, OCModel, StateSpaceModel, Trajectory
from node.models.prom import param_channels
from node.models.result import EWMA_ALPHA, Calibration, OCResult
from node.runtime.history import HISTORY_CHANNELS, estimate_cooling
from node.runtime.ocdetect import OCDetector
from node.runtime.runcurve import add_run_curve
from node.sysid.metrics import pooled_eps
from node.training.calibrate import CV_UNDERCOVERAGE, FALSE_ALARMS_PER_HOUR, peak_score, set_thresholds
from node.training.dataset import (
    Labels,
    Segment,
    first_seen,
    label_runs,
    run_arrays,
    segment_runs,
    target_vectors,
    time_order,
    with_history,
)
from node.training.envelope import band_factors, cv_outside, fit_envelope
from node.training.features import Term, combine_terms, segment_term
from node.training.ocdata import OCData
from node.training.plateau_fit import Visit, choose_settle, choose_shift, visit_tables
from node.training.runs import Run

DEFAULT_GRIDS: dict[Method, dict[str, list]] = {
    Method.WDMD: {"levels": [1, 2, 3, 4, 5], "rcond": [1e-8]},
    Method.DELAY_DMD: {"delays": [1, 2, 4, 8, 16], "rcond": [1e-8]},
    Method.LASSO: {"alpha": [1e-3, 3e-3, 1e-2, 3e-2, 0.1, 0.3, 1.0]},
    Method.PROM: {},  # the parametric models alone: PROM_CANDIDATES
}


# The characteristic-curve candidates of every OC's CV (CurveModel params): the OC's fleet
# curve, one and with rising / falling / steady speed apart (the change over 1 s beyond 20 rpm:
# the simulator's ramps run at 50-150 rpm/s, plateau noise stays within about 15 rpm per s), and
# the run's own curve (run_curve) itself, and the fleet curve anchored to the level the run had
# in the last second before the switch (``Variant.ANCHORED``).
CURVE_CANDIDATES: list[dict] = [
    {"variant": Variant.FLEET.value, "bin": 25.0, "window": 0},
    {"variant": Variant.FLEET.value, "bin": 25.0, "window": int(FS), "deadband": 20.0},
    {"variant": Variant.RUN.value},
    {"variant": Variant.ANCHORED.value, "bin": 25.0, "window": 0, "anchor": int(FS)},
    {"variant": Variant.ANCHORED.value, "bin": 25.0, "window": int(FS), "deadband": 20.0, "anchor": int(FS)},
    {"variant": Variant.VECTOR.value, "bin": 25.0, "window": 0, "anchor": int(FS)},
    {"variant": Variant.VECTOR.value, "bin": 25.0, "window": int(FS), "deadband": 20.0, "anchor": int(FS)},
    {"variant": Variant.VECTOR.value, "bin": 25.0, "window": 0, "anchor": int(10 * FS)},
    {"variant": Variant.VECTOR.value, "bin": 25.0, "window": 0, "anchor": int(60 * FS)},
    {"variant": Variant.INFLUENCE.value, "bin": 25.0, "anchor": int(FS)},
    {"variant": Variant.INFLUENCE.value, "bin": 25.0, "anchor": int(10 * FS)},
    # the same anchors learning how they fade (``CurveModel.decay``: a bowed rotor's 1x vector
    # at the switch fades within minutes), judged by the CV beside the held ones
    {"variant": Variant.ANCHORED.value, "bin": 25.0, "window": 0, "anchor": int(FS), "fade": True},
    {"variant": Variant.VECTOR.value, "bin": 25.0, "window": 0, "anchor": int(FS), "fade": True},
    {"variant": Variant.VECTOR.value, "bin": 25.0, "window": 0, "anchor": int(10 * FS), "fade": True},
    {"variant": Variant.INFLUENCE.value, "bin": 25.0, "anchor": int(FS), "fade": True},
    {"variant": Variant.INFLUENCE.value, "bin": 25.0, "anchor": int(10 * FS), "fade": True},
]
# The vector curves (the anchored curve on the 1x vector) only where every training run holds
# the target's phase channel: a run's imbalance and bow turn its vector, not just scale it; the
# longer anchors (10 s, 60 s) see the run's unbalance over more speeds. The influence curves: the
# vector at each speed an affine function of the vector at the switch, per bin (a linear rotor's
# response to the run's own unbalance). (study: docs/tuning.md#curve_candidates)


def curve_candidates(fade: bool = True) -> list[dict]:
    """``CURVE_CANDIDATES``; without ``fade``, those learning how their anchor fades left out.

    >>> len(curve_candidates(True)) - len(curve_candidates(False))
    5
    """
    return [dict(c) for c in CURVE_CANDIDATES if fade or not c.get("fade")]


# A state-space or regression model keeps an OC only when its CV eps is below (1 - margin) x
# the best curve's: on new runs a free-running model's error exceeds its leave-one-run-out CV
# error more often than a curve's does. (study: docs/tuning.md#curve_margin)
CURVE_MARGIN = 0.5
# With fewer training runs than FEW_RUNS the CV's optimism for a free-running model is larger
# still (4 runs: one OC's WDMD with CV eps 0.04 over-predicted a resonance by 40 % on held-out
# runs of other thermal states): such a model is then never chosen alone, only as a
# member of the curves' average. (study: docs/tuning.md#few_runs)
FEW_RUNS = 6


def curve_margin(n_runs: int) -> float:
    """The margin by which a grid or parametric model must beat the best curve's CV eps to be
    chosen alone, with ``n_runs`` training runs (1: never).

    >>> curve_margin(8), curve_margin(4)
    (0.5, 1.0)
    """
    return CURVE_MARGIN if n_runs >= FEW_RUNS else 1.0

# Where no grid or parametric model beats the curves by CURVE_MARGIN, the OC's model is the best
# curve or the average (``node.models.average``) of the 2 or 3 best of a pool (the
# CURVE_AVERAGE CV-best curves and the grid's CV-best model), whichever has the lowest CV eps
# (``_best_average``): models of different kinds err differently on a new run, so their mean
# errs less than the best of them. (study: docs/tuning.md#curve_average)
CURVE_AVERAGE = 3

# The parametric candidates of every OC's CV (``ParametricOCModel`` params, dissertation section
# 6.4): a WDMD per training segment, interpolated in pole-residue form to the run's engine-history
# parameter at the switch (one of three), with the least-squares line through the samples
# (``regress``) or piecewise-linear interpolation (``linear``), or to two of them (the
# least-squares plane); one real mode, interpolated as
# it is (``direct``), the static gain kept; seeded on the last 10 samples (0.25 s) of past.
# The settings are those ``bench prom-engine`` chose most often by leave-one-run-out CV; like the
# grid's models, a parametric model keeps an OC only when its CV eps beats the best curve's by
# ``CURVE_MARGIN``. (study: docs/tuning.md#prom_candidates, docs/prom_engine_study.md)
PROM_PARAMS = ("hist_thermal", "hist_shutdown", "hist_energy")
PROM_CANDIDATES: list[dict] = [
    {"param": p, "levels": lv, "weights": w, "pairs": 0, "real": 1, "scheme": "direct", "seed": 10}
    for p in PROM_PARAMS for lv in (1, 2) for w in ("regress", "linear")
] + [  # two parameters: the least-squares plane (thin-plate interpolation through scattered
    # runs extrapolates wildly; study: docs/tuning.md#prom_candidates)
    {"param": f"{p},{q}", "levels": lv, "weights": "regress", "pairs": 0, "real": 1, "scheme": "direct",
     "seed": 10} for p, q in itertools.combinations(PROM_PARAMS, 2) for lv in (1, 2)
]


def grid_points(grid: dict[str, list]) -> list[dict]:
    keys = sorted(grid)
    return [dict(zip(keys, vals)) for vals in itertools.product(*(grid[k] for k in keys))]




# Leave-one-run-out CV up to MAX_FOLDS training runs; beyond, MAX_FOLDS folds of contiguous
# runs (``run_folds``), as scikit-learn's grouped K-fold: the fits per candidate stay at
# MAX_FOLDS whatever the runs, each on (1 - 1/MAX_FOLDS) of them (40 runs of an engine: the CV
# of 10 folds of 4 runs; 8 runs: leave-one-run-out). (study: docs/tuning.md#max_folds)
MAX_FOLDS = 10


def run_folds(n_runs: int, max_folds: int = MAX_FOLDS) -> dict[int, int]:
    """Each run's CV fold (runs 0 .. n_runs - 1, in time order): its own up to ``max_folds``
    runs; beyond, ``max_folds`` blocks of consecutive runs (later runs held out together, as
    new runs are), a block named by its first run.

    >>> run_folds(3)
    {0: 0, 1: 1, 2: 2}
    >>> sorted(set(run_folds(40).values()))[:3], run_folds(40)[7], run_folds(12, 4)
    ([0, 4, 8], 4, {0: 0, 1: 0, 2: 0, 3: 3, 4: 3, 5: 3, 6: 6, 7: 6, 8: 6, 9: 9, 10: 9, 11: 9})
    """
    if n_runs <= max_folds:
        return {r: r for r in range(n_runs)}
    block = [r * max_folds // n_runs for r in range(n_runs)]
    first = {b: block.index(b) for b in set(block)}
    return {r: first[b] for r, b in enumerate(block)}


def _ranking_terms(d: OCData) -> list[Term | None]:
    """Each segment's MS-DPCCA term (``segment_term``) on the ranked candidates: computed once,
    shared by every fold (a fold's ranking sums its rows' terms in row order, exactly as
    ``rank_inputs`` over its segments would)."""
    cols = _ranked_columns(d)
    return [segment_term(np.column_stack([d.y[i], d.X[i][:, cols]])[d.start[i]:], 0)
            for i in range(len(d.runs))]


def _ranked_columns(d: OCData) -> list[int]:
    return [j for j, c in enumerate(d.candidates) if c not in d.unranked]


def select_inputs(d: OCData, rows: list[int], inputs: list[str] | None, k: int,
                  terms: list[Term | None] | None = None) -> tuple[list[str], list[tuple[str, float]]]:
    """The inputs of an OC's state-space candidates from its segments ``rows``: ``inputs`` when
    given, else the ``k`` best ranked (MS-DPCCA) with their ranking [(channel, score)]."""
    if inputs is not None:
        return inputs, []
    cols = _ranked_columns(d)
    terms = terms if terms is not None else _ranking_terms(d)
    score = combine_terms([terms[i] for i in rows], len(cols) + 1, 0)[1:]
    order = np.argsort(-score)
    ranking = [(d.candidates[cols[j]], float(score[j])) for j in order]
    return [d.candidates[cols[j]] for j in order[:k]], ranking


def oc_trajectories(d: OCData, rows: list[int], inputs: list[str]) -> list[Trajectory]:
    """The OC's segments ``rows`` as trajectories on the columns ``inputs``."""
    cols = [d.candidates.index(c) for c in inputs]
    return [Trajectory(d.y[i], d.X[i][:, cols], d.start[i], d.z[i] if d.z else None) for i in rows]


def _predict_pairs(model: OCModel, trajs: list[Trajectory]) -> list[tuple[np.ndarray, np.ndarray]]:
    out = []
    for t in trajs:
        with np.errstate(all="ignore"):
            try:
                p = model.predict(t)
            except (np.linalg.LinAlgError, ValueError):
                p = np.full(t.seg_y.shape, np.nan)
        out.append((t.seg_y, np.where(np.isfinite(p), p, np.inf)))
    return out


def cross_validate_candidate(d: OCData, folds: list[int], method: str, params: dict,
                             fold_inputs: dict[int, list[str]], bound: float = math.inf, parts: bool = True
                             ) -> tuple[float, list[tuple[np.ndarray, np.ndarray]]]:
    """Pooled eps of ``method`` with ``params`` over the CV ``folds`` (``OCData.fold``: leave one
    run out, or blocks of runs), and the held-out (measured, predicted) pairs in fold order (inf
    and no pairs when a fit fails).

    bound: stop, returning inf and no pairs, as soon as the folds done prove the pooled eps at
    least ``bound`` (their error energy over every fold's reference energy only grows): the
    candidate can no longer be chosen (``train_oc``).
    parts: a curve's folds from the runs' parts (``_fold_fitter``; False: each fitted afresh,
    the same numbers slower)."""
    pairs_all: list[tuple[np.ndarray, np.ndarray]] = []
    num, den = 0.0, _reference_energy(d, folds) if bound < math.inf else 0.0
    fit = _fold_fitter(d, method, params, fold_inputs, parts)
    for f in folds:
        chosen = fold_inputs[f]
        try:
            m = fit(d.fitted_on(f), chosen)
        except (np.linalg.LinAlgError, ValueError):
            return float("inf"), []
        pairs = _predict_pairs(m, oc_trajectories(d, d.held_out(f), chosen))
        pairs_all += pairs
        if bound < math.inf:
            for y, p in pairs:  # the terms of pooled_eps's sum, in its order: a prefix of it
                num += float(np.sum((y - p) ** 2))
            if not math.sqrt(num / den) < bound:  # (nan: an infinite prediction)
                return float("inf"), []
    return (pooled_eps(pairs_all) if pairs_all else float("inf")), pairs_all


def _fold_fitter(d: OCData, method: str, params: dict, fold_inputs: dict[int, list[str]],
                 parts: bool = True) -> Callable[[list[int], list[str]], OCModel]:
    """fit(rows, inputs): the model of ``method`` fitted on the segments ``rows`` with ``inputs``.

    parts: a curve is made from the rows' parts (``CurveModel.part``), each segment's computed
    once for every fold: the model ``fit_oc_model`` gives on those rows, bit for bit, without
    re-binning every other run in every fold (40 runs: 13 s of curve CV per OC before)."""
    if not parts or Method(method) is not Method.CURVE or len({tuple(c) for c in fold_inputs.values()}) != 1:
        return lambda rows, inputs: fit_oc_model(method, params, oc_trajectories(d, rows, inputs))
    inputs = next(iter(fold_inputs.values()))  # every fold's: the one input of the curve
    done: dict[int, CurvePart] = {}

    def fit(rows: list[int], _: list[str]) -> OCModel:
        for i in rows:
            if i not in done:
                done[i] = CurveModel.part(params, oc_trajectories(d, [i], inputs)[0])
        return CurveModel.from_parts(params, [done[i] for i in rows])
    return fit


def _reference_energy(d: OCData, folds: list[int]) -> float:
    """The pooled eps's denominator over ``folds``: the squared target of every OC sample of
    every segment, summed in fold order as ``pooled_eps`` sums it (nan when zero)."""
    rows = [i for f in folds for i in d.held_out(f)]
    return sum(float(np.sum(d.y[i][d.start[i]:] ** 2)) for i in rows) or math.nan


# a CV's result: CV eps, method, params, (measured, predicted) pairs, inputs
Scored = tuple[float, str, dict, list[tuple[np.ndarray, np.ndarray]], list[str]]


def _best_average(pool: list[Scored]) -> Scored:
    """Of the best curve alone and the averages (``node.models.average``) of the k best of
    ``pool`` (best first, curves and at most one grid model; k = 2 .. ``CURVE_AVERAGE``), the
    one with the lowest CV eps (the smaller k on a tie): a grid model that did not beat the
    curves by ``CURVE_MARGIN`` is a member, never alone (alone its residual band, set from its
    CV, is too narrow on new runs: false alarms; study: docs/tuning.md#curve_average).
    An average's pairs are its members' held-out predictions averaged as
    ``AverageModel.predict`` averages them; of curves, that is the average's own CV to the last
    bit (each fold's average is the average of the members' fold models)."""
    best = next(c for c in pool if c[1] == Method.CURVE)
    for k in range(2, min(CURVE_AVERAGE, len(pool)) + 1):
        top = pool[:k]
        pairs = [(y, mean_in_order([c[3][n][1] for c in top])) for n, (y, _) in enumerate(top[0][3])]
        params = average_params([(c[1], c[2], c[4]) for c in top])
        score = pooled_eps(pairs)
        if score < best[0]:
            best = (score, Method.AVERAGE.value, params, pairs, list(params["inputs"]))
    return best


def curve_model_inputs(d: OCData, curve: dict) -> list[str] | None:
    """The one input of a curve candidate (the switch speed or run_curve); None: not a candidate."""
    if Variant(curve.get("variant", Variant.FLEET)).on_vector and not d.z:
        return None
    name = RUN_CURVE if curve.get("variant") == Variant.RUN else d.switch
    return [name] if name in d.candidates else None


def train_oc(d: OCData, method: str, grid: dict[str, list], inputs: list[str] | None,
             n_inputs: int, prune: bool = True) -> OCResult:
    """CV over ``grid`` (leave one run out, or ``d.folds``; inputs chosen inside each fold),
    then the final fit.

    The OC's curve candidates (``d.curves``) are cross-validated on the same folds. The grid's
    (or a parametric model's) best is the OC's model when its CV eps is below
    (1 - ``curve_margin(n_runs)``) x the best curve's; otherwise the best curve, or the average of the
    2-3 best of the best curves and the grid's best, whichever has the lowest CV eps
    (``_best_average``).

    prune: a candidate's CV stops as soon as its folds so far prove that it cannot be chosen
    (its error energy only grows with the folds: a curve beyond the ``CURVE_AVERAGE``-th best
    so far, a grid model beyond the grid's best so far or that curve, a parametric model beyond
    the best model or (1 - ``CURVE_MARGIN``) x the best curve's eps); its ``cv_scores`` entry
    is then inf; and a curve's folds are made from the runs' parts (``_fold_fitter``). The
    choice, the model and its calibration are those of the full CV (prune False: every
    candidate on every fold, each fold fitted afresh; tests; ``bench train-speed --check-full``
    compares the two: docs/tuning.md#max_folds).
    """
    n_runs = len(set(d.runs))
    if n_runs < 2:
        return OCResult(d.name, None, [], {}, n_runs, float("nan"), float("nan"), None,
                        note=f"seen in {n_runs} run(s); at least 2 are needed")
    if len(d.fold_ids()) < 2:  # its runs all in one block: leave one run out
        d = dataclasses.replace(d, folds={})
    folds = d.fold_ids()
    fold_inputs = {}
    terms = _ranking_terms(d) if inputs is None else None
    for f in folds:
        fold_inputs[f] = select_inputs(d, d.fitted_on(f), inputs, n_inputs, terms)[0]
    # The curves first: the best of them bounds what a grid or parametric model must reach
    # (``prune``: a candidate is dropped once its folds so far prove it cannot be chosen).
    cv_scores: list[tuple[dict, float]] = []
    ranked: list[Scored] = []  # the CURVE_AVERAGE best curves so far, best first
    for curve in d.curves:
        curve_inputs = curve_model_inputs(d, curve)
        if curve_inputs is None:
            continue
        # a curve beyond the CURVE_AVERAGE best so far is neither the best nor a member
        bound = ranked[-1][0] if prune and len(ranked) == CURVE_AVERAGE else math.inf
        score, pairs_all = cross_validate_candidate(d, folds, Method.CURVE, curve,
                                                    dict.fromkeys(folds, curve_inputs), bound, parts=prune)
        cv_scores.append(({"method": Method.CURVE.value, **curve}, score))
        if np.isfinite(score):
            ranked = sorted([*ranked, (score, Method.CURVE.value, curve, pairs_all, curve_inputs)],
                            key=lambda c: c[0])[:CURVE_AVERAGE]
    # a grid or parametric model is taken alone below (1 - CURVE_MARGIN) x the best curve's eps;
    # the grid's best is a member of the curves' average when among the CURVE_AVERAGE best
    best_curve = ranked[0][0] if ranked else math.inf
    to_beat = (1.0 - curve_margin(n_runs)) * best_curve
    member_bound = ranked[-1][0] if len(ranked) == CURVE_AVERAGE else math.inf
    best: tuple[float, dict, list[tuple[np.ndarray, np.ndarray]]] | None = None
    for params in grid_points(grid) if grid else []:
        bound = min(member_bound, best[0] if best is not None else math.inf) if prune else math.inf
        score, pairs_all = cross_validate_candidate(d, folds, method, params, fold_inputs, bound)
        cv_scores.append((params, score))
        if best is None or score < best[0]:
            best = (score, params, pairs_all)
    if best is None and not (d.proms and Method(method) is Method.PROM):
        raise ValueError("empty hyper-parameter grid")
    cv_eps, params, pairs = best or (float("inf"), {}, [])
    all_rows = list(range(len(d.runs)))
    chosen, ranking = select_inputs(d, all_rows, inputs, n_inputs, terms)
    grid_best: Scored | None = (cv_eps, str(Method(method)), params, pairs, chosen) \
        if best is not None and np.isfinite(cv_eps) and Method(method) is not Method.PROM else None
    for prom in d.proms:  # the parametric models, on the same folds: the lowest CV of all models
        prom_inputs = [d.switch, *param_channels(prom)]
        if any(c not in d.candidates for c in prom_inputs):
            continue
        bound = min(to_beat, cv_eps) if prune else math.inf
        score, pairs_all = cross_validate_candidate(d, folds, Method.PROM, prom,
                                                    dict.fromkeys(folds, prom_inputs), bound)
        cv_scores.append(({"method": Method.PROM.value, **prom}, score))
        if score < cv_eps:
            method, cv_eps, params, pairs, chosen = Method.PROM, score, prom, pairs_all, prom_inputs
    if ranked and not cv_eps < to_beat:  # the curves' side: the best of them, or an average
        pool = sorted(ranked + ([grid_best] if grid_best is not None else []), key=lambda c: c[0])
        cv_eps, method, params, pairs, chosen = _best_average(pool)
        if method == Method.AVERAGE:
            cv_scores.append(({"method": Method.AVERAGE.value, **params}, cv_eps))
    if Method(method) is Method.PROM and not np.isfinite(cv_eps):
        return OCResult(d.name, None, [], {}, n_runs, float("nan"), float("nan"), None, ranking,
                        cv_scores, note="no parametric model in cross-validation")
    plateau = None
    if d.plateau_vector is not None and pairs:  # the plateau shift, if the OC's CV says it helps
        order = [d.held_out(f) for f in folds]
        plateau, moved = choose_shift(d.plateaus, order, [d.fitted_on(f) for f in folds], pairs,
                                      d.plateau_vector)
        if plateau is not None:
            pairs, cv_eps = moved, pooled_eps(moved)
    settle = None
    unsettled = pairs  # the residuals' scale: before the settle anchor (see below)
    if d.settle and pairs:  # the re-anchor on the visit's own level, if the OC's CV says it helps
        settle, moved = choose_settle([d.held_out(f) for f in folds], pairs)
        if settle is not None:
            pairs, cv_eps = moved, pooled_eps(moved)
    trajs = oc_trajectories(d, all_rows, chosen)
    model = fit_oc_model(method, params, trajs)
    train_eps = pooled_eps(_predict_pairs(model, trajs))
    calib = None
    if np.isfinite(cv_eps):
        res = [y - p for y, p in pairs]
        # sigma from the residuals before the settle anchor: it moves a visit only from its 15th
        # second on, so a sigma of the moved ones would narrow the band of the transition before
        # it, where the first OC after a start misses most (``bench generalise``: with 8 training runs 0.57
        # false alarms per hour against 0.23); the peaks are the moved residuals' over it
        sigma = float(np.sqrt(np.mean(np.concatenate([y - p for y, p in unsettled]) ** 2)))
        sigma = max(sigma, 1e-9)
        rows = [i for f in folds for i in d.held_out(f)]  # the order of ``pairs``
        calib = Calibration(
            sigma, float("inf"),
            peaks=tuple(peak_score(r, sigma, EWMA_ALPHA) for r in res),
            segments=tuple((d.runs[i], d.at[i], float(np.mean((r / sigma) ** 2))) for i, r in zip(rows, res)))
    note = f"{model.repaired} unstable pole(s) moved inside" if model.repaired else ""
    if isinstance(model, StateSpaceModel) and not np.isfinite(cv_eps):
        note = "no stable candidate in cross-validation"
    envelope = fit_envelope(d, all_rows, chosen)
    outside = cv_outside(d, folds, chosen, res, sigma) if calib is not None else None
    return OCResult(d.name, model, chosen, params, n_runs, train_eps, cv_eps, calib,
                    ranking, cv_scores, note, envelope, outside, plateau, settle)


def oc_datasets(runs: list[Run], schedule: Schedule, target: str, candidates: list[str],
                segments: list[Segment] | None = None,
                history_s: float = RuntimeConfig().history_s,
                curves: list[dict] | None = None, phase: bool = True,
                proms: list[dict] | None = None, unranked: list[str] | None = None,
                visits: list[dict[int, Visit]] | None = None, plateau_vector: bool = False,
                settle: bool = False) -> list[OCData]:
    """Per-OC arrays from runs (``Schedule.models``: every OC, the rundown, the start), each
    segment with up to ``history_s`` of past before it (``segments``: cut from labels by model,
    ``label_runs(models=True)``; None: cut here so).

    curves: each OC's curve candidates (``CURVE_CANDIDATES``; None: none). phase: the target's
    1x vectors too (``OCData.z``) when every run holds its phase channel. proms: the parametric
    candidates (``PROM_CANDIDATES``); unranked: candidates MS-DPCCA leaves out (their inputs).
    visits: per run, its visits by start (``plateau_fit.visit_tables``; on the 1x vector with
    ``plateau_vector``): each OC learns its plateau shift (None: none).
    """
    segments = segment_runs(runs, schedule, labels=label_runs(runs, schedule, True)) if segments is None \
        else segments
    arrays = [run_arrays(run, target, candidates) for run in runs]
    vectors = [target_vectors(run, target) for run in runs] if phase else []
    zs = [v for v in vectors if v is not None]
    if not zs or len(zs) < len(runs):
        zs = []
    hist = int(history_s * FS)
    seen = [first_seen(run, [target, schedule.switch]) for run in runs]
    out = []
    for j, name in enumerate(schedule.models):
        plateau = j < schedule.rundown  # the rundown and the start have none: no shift, no settle anchor
        d = OCData(name, target, list(candidates), [], [], [], [], switch=schedule.switch,
                   curves=[dict(c) for c in curves or []], proms=[dict(c) for c in proms or []],
                   unranked=list(unranked or []), folds=run_folds(len(runs)),
                   plateau_vector=plateau_vector if visits is not None and plateau else None,
                   settle=settle and plateau)
        for s in segments:
            if s.oc != j:
                continue
            # the past the node seeds from: from the first row with the target and the switch
            # measured (the node's rule also awaits the model's inputs, here not yet chosen)
            lo = min(max(0, s.start - hist, seen[s.run]), s.start)
            ra = arrays[s.run]
            d.runs.append(s.run)
            d.y.append(ra.y[lo:s.stop])
            if zs:
                d.z.append(zs[s.run][lo:s.stop])
            d.X.append(ra.U[lo:s.stop])
            d.start.append(s.start - lo)
            d.at.append(s.start)
            if visits is not None:
                d.plateaus.append(visits[s.run].get(s.start))
        out.append(d)
    return out


def candidate_channels(runs: list[Run], target: str, switch: str) -> list[str]:
    """Channels usable as inputs: present and mostly finite in every run, not vibration outputs
    (amplitudes ``y*``, order phases ``*_ph``: the target's own vibration, not its cause)."""
    common = [c for c in runs[0].channels if all(c in r.channels for r in runs)]
    out = []
    for c in common:
        if c == target or c.startswith("y") or is_phase_channel(c):
            continue
        finite = min(float(np.mean(np.isfinite(r.column(c)))) for r in runs)
        if finite >= 0.5:
            out.append(c)
    if switch in out:  # the switch speed first: a sensible default input
        out.remove(switch)
        out.insert(0, switch)
    return out


def fleet_curve(runs: list[Run], switch: str, target: str) -> tuple[np.ndarray, np.ndarray]:
    """The training runs' characteristic curve (speeds (B,), mean target (B,))."""
    arrays = [run_arrays(r, target, [switch]) for r in runs]
    c = CharacteristicCurve().fit(np.concatenate([a.U[:, 0] for a in arrays]),
                                  np.concatenate([a.y for a in arrays]))
    return c.centres_, c.means_


def history_config(runs: list[Run], schedule: Schedule, config: RuntimeConfig | None = None
                   ) -> RuntimeConfig:
    """``config`` with the engine history's cooling rate estimated from ``runs`` (one engine's,
    see ``node.runtime.history.estimate_cooling``); unchanged when the runs cannot tell."""
    config = config or RuntimeConfig()
    order = [runs[i] for i in time_order(runs)]
    rate = estimate_cooling(order, schedule.switch, OCDetector(schedule, config).off_level)
    return config if rate is None else dataclasses.replace(config, history_cooling=rate)


def _worker_init() -> None:
    """A training worker leaves Ctrl-C to its parent, which stops it; SIGTERM ends it at once.

    Its BLAS runs one thread: the workers already use the cores, and two workers each with
    a BLAS thread per core spin against each other on the many small products of a CV (8
    runs of an engine: 100 s with the default threads, 8.9 s with one; one process alone
    15.4 s)."""
    from threadpoolctl import threadpool_limits

    # the parent forks its workers with both signals blocked (``_signals_blocked``): a signal
    # that comes before these lines waits, and then ends the worker without a traceback
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, _STOP_SIGNALS)
    threadpool_limits(limits=1)


_STOP_SIGNALS = {signal.SIGINT, signal.SIGTERM}


@contextmanager
def _signals_blocked() -> Iterator[None]:
    """SIGINT and SIGTERM held back while the pool's workers (and its manager thread, which
    may start more) are made, so that they inherit the block until ``_worker_init`` has
    their handlers set; one that came meanwhile is delivered to this process on the way out.
    (Without it, a SIGTERM to the process group between a worker's fork and its handlers
    ran the parent's handler there: a traceback from the worker.)"""
    old = signal.pthread_sigmask(signal.SIG_BLOCK, _STOP_SIGNALS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def _stop_pool(pool: ProcessPoolExecutor, grace_s: float = 2.0) -> None:
    """End the pool's workers now (busy or not) and drop the jobs still queued."""
    procs = list((getattr(pool, "_processes", None) or {}).values())  # 3.14: pool.terminate_workers()
    for p in procs:
        p.terminate()
    for p in procs:
        p.join(grace_s)
        if p.is_alive():
            p.kill()
            p.join()
    pool.shutdown(wait=False, cancel_futures=True)
    # Let the pool's manager thread see its dead workers and close its wake-up pipe now:
    # otherwise the interpreter's exit hook may write to that pipe while the thread closes
    # it ("OSError: Bad file descriptor" after the one-line message).
    # (CPython 3.11 races there; the ``ordervib`` entry also leaves an interrupted command
    # without exit hooks).
    manager = getattr(pool, "_executor_manager_thread", None)
    if manager is not None:
        manager.join(grace_s)


def train(runs: list[Run], schedule: Schedule, target: str = "yB", method: str = "wdmd",
          inputs: list[str] | None = None, n_inputs: int = 4, grid: dict[str, list] | None = None,
          workers: int | None = None, progress: Callable[[OCResult, int, int], None] | None = None,
          false_alarms_per_hour: float = FALSE_ALARMS_PER_HOUR,
          cv_undercoverage: float = CV_UNDERCOVERAGE,
          fleet: tuple[np.ndarray, np.ndarray] | None = None,
          config: RuntimeConfig | None = None, curves: bool = True,
          history: bool = False, phase: bool = True, prom: bool = True, prune: bool = True,
          fade: bool = True, labels: list[Labels] | None = None, plateaus: bool = True,
          settle: bool = True) -> list[OCResult]:
    """Train every OC of the schedule, the rundown and the start (``Schedule.models``).
    ``inputs=None`` selects them by MS-DPCCA (top ``n_inputs``).

    config: the run-time settings the bundle will carry (default ``RuntimeConfig()``); each
    OC's model is evaluated seeded from ``config.history_s`` of past, as the node seeds it.

    fleet: the training runs' characteristic curve (speeds, means); given, every run gains
    the derived ``run_curve`` input (``node.runtime.runcurve``), a candidate like any channel.

    history: every run gains the engine-history channels (``node.runtime.history``, with
    ``config.history_cooling``: see ``history_config``), candidates like any channel; ``runs``
    are then one engine's.

    curves: per OC, also cross-validate the characteristic curves (``CURVE_CANDIDATES``: the
    OC's fleet curve on the switch speed, the curve anchored to the run's level at the
    switch, and run_curve itself, when among the candidates) and keep the best of them unless
    the grid's best beats it by ``CURVE_MARGIN`` (see ``train_oc``); with ``phase`` and the
    target's phase channel in every run, the vector curves too.

    prom: per OC, also cross-validate the parametric models (``PROM_CANDIDATES``; with
    ``method="prom"`` they alone, beside the curves) on the
    engine-history parameters (computed for them when ``history`` is off, then only they take
    them as inputs); ``runs`` are then one engine's.

    fade: also the anchored curves that learn how their anchor fades (``CurveModel.decay``;
    ``"fade": true`` in their params); False: only the held ones.

    prune: stop a candidate's CV once it cannot be chosen, and make the curves' folds from the
    runs' parts (``train_oc``; the same models; False: the full CV, slower).

    labels: each run's labels by model (``label_runs(models=True)``; None: labelled here), computed once per
    training by the caller that trains several targets.

    plateaus: each OC also learns what the run's earlier plateaus add to its model's plateau
    (``node.models.plateau``; on the 1x vector with ``phase`` and the phase in every run), kept
    where its CV says it helps (``node.training.plateau_fit``).

    settle: each OC also learns how much of what its model missed as the visit settled stays
    for the rest of it (``node.models.settle``), kept where its CV says it helps
    (``plateau_fit.choose_settle``).

    Alarm thresholds are set last, from every OC's CV peaks and the false-alarm budget
    (per hour of OC time in normal runs), see ``node.training.calibrate``.
    """
    meth = Method(method)
    prom = prom or meth is Method.PROM
    if not runs:
        raise OrdervibError("no runs to train on")
    if any(target not in r.channels for r in runs):
        raise OrdervibError(f"target channel {target!r} is missing from some run")
    labels = label_runs(runs, schedule, models=True) if labels is None else labels
    if fleet is not None:
        runs = [add_run_curve(r, schedule, target, fleet, codes) for r, (codes, _) in zip(runs, labels)]
    if history or prom:
        runs = with_history(runs, schedule, config or RuntimeConfig())
    candidates = candidate_channels(runs, target, schedule.switch)
    unranked = [c for c in candidates if c in HISTORY_CHANNELS] if not history and inputs is None else []
    if inputs is not None:
        missing = [c for c in inputs if c not in candidates]
        if missing:
            raise OrdervibError(f"input channel(s) {missing} missing or mostly empty in the recordings")
        extra = [c for c in PROM_PARAMS if prom and c in candidates and c not in inputs]
        candidates, unranked = list(inputs) + extra, extra
    if len(candidates) == len(unranked):
        raise OrdervibError("no usable input channel in the recordings")
    grid = grid or DEFAULT_GRIDS[meth]
    visits, on_vector = None, False
    if plateaus:
        on_vector = phase and all(phase_channel(target) in r.channels for r in runs)
        visits = visit_tables(runs, [codes for codes, _ in labels], target, len(schedule.names), on_vector)
    datas = oc_datasets(runs, schedule, target, candidates, segment_runs(runs, schedule, labels=labels),
                        history_s=(config or RuntimeConfig()).history_s,
                        curves=curve_candidates(fade) if curves else None, phase=phase,
                        proms=PROM_CANDIDATES if prom else None, unranked=unranked,
                        visits=visits, plateau_vector=on_vector, settle=settle)
    workers = workers or min(2, os.cpu_count() or 1)
    jobs = [(d, method, grid, inputs, n_inputs, prune) for d in datas]
    results: list[OCResult | None] = [None] * len(jobs)
    if workers > 1:
        pool = ProcessPoolExecutor(max_workers=workers, initializer=_worker_init)
        try:
            with _signals_blocked():
                futures = {pool.submit(train_oc, *job): i for i, job in enumerate(jobs)}
            for done, fut in enumerate(as_completed(futures), 1):
                i = futures[fut]
                results[i] = r = fut.result()
                if progress:
                    progress(r, done, len(jobs))
        except BaseException:  # Ctrl-C, SIGTERM made KeyboardInterrupt, a failed job: stop them all
            _stop_pool(pool)
            raise
        pool.shutdown()
    else:
        for i, job in enumerate(jobs):
            results[i] = r = train_oc(*job)
            if progress:
                progress(r, i + 1, len(jobs))
    out = [r for r in results if r is not None]
    factors = band_factors([r.outside_cv for r in out])
    out = [dataclasses.replace(r, envelope=r.envelope.with_band_factor(f)) if r.envelope is not None else r
           for r, f in zip(out, factors)]
    return set_thresholds(out, datas, false_alarms_per_hour, cv_undercoverage)


