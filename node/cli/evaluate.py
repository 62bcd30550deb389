"""``ordervib evaluate``: a trained model on held-out recordings: per-OC errors, false alarms, PNG."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from node.cli.outputs import check_output, replacing
from node.console.table import print_table
from node.contract import OrdervibError

if TYPE_CHECKING:
    from node.models.bundle import Bundle
    from node.training.evaluation import SegmentPrediction
    from node.training.runs import Run

log = logging.getLogger(__name__)

NAME = "evaluate"
HELP = "evaluate a trained model on held-out recordings (table, false alarms, PNG)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("model", metavar="MODEL", help="model bundle directory")
    p.add_argument("recordings", nargs="+", metavar="REC.mcap", help="held-out recordings")
    p.add_argument("--png", default=None, metavar="OUT.png",
                   help="plot of predicted against measured per OC (default MODEL/evaluation.png)")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")


def run(args: argparse.Namespace) -> int:
    from node.models.bundle import load_model
    from node.training.fit import load_runs
    from replay.offline import node_alarms

    model = load_model(args.model)
    if not any(r.model is not None for b in model.bundles for r in b.ocs):
        raise OrdervibError(f"{args.model} holds no trained OC: nothing to evaluate")
    png = Path(args.png) if args.png else Path(args.model) / "evaluation.png"
    several = len(model.bundles) > 1  # a plot per target: OUT-<target>.png
    pngs = [png.with_name(f"{png.stem}-{t}{png.suffix}") if several else png for t in model.targets]
    for path in pngs:
        check_output(str(path), "--png", suffix=".png", inputs=[args.model, *args.recordings])
    runs = load_runs(args.recordings, args.quiet)
    preds = []
    for bundle in model.bundles:
        if several:
            print(f"target {bundle.target}:")
        preds.append(_table(bundle, runs))
    print(node_alarms(args.recordings, model).line())
    for bundle, mine, path in zip(model.bundles, preds, pngs):
        if _plot(bundle, mine, path):
            print(f"plot written to {path}")
    return 0


def _table(bundle: Bundle, runs: list[Run]) -> list[SegmentPrediction]:
    """Print the per-OC held-out table of one target's bundle over ``runs``; its predictions."""
    from node.training.evaluation import curve_eps, evaluate

    evals, preds = evaluate(bundle.ocs, runs, bundle.schedule, bundle.target, bundle.curve,
                            bundle.config)
    base_eps = [float("nan")] * len(evals)
    if bundle.curve is not None:
        base_eps = curve_eps(bundle.curve, runs, preds, bundle.schedule, bundle.target)
    header = ["OC", "model", "segments", "held-out eps_td", "CV eps_td", "baseline eps_td", "outside"]
    rows = []
    hold, base = [], []
    for e, b in zip(evals, base_eps):
        res = bundle.oc(e.name)
        rows.append([e.name, res.kind if res else "-", str(e.n_segments), _f(e.eps),
                     _f(res.cv_eps if res else float("nan")), _f(b), _share(e.outside, e.samples)])
        if np.isfinite(e.eps):
            hold.append(e.eps)
            base.append(b)
    print_table(header, rows)
    if hold:
        print(f"mean held-out eps_td {np.mean(hold):.3f} over {len(hold)} OCs "
              f"(characteristic-curve baseline {np.nanmean(base):.3f})")
    outside, samples = sum(e.outside for e in evals), sum(e.samples for e in evals if np.isfinite(e.eps))
    if samples:
        print(f"outside the training runs' envelope: {_share(outside, samples)} of {samples} modelled "
              f"samples (predicted with the inputs held at its edge, the band widened)")
    return preds


def _share(part: int, whole: int) -> str:
    """'12.5 %' of a count; '-' of none."""
    return f"{100.0 * part / whole:.1f} %" if whole else "-"


def _f(x: float) -> str:
    return f"{x:.3f}" if np.isfinite(x) else "-"


def _plot(bundle: Bundle, preds: list[SegmentPrediction], png: Path) -> bool:
    """Predicted against measured per OC, written to png; False when no OC was found."""
    from replay.report.figures import segments_figure

    fig = segments_figure(bundle.schedule.names, preds, bundle.target)
    if fig is None:
        log.warning("no OC of the model in the recordings: no plot")
        return False
    with replacing(str(png)) as tmp:  # an existing plot is replaced only by a complete one
        fig.savefig(tmp, dpi=90, format="png")
    return True
