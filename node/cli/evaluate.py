"""``ordervib evaluate``: a trained model on recordings: per-OC errors, false alarms, PNG.

Each run is held-out or in-sample (among the model's training runs), by the one rule of
``node.training.provenance``; each kind has its own table and mean line, named by it, so an
in-sample error is never printed as a held-out one.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from node.cli.outputs import check_output, replacing
from node.cli.results import Results, add_json_option
from node.contract import OrdervibError

if TYPE_CHECKING:
    from node.models.bundle import Bundle
    from node.training.evaluation import SegmentPrediction
    from node.training.runs import Run

log = logging.getLogger(__name__)

NAME = "evaluate"
HELP = ("evaluate a trained model on recordings (a table of the held-out runs, one of the in-sample ones, "
        "false alarms, PNG)")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("model", metavar="MODEL", help="model bundle directory")
    p.add_argument("recordings", nargs="+", metavar="REC.mcap",
                   help="recordings (a run among the model's training runs is in-sample, others held-out)")
    p.add_argument("--png", default=None, metavar="OUT.png",
                   help="plot of predicted against measured per OC (default MODEL/evaluation.png)")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")
    add_json_option(p)


def run(args: argparse.Namespace) -> int:
    from node.models.bundle import load_model
    from node.training.fit import read_sourced
    from node.training.provenance import run_provenance
    from replay.offline import node_alarms

    model = load_model(args.model)
    if not any(r.model is not None for b in model.bundles for r in b.ocs):
        raise OrdervibError(f"{args.model} holds no trained OC: nothing to evaluate")
    png = Path(args.png) if args.png else Path(args.model) / "evaluation.png"
    several = len(model.bundles) > 1  # a plot per target: OUT-<target>.png
    pngs = [png.with_name(f"{png.stem}-{t}{png.suffix}") if several else png for t in model.targets]
    for path in pngs:
        check_output(str(path), "--png", suffix=".png", inputs=[args.model, *args.recordings])
    runs, recordings, source = read_sourced(args.recordings, args.quiet)
    kinds = run_provenance(model, runs, [recordings[i]["sha256"] for i in source])
    out = Results(args.json)
    for line in _provenance_lines(kinds, source, [r["path"] for r in recordings]):
        out.line(line)
    preds = []
    for bundle in model.bundles:
        if several:
            out.line(f"target {bundle.target}:")
        preds.append(_tables(bundle, runs, kinds, out))
    alarms = node_alarms(args.recordings, model)
    out.line(f"{alarms.line()} (over {_counts(kinds)} run(s))", "false_alarms", alarms.line())
    plots = []
    for bundle, mine, path in zip(model.bundles, preds, pngs):
        if _plot(bundle, mine, path):
            plots.append(str(path))
            out.line(f"plot written to {path}", "plots", plots)
    out.done()
    return 0


def _counts(kinds: list[str]) -> str:
    """``"1 held-out, 4 in-sample"``: how many runs of each provenance there are (none: left out)."""
    from node.training.provenance import PROVENANCES

    return ", ".join(f"{kinds.count(k)} {k}" for k in PROVENANCES if k in kinds)


def _provenance_lines(kinds: list[str], source: list[int], paths: list[str]) -> list[str]:
    """A line per recording (``paths``; run i is of ``paths[source[i]]``) with its runs'
    provenance; a line when no run is held out, and one when the model cannot tell (trained
    before it recorded its runs)."""
    from node.training.provenance import HELD_OUT, UNKNOWN

    lines = []
    for i, path in enumerate(paths):
        mine = [k for k, s in zip(kinds, source) if s == i]
        lines.append(f"{path}: {len(mine)} run(s)" + (f", {_counts(mine)}" if mine else ""))
    if HELD_OUT not in kinds:
        known = " known to be" if UNKNOWN in kinds else ""
        lines.append(f"none of the {len(kinds)} run(s) is{known} held out ({_counts(kinds)}): CV eps_td is "
                     "the model's cross-validated estimate")
    if UNKNOWN in kinds:
        lines.append(f"unknown provenance: {kinds.count(UNKNOWN)} run(s): the model records its training "
                     "recordings' sha256 but not its runs (trained by an older ordervib), and these "
                     "recordings are not among them")
    return lines


def _tables(bundle: Bundle, runs: list[Run], kinds: list[str], out: Results) -> list[SegmentPrediction]:
    """Put one target's per-OC table of each provenance present (held-out first) in ``out``;
    all runs' predictions (predicted together, in time order, as the node runs them)."""
    from node.training.evaluation import predict_segments
    from node.training.provenance import IN_SAMPLE, PROVENANCES, TABLE_WORDS

    preds = predict_segments(bundle.ocs, runs, bundle.schedule, bundle.target, bundle.curve,
                             bundle.config)
    for kind in (k for k in PROVENANCES if k in kinds):
        among = " (among the model's training runs)" if kind == IN_SAMPLE else ""
        out.line(f"{TABLE_WORDS[kind]} runs: {kinds.count(kind)} of {len(kinds)}{among}")
        _table(bundle, runs, [p for p in preds if kinds[p.run] == kind], TABLE_WORDS[kind], out,
               f"{bundle.target} {TABLE_WORDS[kind]}")
    return preds


def _table(bundle: Bundle, runs: list[Run], preds: list[SegmentPrediction], word: str, out: Results,
           key: str) -> None:
    """The per-OC table of one target's bundle over the predictions ``preds`` of some of
    ``runs``, their eps_td named ``word`` (e.g. held-out), and its mean line, in ``out`` (as
    JSON: under ``key``)."""
    from node.training.evaluation import coverage, curve_eps, score_segments, start_evaluation

    evals = score_segments(bundle.ocs, bundle.schedule, preds)
    base_eps = [float("nan")] * len(evals)
    if bundle.curve is not None:
        base_eps = curve_eps(bundle.curve, runs, preds, bundle.schedule, bundle.target)
    header = ["OC", "model", "segments", f"{word} eps_td", "coverage", "CV eps_td", "baseline eps_td",
              "outside", "on the curve"]
    rows = []
    hold, base = [], []
    for e, b in zip(evals, base_eps):
        res = bundle.oc(e.name)
        rows.append([e.name, res.kind if res else "-", str(e.n_segments), _f(e.eps),
                     _share(e.predicted, e.samples), _f(res.cv_eps if res else float("nan")), _f(b),
                     _share(e.outside, e.predicted), _share(e.guarded, e.predicted)])
        if np.isfinite(e.eps):
            hold.append(e.eps)
            base.append(b)
    out.table(key, header, rows)
    if hold:
        out.line(f"mean {word} eps_td {np.mean(hold):.3f} over {len(hold)} segments, every sample scored "
                 f"(one without a prediction a miss) (characteristic-curve baseline {np.nanmean(base):.3f})",
                 f"{key} mean eps_td",
                 {"eps_td": float(np.mean(hold)), "ocs": len(hold), "baseline": float(np.nanmean(base))})
    start = start_evaluation(bundle.ocs, bundle.schedule, preds)
    if start is not None:
        res = bundle.oc(start.name)
        cv = res.cv_eps if res else float("nan")
        out.line(f"of {bundle.schedule.names[0]}, its start until the speed leaves the speed it held (model "
                 f"{start.name}): {res.kind if res else '-'}, {word} eps_td {_f(start.eps)}, coverage "
                 f"{_share(start.predicted, start.samples)}, CV eps_td {_f(cv)}", f"{key} start",
                 {"model": start.name, "eps_td": start.eps, "coverage": start.coverage, "cv_eps_td": cv})
    covered, total = coverage(runs, bundle.schedule, preds, bundle.config)
    if total:
        out.line(f"coverage light-off to standstill: {_share(covered, total)} of {total} samples predicted",
                 f"{key} coverage", {"predicted": covered, "samples": total})
    outside, samples = sum(e.outside for e in evals), sum(e.predicted for e in evals)
    if samples:
        guarded = sum(e.guarded for e in evals)
        counts = {"modelled": samples, "outside": outside, "on_the_curve": guarded}
        out.line(f"outside the training runs' envelope: {_share(outside, samples)} of {samples} modelled "
                 f"samples (predicted with the inputs held at its edge, the band widened)",
                 f"{key} samples", counts)
        out.line(f"on the characteristic curve: {_share(guarded, samples)} of the modelled samples (the "
                 f"curve guard: where, so far in the OC, the model erred more than the curve)",
                 f"{key} samples", counts)


def _share(part: int, whole: int) -> str:
    """'12.5 %' of a count; '-' of none."""
    return f"{100.0 * part / whole:.1f} %" if whole else "-"


def _f(x: float) -> str:
    return f"{x:.3f}" if np.isfinite(x) else "-"


def _plot(bundle: Bundle, preds: list[SegmentPrediction], png: Path) -> bool:
    """Predicted against measured per OC, written to png; False when no OC was found."""
    from replay.report.figures import segments_figure

    fig = segments_figure(bundle.schedule.models, preds, bundle.target)
    if fig is None:
        log.warning("no OC of the model in the recordings: no plot")
        return False
    with replacing(str(png)) as tmp:  # an existing plot is replaced only by a complete one
        fig.savefig(tmp, dpi=90, format="png")
    return True
