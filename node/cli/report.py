"""``ordervib report``: the engineer's report of pass-off runs as one self-contained HTML file.

With acceptance limits in the model's schedule, the pass-off verdict first (per target each
run's pass or fail, margin, engine, bed and date; the forecasts against what happened). A
summary (per target a verdict and a table of the OCs: kind, eps_td of the model and the curve
per run set, held-out or in-sample by ``node.training.provenance``, outside the
envelope, alarm episodes), then five panels folded in ``<details>`` (``replay.report``): I the
characteristic curve in context, II the per-OC parameters of every run, III validation
(measured against predicted, eps_td and R^2 beside the characteristic curve's, the node's
alarms), IV prediction, V the transients (``replay.report.transients``). Plots are embedded
PNGs: the file opens in any browser, with no server and no network.
"""

from __future__ import annotations

import argparse
import logging

from node.cli.outputs import check_output, replacing
from node.contract import OrdervibError

log = logging.getLogger(__name__)

NAME = "report"
HELP = ("the engineer's report of pass-off runs (a summary, then curves in context, parameters, validation, "
        "prediction) as one HTML file")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("recordings", nargs="+", metavar="REC.mcap",
                   help="pass-off recordings of one engine (its history is derived from them in time order)")
    p.add_argument("--model", required=True, metavar="MODEL", help="model bundle directory")
    p.add_argument("--out", required=True, metavar="REPORT.html", help="the report to write")
    p.add_argument("--target", default=None, metavar="LIST",
                   help="target(s) to report, comma-separated (default: every target of the model)")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")


def _targets(spec: str | None, available: list[str]) -> list[str]:
    """The targets of ``--target`` (each one of the model's), default all of them."""
    if spec is None:
        return list(available)
    targets = [t.strip() for t in spec.split(",") if t.strip()]
    unknown = [t for t in targets if t not in available]
    if not targets or unknown:
        raise OrdervibError(f"--target {spec!r}: the model's targets are {', '.join(available)}")
    return list(dict.fromkeys(targets))


def run(args: argparse.Namespace) -> int:
    from node.mcap import open_recording, recorded_engine
    from node.models.bundle import load_model
    from node.training.fit import read_sourced

    for rec in args.recordings:  # one line for a missing or non-MCAP file, before any output
        with open_recording(rec):
            pass
    model = load_model(args.model)
    if not any(r.model is not None for b in model.bundles for r in b.ocs):
        raise OrdervibError(f"{args.model} holds no trained OC: nothing to report")
    targets = _targets(args.target, model.targets)
    check_output(args.out, "--out", suffix=".html", inputs=[args.model, *args.recordings])

    from node.cli.logs import Progress
    from replay.report.build import build_report
    from replay.report.panels import RunSet

    runs, labels, hashes, engines = [], [], [], []
    for rec in args.recordings:
        found, read, _ = read_sourced([rec], args.quiet)
        runs += found
        labels += [RunSet.label(rec, i) for i in range(len(found))]
        hashes += [read[0]["sha256"]] * len(found)  # whether a run is in-sample: by it and its span
        engines += [recorded_engine(rec)] * len(found)
    needed = [model.schedule.switch, *targets]
    for i, r in enumerate(runs):
        missing = [c for c in needed if c not in r.channels]
        if missing:
            raise OrdervibError(f"run {labels[i]} has no channel {', '.join(missing)} "
                                f"(the schedule's switch and the targets are needed)")
    page = build_report(model, RunSet(runs, labels, hashes, engines), args.recordings, targets, args.model,
                        progress=Progress("report", log))
    with replacing(args.out) as tmp:  # an existing report is replaced only by a complete one
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(page)
    print(f"report written to {args.out}")
    return 0
