"""Panels I-IV of the engineer's report, each as the blocks of one target.

``context_panel`` (I), ``parameters_panel`` (II), ``validation_panel`` (III) and
``prediction_panel`` (IV) take the target's bundle, the runs, the schedule and the target,
and return their blocks. ``score_runs`` (the free-run predictions, the curve's, each run's
provenance), ``oc_scores`` and ``target_episodes`` are shared with the summary
(``replay.report.summary``), so that it shows the very numbers of panel III.
"""

from __future__ import annotations

import dataclasses
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from node.contract import parse_monitor_key
from node.contract.schedule import Schedule
from node.models.baseline import CharacteristicCurve
from node.models.bundle import Bundle
from node.runtime.history import HISTORY_CHANNELS
from node.sysid.metrics import pooled_eps, pooled_r2
from node.training.dataset import Segment, label_runs, segment_runs
from node.training.evaluation import (
    SegmentPrediction,
    curve_predictions,
    derived_runs,
    pooled,
    predict_segments,
    score_segments,
    scored_pairs,
)
from node.training.runs import Run
from replay.offline import NodeAlarms
from replay.report.correlation import MASK, MAX_ROWS, dpcca_figure, dpcca_rows
from replay.report.document import Block, Figure, Heading, Paragraph, Table
from replay.report.figures import (
    curve_figure,
    parallel_figure,
    run_colours,
    score_figure,
    segments_figure,
)

MAX_EPISODES = 50  # alarm episodes listed one by one; the rest are counted
R2_FLOOR = -1.0  # R^2 bars below this are cut (a wild OC would flatten the others)


@dataclass(frozen=True)
class RunSet:
    """The report's runs, in the order read, each with a label (``REC #i``, i from 1 per file)
    and the sha256 of its recording (None: not known), by which, and by its span, a run is told
    in-sample or held-out (``node.training.provenance``); engines: each run's recording's
    ``ordervib`` metadata record (``node.mcap.recorded_engine``: engine, bed, date; None: not read).

    >>> RunSet.label("data/engine1_runs.mcap", 0)
    'engine1_runs #1'
    """

    runs: list[Run]
    labels: list[str]
    sha256: list[str | None] | None = None
    engines: list[dict[str, str]] | None = None

    @staticmethod
    def label(recording: str, i: int) -> str:
        """The label of the i-th run (from 0) of ``recording``: its file name without ``.mcap``."""
        name = recording.replace("\\", "/").rsplit("/", 1)[-1]
        return f"{name.removesuffix('.mcap')} #{i + 1}"


def _f(x: float, digits: int = 3) -> str:
    return f"{x:.{digits}f}" if np.isfinite(x) else "-"


def _pct(x: float) -> str:
    return f"{100.0 * x:.1f} %" if np.isfinite(x) else "-"


def _g(x: float) -> str:
    return f"{x:.5g}" if np.isfinite(x) else "-"


def fleet_curve(bundle: Bundle, runs: Sequence[Run], switch: str, target: str
                ) -> tuple[np.ndarray, np.ndarray]:
    """The bundle's characteristic curve (speeds, means); fitted on ``runs`` when it has none."""
    if bundle.curve is not None:
        return bundle.curve
    ok = [r for r in runs if switch in r.channels and target in r.channels]
    cc = CharacteristicCurve().fit(np.concatenate([r.column(switch) for r in ok]),
                                   np.concatenate([r.column(target) for r in ok]))
    return cc.centres_, cc.means_


def _plateaus(runs: Sequence[Run], segs: list[Segment], target: str) -> dict[tuple[int, int], float]:
    """The target's mean over each segment's plateau (steady samples), by (run, OC)."""
    out = {}
    for s in segs:
        if s.steady_start < s.stop and target in runs[s.run].channels:
            y = runs[s.run].column(target)[s.steady_start:s.stop]
            if np.isfinite(y).any():
                out[(s.run, s.oc)] = float(np.nanmean(y))
    return out


def context_panel(bundle: Bundle, runs: RunSet, schedule: Schedule, target: str) -> list[Block]:
    """I: the characteristic curve with every run on it, each OC's plateau levels, and the
    contextual curves (section 3.4): per OC a Dirichlet-process mixture on the temperatures,
    its clusters carried onto the speed profile and the curve, and each cluster's posterior
    of the amplitude's mean and spread (Gibbs sampling, Student-t likelihood; figure 3.6)."""
    sw = schedule.switch
    curve = fleet_curve(bundle, runs.runs, sw, target)
    fig = curve_figure(runs.runs, runs.labels, sw, target, curve,
                       [(oc.name, oc.speed) for oc in schedule.ocs])
    level = _plateaus(runs.runs, segment_runs(runs.runs, schedule), target)
    rows = []
    for j, oc in enumerate(schedule.ocs):
        vals = np.array([v for (_, o), v in level.items() if o == j])
        at = float(np.interp(oc.speed, curve[0], curve[1]))
        rows.append([oc.name, f"{oc.speed:.0f}", _f(at), str(vals.size),
                     *(_f(f(vals)) if vals.size else "-" for f in (np.mean, np.std, np.min, np.max))])
    src = "the model's" if bundle.curve is not None else "fitted on these runs (the model has none)"
    blocks: list[Block] = [
        Figure.of(fig, f"{target} against {sw}, one line per run; black: the characteristic curve ({src}); "
                  "dotted: the OCs' nominal speeds"),
        Table(["OC", f"{sw} (rpm)", "curve (mm/s)", "runs", "plateau mean", "spread (std)", "min", "max"],
              rows, f"{target} on each OC's plateau across the runs (mm/s)"),
    ]
    return blocks + _context_blocks(runs.runs, schedule, target)


def _context_blocks(runs: list[Run], schedule: Schedule, target: str) -> list[Block]:
    """The mixture clusters on the temperatures and their posteriors (or why there are none)."""
    from node.training.context import TEMPERATURES, context_curves
    from replay.views.context_plots import fig_context_clusters, fig_context_timeline, fig_context_violins

    missing = [c for c in TEMPERATURES if any(c not in r.channels for r in runs)]
    if missing:
        return [Paragraph(f"contextual curves: the recordings lack {', '.join(missing)} (the mixture "
                          f"clusters are taken on {', '.join(TEMPERATURES)})", note=True)]
    ctxs = [c for c in context_curves(runs, schedule, target) if c.n_clusters]
    if not ctxs:
        return [Paragraph("contextual curves: no OC has enough plateau samples for clusters", note=True)]
    rows = []
    for c in ctxs:
        for k, post in enumerate(c.posteriors):
            lo, mid, hi = np.percentile(post.mu, [5, 50, 95])
            at = [f"{x:.1f}" for x in c.centres[k]]
            rows.append([c.name, str(k + 1), str(post.n), f"{c.weights[k]:.2f}", ", ".join(at),
                         f"{mid:.3f} [{lo:.3f}, {hi:.3f}]", _f(float(np.median(post.sigma)))])
    busiest = sorted(ctxs, key=lambda c: -float(np.ptp([np.median(p.mu) for p in c.posteriors])))[:2]
    return [
        Heading("Contextual characteristic curves (section 3.4)"),
        Paragraph(f"Per OC, a Dirichlet-process Gaussian mixture (scikit-learn BayesianGaussianMixture) "
                  f"on the standardised plateau temperatures {', '.join(ctxs[0].channels)}: each cluster "
                  f"a thermal context. Its {target} mean and spread by Gibbs sampling with a Student-t "
                  f"likelihood (nu = {ctxs[0].posteriors[0].nu:g}: a few outliers do not move them)."),
        Figure.of(fig_context_timeline(ctxs), "Figure 3.5 (b): each OC's clusters over the plateau's "
                  "normalised time, a row per run: the clusters follow one another in time"),
        Figure.of(fig_context_clusters(busiest), "Figures 3.4 / 3.5: the two OCs whose clusters' means "
                  "differ most: the clusters in temperature space, on the speed profile and on the curve"),
        Figure.of(fig_context_violins(ctxs), f"Figure 3.6: posterior of each cluster's {target} mean (mu) "
                  "and spread (sigma), per OC"),
        Table(["OC", "cluster", "samples", "weight", f"centre ({', '.join(ctxs[0].channels)})",
               "mu: median [5 %, 95 %]", "sigma: median"], rows,
              f"{target} per thermal context (mm/s; 4 plateau samples a second)"),
    ]

def _oc_parameters(bundle: Bundle, runs: list[Run], schedule: Schedule, target: str
                   ) -> list[tuple[str, list[str], list[str], np.ndarray]]:
    """Per OC with a model: (OC name, its inputs, axis names, values (runs, axes)): each input at
    the OC switch and its plateau mean, then the engine-history parameters at the switch (NaN
    where a run does not reach the OC)."""
    inputs = sorted({c for r in bundle.ocs if r.model is not None for c in r.inputs})
    full = derived_runs(runs, schedule, target, [*inputs, *HISTORY_CHANNELS], bundle.curve,
                        bundle.config)
    segs = segment_runs(full, schedule, labels=label_runs(full, schedule, models=True))  # (each model's)
    out = []
    for res in bundle.ocs:
        if res.model is None:
            continue
        j = schedule.index(res.name)
        hist = [h for h in HISTORY_CHANNELS if h not in res.inputs]
        names = [n for c in res.inputs for n in (f"{c} at switch", f"{c} plateau")]
        names += [f"{h} at switch" for h in hist]
        values = np.full((len(runs), len(names)), np.nan)
        for s in (s for s in segs if s.oc == j):
            run = full[s.run]
            row = []
            for c in res.inputs:
                x = run.column(c)
                plateau = x[s.steady_start:s.stop]
                row += [x[s.start], float(np.nanmean(plateau)) if np.isfinite(plateau).any() else np.nan]
            row += [run.column(h)[s.start] for h in hist]
            values[s.run] = row  # a run that visits the OC twice: its last visit
        out.append((res.name, res.inputs, names, values))
    return out


def parameters_panel(bundle: Bundle, runs: RunSet, schedule: Schedule, target: str) -> list[Block]:
    """II: per OC, the model's inputs for every run (at the OC switch and their plateau means)
    and the engine-history parameters at the switch, as parallel coordinates and tables."""
    params = _oc_parameters(bundle, runs.runs, schedule, target)
    if not params:
        return [Paragraph(f"the model of {target} has no trained OC: no parameters to show", note=True)]
    fig = parallel_figure([(f"{n} ({target})", names, v) for n, _, names, v in params], runs.labels)
    blocks: list[Block] = []
    if fig is not None:
        blocks.append(Figure.of(fig, "Per OC, one line per run (colour as in the other panels): each "
                                "axis scaled to the runs' range, its minimum and maximum at its ends. "
                                "History: hist_energy rpm min, hist_rate rpm, hist_shutdown h, "
                                "hist_thermal degC (appendix A.2.5)."))
    for name, inputs, names, values in params:
        rows = [[label, *map(_g, row)] for label, row in zip(runs.labels, values)
                if np.isfinite(row).any()]
        blocks.append(Table(["run", *names], rows, f"{name}: inputs {', '.join(inputs)}"))
    return blocks + _dpcca_blocks(runs, schedule, target)


def _dpcca_blocks(runs: RunSet, schedule: Schedule, target: str) -> list[Block]:
    """The rho_DPCCA heatmap (figure 3.8; ``replay.report.correlation``)."""
    labels, channels, values = dpcca_rows(runs.runs, schedule, target)
    if not labels or not channels:
        return [Paragraph(f"no OC visit of 10 s or more with {target} and other channels: no rho_DPCCA "
                          "heatmap", note=True)]
    cut = f"; the first {MAX_ROWS} of {len(labels)} visits shown" if len(labels) > MAX_ROWS else ""
    fig = dpcca_figure(labels, channels, values, target)
    return [Figure.of(fig, f"|rho_DPCCA| between {target} and every other channel in each OC visit of each "
                      f"run (mean over the scales 0.25-8 s; the measure training ranks inputs by), one row "
                      f"per visit, grouped by OC; below {MASK} not drawn (dissertation figure 3.8){cut}")]


def _locate(runs: Sequence[Run], segs: list[Segment], names: Sequence[str], bed: str, t: float
            ) -> tuple[int | None, float, str]:
    """The run of bed ``bed`` holding time t (s since the epoch), the seconds into it, its OC there."""
    for i, run in enumerate(runs):
        if run.bed == bed and run.t.size and run.t[0] - 1.0 <= t <= run.t[-1] + 1.0:
            k = int(np.searchsorted(run.t, t))
            oc = next((names[s.oc] for s in segs if s.run == i and s.start <= k < s.stop), "-")
            return i, t - float(run.t[0]), oc
    return None, float("nan"), "-"


@dataclass(frozen=True)
class Episode:
    """One alarm episode of the node on a target: its run (its label; the bed when no run holds
    it), the OC there ("-": none), seconds into the run, its duration (s) and its reason."""

    run: str
    oc: str
    into: float
    duration: float
    reason: str


def target_episodes(alarms: NodeAlarms, runs: RunSet, schedule: Schedule, target: str) -> list[Episode]:
    """The node's alarm episodes on ``target``, each placed in its run and OC, in order."""
    mine = [e for e in alarms.episodes if (parse_monitor_key(e["key"]) or ("", ""))[1] == target]
    if not mine:
        return []
    segs = segment_runs(runs.runs, schedule)
    out = []
    for e in mine:
        bed = (parse_monitor_key(e["key"]) or ("", ""))[0]
        i, into, oc = _locate(runs.runs, segs, schedule.segments, bed, float(e["start"]))
        out.append(Episode(runs.labels[i] if i is not None else bed, oc, into,
                           float(e["end"]) - float(e["start"]), str(e["reason"])))
    return out


def _alarm_blocks(alarms: NodeAlarms, runs: RunSet, schedule: Schedule, target: str) -> list[Block]:
    """The node's alarm episodes on ``target``: a summary line, by reason, one by one."""
    mine = target_episodes(alarms, runs, schedule, target)
    hours = alarms.hours
    rate = len(mine) / hours if hours else 0.0
    reasons = Counter(e.reason for e in mine)
    blocks: list[Block] = [
        Heading("Alarms of the node", 4),
        Paragraph("The node replayed offline over the recordings "
                  f"({', '.join(r for r, _, _ in alarms.per_file)}; "
                  + ("one engine's in this order, its history carried from one to the next"
                     if alarms.carried else "each from a cold engine")
                  + f"): {len(mine)} alarm episode(s) on {target} in "
                  f"{hours * 60:.1f} min of data, {rate:.2f} per hour; by reason: "
                  + (", ".join(f"{k} {v}" for k, v in sorted(reasons.items())) or "none") + "."),
    ]
    if mine:
        rows = [[e.run, e.oc, _f(e.into, 1), _f(e.duration, 1), e.reason] for e in mine[:MAX_EPISODES]]
        more = f" (the first {MAX_EPISODES} of {len(mine)})" if len(mine) > MAX_EPISODES else ""
        blocks.append(Table(["run", "OC", "start (s into the run)", "duration (s)", "reason"], rows,
                            f"alarm episodes on {target}{more}"))
    return blocks


def _provenance_text(labels: Sequence[str], kinds: Sequence[str]) -> str:
    """Which runs are held out and which in-sample (``node.training.provenance``), in words."""
    from node.training.provenance import HELD_OUT, IN_SAMPLE, UNKNOWN

    why = {HELD_OUT: "Held-out runs (not among the model's training runs)",
           IN_SAMPLE: "In-sample runs (among the model's training runs: their errors tell how the model "
                      "fits its training data, not how it does on new runs; CV eps_td is the "
                      "cross-validated estimate)",
           UNKNOWN: "Runs of unknown provenance (the model records its training recordings' sha256 but "
                    "not its runs, and these runs' recordings are not among them)"}
    parts = [f"{text}: {', '.join(lab for lab, k in zip(labels, kinds) if k == kind)}."
             for kind, text in why.items() if kind in kinds]
    if HELD_OUT not in kinds:
        parts.append("None of these runs is held out.")
    return " ".join(parts)


@dataclass(frozen=True)
class Scores:
    """One target's free-run predictions of every OC segment of the runs (``predict_segments``),
    the characteristic curve's on the very samples (one array per prediction), and each run's
    provenance (``node.training.provenance``: in-sample, held-out or unknown)."""

    preds: list[SegmentPrediction]
    base: list[np.ndarray]
    kinds: list[str]

    def of(self, kind: str) -> tuple[list[SegmentPrediction], list[np.ndarray]]:
        """The predictions and the curve's of the runs of provenance ``kind``."""
        mine = [i for i, p in enumerate(self.preds) if self.kinds[p.run] == kind]
        return [self.preds[i] for i in mine], [self.base[i] for i in mine]


def score_runs(bundle: Bundle, runs: RunSet, schedule: Schedule, target: str) -> Scores:
    """The ``Scores`` of ``target``'s bundle over ``runs`` (the summary's and panel III's)."""
    from node.training.provenance import run_provenance

    preds = predict_segments(bundle.ocs, runs.runs, schedule, target, bundle.curve, bundle.config)
    curve = fleet_curve(bundle, runs.runs, schedule.switch, target)
    base = curve_predictions(curve, runs.runs, preds, schedule.switch, target)
    return Scores(preds, base, run_provenance(bundle, runs.runs, runs.sha256))


@dataclass(frozen=True)
class OCScore:
    """One OC (or the rundown) over some runs: the model's kind ("-": none), segments, eps_td and
    R^2 of the model (every sample, one without a prediction a miss) and of the characteristic
    curve on the same samples, the CV eps_td, the samples the evaluation's alarm rule flags, the
    samples modelled and outside the envelope, and the share of samples predicted."""

    name: str
    kind: str
    segments: int
    eps: float
    r2: float
    curve_eps: float
    curve_r2: float
    cv_eps: float
    alarm_samples: int
    samples: int
    outside: int
    guarded: int = 0  # samples the curve guard predicted with the characteristic curve
    coverage: float = float("nan")  # the share of the OC's samples predicted

    @property
    def outside_share(self) -> str:
        """The share of samples outside the envelope, e.g. ``'4.1 %'`` (``'-'``: no sample)."""
        return f"{100.0 * self.outside / self.samples:.1f} %" if self.samples else "-"

    @property
    def guarded_share(self) -> str:
        """The share of samples predicted with the curve (the guard), e.g. ``'2.0 %'``."""
        return f"{100.0 * self.guarded / self.samples:.1f} %" if self.samples else "-"


def oc_scores(bundle: Bundle, schedule: Schedule, preds: list[SegmentPrediction], base: list[np.ndarray]
              ) -> list[OCScore]:
    """Per OC of the schedule, the ``OCScore`` of ``preds`` (the model's) and ``base`` (the
    characteristic curve's on the same samples), pooled over their segments."""
    out = []
    for j, e in enumerate(score_segments(bundle.ocs, schedule, preds)):
        res = bundle.oc(e.name)
        pairs = scored_pairs([p for p in preds if p.oc in pooled(schedule, j)])
        curve_pairs = [(p.measured, b) for p, b in zip(preds, base) if p.oc in pooled(schedule, j)]
        out.append(OCScore(
            e.name, res.kind if res else "-", e.n_segments, e.eps,
            pooled_r2(pairs) if pairs else float("nan"),
            pooled_eps(curve_pairs) if curve_pairs else float("nan"),
            pooled_r2(curve_pairs) if curve_pairs else float("nan"),
            res.cv_eps if res else float("nan"), e.alarm_samples, e.predicted, e.outside, e.guarded,
            e.coverage))
    return out


def _score_blocks(bundle: Bundle, schedule: Schedule, target: str, preds: list[SegmentPrediction],
                  base: list[np.ndarray], word: str) -> list[Block]:
    """The bar charts and the table of eps_td and R^2 per OC over ``preds`` (the model's) and
    ``base`` (the characteristic curve's on the same samples), their runs named ``word``."""
    scores = oc_scores(bundle, schedule, preds, base)
    rows = [[s.name, s.kind, str(s.segments), _f(s.eps), _f(s.r2), _pct(s.coverage), _f(s.curve_eps),
             _f(s.curve_r2), _f(s.cv_eps), str(s.alarm_samples), s.outside_share, s.guarded_share]
            for s in scores]
    return [
        Figure.of(score_figure(schedule.segments, [(f"{word} eps_td", [s.eps for s in scores],
                                                 [s.curve_eps for s in scores], None),
                                                (f"{word} R\u00b2", [s.r2 for s in scores],
                                                 [s.curve_r2 for s in scores], R2_FLOOR)]),
                  f"{target}, {word} runs: per OC, the model (blue) and the characteristic curve (grey) "
                  "over the same samples: relative error eps_td (lower is better) and R\u00b2 (1 is a "
                  f"perfect fit; below {R2_FLOOR:g} cut, its value written)"),
        Table(["OC", "model", "segments", f"{word} eps_td", f"{word} R\u00b2", "coverage", "curve eps_td",
               "curve R\u00b2", "CV eps_td", "alarm samples", "outside the envelope", "on the curve"], rows,
              f"{target}: the {word} runs' OC segments and rundowns, pooled (free run from the OC switch, "
              "seeded from the measured past, as the node runs it; every sample scored, one without a "
              "prediction a miss; coverage: the share predicted); outside the envelope: the share of samples "
              "beyond the region the training runs covered (predicted with the inputs held at its "
              "edge, the band widened); on the curve: the share the curve guard predicted with the "
              "characteristic curve (where, so far in the OC visit, the model erred more)"),
    ]


def validation_panel(bundle: Bundle, runs: RunSet, schedule: Schedule, target: str,
                     alarms: NodeAlarms, scores: Scores | None = None) -> list[Block]:
    """III: per OC, eps_td and R^2 of the model beside the characteristic curve's, for the
    held-out runs and the in-sample ones apart (``node.training.provenance``), the measured and
    predicted segments of every run, and the node's alarms with their reasons.

    scores: ``score_runs`` of these (default: computed here)."""
    from node.training.provenance import PROVENANCES, TABLE_WORDS

    if scores is None:
        scores = score_runs(bundle, runs, schedule, target)
    kinds = scores.kinds
    blocks: list[Block] = [Paragraph(_provenance_text(runs.labels, kinds))]
    for kind in (k for k in PROVENANCES if k in kinds):
        blocks += _score_blocks(bundle, schedule, target, *scores.of(kind), TABLE_WORDS[kind])
    seg_fig = segments_figure(schedule.models, scores.preds, target, run_colours(len(runs.runs)))
    if seg_fig is not None:
        blocks.append(Figure.of(seg_fig, f"{target} measured (solid) and predicted (dashed) per OC, "
                                "from each OC switch; a colour per run, as in panels I and II"))
    else:
        blocks.append(Paragraph(f"no OC of the model of {target} was found in these runs", note=True))
    return blocks + _alarm_blocks(alarms, runs, schedule, target)


def prediction_panel(bundle: Bundle, runs: RunSet, schedule: Schedule, target: str,
                     kinds: Sequence[str] | None = None) -> list[Block]:
    """IV: the prediction from the profile and the engine history alone (no measured order: the
    node's models chained through the OCs, ``node.training.prediction``): each recorded run's
    against what it measured, eps_td per OC, each run named held-out or in-sample and each set
    pooled apart; then the schedule as a planned profile after these runs and after a cold
    start, with the history parameters of appendix A.2.5 (figure A.5).

    kinds: each run's provenance (default: ``run_provenance`` of the bundle)."""
    from node.contract import OrdervibError
    from node.training.prediction import (
        RecordedPrediction,
        history_after,
        needed_channels,
        predict_profile,
        predict_recorded_runs,
        recorded_eps,
        schedule_profile,
        stated_history,
        with_interval,
    )
    from node.training.prediction_aids import AmplitudeBound, InputFill, IntervalWidths
    from node.training.provenance import PROVENANCES, TABLE_WORDS, run_provenance
    from replay.views.prediction_plots import fig_history, fig_prediction

    blocks: list[Block] = []
    try:
        bound = AmplitudeBound.fit(runs.runs, schedule, [bundle.target])
        levels = InputFill.fit(runs.runs, schedule, [bundle.target], "runs")
        recs = predict_recorded_runs(bundle, runs.runs, bound=bound, levels=levels)
    except OrdervibError as exc:
        return [Paragraph(f"prediction: {exc}", note=True)]
    widths = IntervalWidths.from_recorded(bundle, recs)
    recs = [dataclasses.replace(r, prediction=with_interval(r.prediction, widths)) for r in recs]
    eps = recorded_eps(recs)[0]
    cc = CharacteristicCurve()
    cc.centres_, cc.means_ = fleet_curve(bundle, runs.runs, schedule.switch, target)
    curve_recs = [RecordedPrediction(  # the characteristic curve on the very samples
        dataclasses.replace(r.prediction, predicted=cc.predict(np.nan_to_num(r.prediction.speed))[:, None]),
        r.measured, r.segments) for r in recs]
    base = recorded_eps(curve_recs)[0]
    present = [j for j in range(len(schedule.names)) if np.isfinite(eps[j])]
    if kinds is None:
        kinds = run_provenance(bundle, runs.runs, runs.sha256)
    rows = []
    for label, kind, rec in zip(runs.labels, kinds, recs):
        rows.append([label, TABLE_WORDS[kind], *(_f(float(rec.eps[0, j])) for j in present)])
    for kind in (k for k in PROVENANCES if k in kinds):
        for name, of in (("", recs), ("curve, ", curve_recs)):
            pooled = recorded_eps([r for r, k in zip(of, kinds) if k == kind])[0]
            rows.append([f"{name}{TABLE_WORDS[kind]} runs", "pooled",
                         *(_f(float(pooled[j])) for j in present)])
    rows.append(["all runs", "pooled", *(_f(float(eps[j])) for j in present)])
    rows.append(["curve, all runs", "pooled", *(_f(float(base[j])) for j in present)])
    blocks += [
        Paragraph(f"{target} predicted from each run's own speed profile, inputs and engine history, "
                  "without its measured order (each OC's model seeded from the prediction of the OC "
                  "before it; the first from the fleet level), against what the run measured; never "
                  f"below 0 nor above {bound.factor:g} x the largest these runs measured in the OC within "
                  f"{bound.window:g} rpm, with the {100 * widths.level:g} % interval of a new run from "
                  "these runs' residuals."),
        Figure.of(fig_prediction(recs[0]), f"{runs.labels[0]}: predicted against measured"),
        Table(["run", "run set", *(schedule.names[j] for j in present)], rows,
              f"{target}: eps_td of the prediction per OC, each run held-out or in-sample (among the "
              "model's training runs); pooled per run set and over all runs, each beside the characteristic "
              "curve on the same samples"),
    ]
    plan = schedule_profile(schedule)
    start = float(plan.t[0])
    try:
        fill = InputFill.fit(runs.runs, schedule, needed_channels(bundle))
        now = history_after(runs.runs, bundle)
        states = ((now, "after these runs"), (stated_history(start, 24.0), "cold (24 h)"))
        preds = [predict_profile(bundle, plan, state, fill, label=label, bound=bound, widths=widths,
                                 levels=levels)
                 for state, label in states]
    except OrdervibError as exc:
        return blocks + [Paragraph(f"planned pass-off: {exc}", note=True)]
    blocks += [
        Heading("A planned pass-off"),
        Paragraph(f"The schedule's plateaus in order ({len(schedule.names)} OCs, 60 s each, ramps at 250 "
                  "rpm/s); inputs the profile lacks filled from these runs at the planned speed in each OC; "
                  "the engine's history as these runs leave it, and after 24 h standing."),
        Figure.of(fig_prediction(preds), f"expected {target} over the planned profile"),
        Figure.of(fig_history(preds), "Figure A.5: the speed profile, the cumulative energy (hist_energy, "
                  "rpm min) and the cumulative rate of change of speed (hist_rate, rpm)"),
    ]
    return blocks
