"""``ordervib predict``: the expected order amplitudes for a planned speed profile and a stated
engine history (``node.training.prediction``; the toolbox's panel IV, appendix A.2.4-A.2.5);
with acceptance limits (the schedule given's, else the model's), per planned OC the predicted
peak and the probability of exceeding its limit (``node.training.prediction_limits``)."""

from __future__ import annotations

import argparse
import logging
import math
import os
from typing import TYPE_CHECKING

from node.cli.outputs import check_output, replacing
from node.cli.results import Results, add_json_option
from node.contract.errors import OrdervibError

if TYPE_CHECKING:
    from node.contract.schedule import Limit, Schedule
    from node.models.bundle import Model
    from node.runtime.history import EngineState
    from node.training.prediction import Prediction, Profile

log = logging.getLogger(__name__)

OUTSIDE_STATUS = 3  # the exit status when the plan leaves what the model knows (rows marked)

NAME = "predict"
HELP = ("expected order amplitudes for a planned speed profile (CSV, or a schedule's plateaus) "
        "and engine history")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--model", required=True, metavar="MODEL", help="model bundle directory")
    p.add_argument("--profile", required=True, metavar="PROFILE",
                   help="planned profile: a CSV with columns t (s) and the switch speed (nB, rpm), "
                        "optionally any other sensor channel (breakpoints, interpolated linearly to "
                        "40 Hz; a step in t of 5 s or more between two rows with the engine off starts "
                        "a new engine run); or a schedule "
                        "(.toml): its plateaus in order, each held --plateau-s. The limits: its [[limit]] "
                        "tables, else the model's schedule's; with limits, per OC the predicted peak and "
                        "p_exceed, and the CSV's yB_limit and yB_p_exceed")
    p.add_argument("--out", required=True, metavar="OUT.csv",
                   help="the prediction at 40 Hz: history, t, oc, each target with its 90 %% interval "
                        "(yB, yB_lo, yB_hi), the engine-history channels and every input fed to the "
                        "node; notes above the header (lines starting with #) state the bounds and where "
                        "they acted, the interval, and how each filled channel was filled")
    p.add_argument("--png", metavar="OUT.png",
                   help="plot of the expected amplitudes over the profile, with their interval and bound")
    p.add_argument("--history-png", metavar="OUT.png",
                   help="plot of the engine-history parameters over the profile (figure A.5)")
    p.add_argument("--shutdown-hours", type=float, nargs="+", metavar="H",
                   help="hours the engine stood before the profile; several: one prediction each "
                        "(default: as --engine-state says, else unknown: a cold engine)")
    p.add_argument("--energy", type=float, metavar="RPM_MIN",
                   help="the cumulative energy parameter the engine carried when it last ran, rpm min "
                        "(default: as --engine-state says, else 0)")
    p.add_argument("--engine-state", metavar="FILE.json",
                   help="a node's engine-history file: the history before the profile")
    p.add_argument("--bed", metavar="BED", help="the bed of --engine-state (needed when it holds several)")
    p.add_argument("--train", nargs="+", metavar="REC.mcap",
                   help="recordings whose runs fill the inputs the profile lacks and set the upper bound "
                        "and the interval (default: the training runs the model keeps, training-runs.npz; "
                        "else its training recordings, when they are where and as they were at training)")
    p.add_argument("--plateau-s", type=float, default=60.0, metavar="S",
                   help="with a schedule as --profile: seconds each plateau is held (default 60)")
    p.add_argument("--seed", choices=("chain", "absent"), default="chain",
                   help="what the node is fed as the unmeasured target: the prediction so far (chain, "
                        "default) or nothing (absent: models start from rest)")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")
    add_json_option(p)


def run(args: argparse.Namespace) -> int:
    from node.models.bundle import load_model
    from node.runtime.history import HISTORY_CHANNELS
    from node.training.prediction import predict_profile, stated_history, takes_history
    from node.training.prediction_limits import plan_limits
    from node.training.prediction_setup import prepare_prediction

    model = load_model(args.model)
    profile, given = _profile(args, model)
    limits = plan_limits(given, model.schedule, model.targets)
    engine = _engine(args)
    hours: list[float | None] = list(args.shutdown_hours) if args.shutdown_hours else [None]
    for h in hours:
        if h is not None and not (math.isfinite(h) and h >= 0):
            raise OrdervibError(f"--shutdown-hours must be numbers of hours >= 0, got {h:g}")
    if args.energy is not None and not (math.isfinite(args.energy) and args.energy >= 0):
        raise OrdervibError(f"--energy must be a number >= 0 (rpm min), got {args.energy:g}")
    inputs = [args.model, args.profile, *(args.train or [])]
    if args.engine_state:
        inputs.append(args.engine_state)
    check_output(args.out, "--out", suffix=".csv", inputs=inputs)
    pngs = [(args.png, "--png"), (args.history_png, "--history-png")]
    for path, option in pngs:
        if path:
            check_output(path, option, suffix=".png", inputs=[*inputs, args.out])
    if args.png and args.history_png and os.path.abspath(args.png) == os.path.abspath(args.history_png):
        raise OrdervibError("--png and --history-png must differ")
    if (args.shutdown_hours or args.energy is not None or args.engine_state) and not takes_history(model):
        log.warning("the model takes no engine-history input (%s): the stated history (--shutdown-hours, "
                    "--energy, --engine-state) cannot change its prediction, every history gives the "
                    "same numbers", ", ".join(HISTORY_CHANNELS))
    setup = prepare_prediction(model, args.model, profile, args.train, args.quiet)
    preds = []
    for h in hours:
        state = stated_history(setup.start, h, args.energy, engine)
        label = "" if h is None else f"{h:g}"
        preds.append(predict_profile(model, profile, state, setup.fill, args.seed, label, setup.bound,
                                     setup.widths, setup.levels, setup.speeds))
        stood = f" ({h:g} h stood)" if h is not None else ""
        for line in preds[-1].bound_notes():
            (log.warning if "capped" in line else log.info)("bounds%s: %s", stood, line)
        for line in preds[-1].envelope_notes():
            (log.warning if "OUTSIDE" in line else log.info)("envelope%s: %s", stood, line)
        if not args.quiet:
            log.info("predicted %d samples%s", preds[-1].t.size,
                     f" for {h:g} h stood" if h is not None else "")
    # the marks depend on the plan's speed and OCs alone, the same for every stated history: one line
    note = preds[0].reach_note()
    status = OUTSIDE_STATUS if note is not None else 0
    if note is not None:
        log.warning("%s; exit status %d", note, status)
    _write(args, preds, status, limits)
    return status


def _profile(args: argparse.Namespace, model: Model) -> tuple[Profile, Schedule | None]:
    """The planned profile: a schedule's plateaus (.toml) or a CSV (validated, one-line errors);
    and the schedule when it is one."""
    from node.training.prediction import schedule_profile
    from node.training.prediction_csv import read_profile

    if args.profile.endswith(".toml"):
        from node.contract.schedule import load_schedule
        if not (math.isfinite(args.plateau_s) and args.plateau_s > 0):
            raise OrdervibError(f"--plateau-s must be > 0, got {args.plateau_s:g}")
        sched = load_schedule(args.profile)
        if sched.switch != model.schedule.switch:
            raise OrdervibError(f"the schedule's switch {sched.switch!r} is not the model's "
                                f"{model.schedule.switch!r}")
        return schedule_profile(sched, args.plateau_s), sched
    return read_profile(args.profile, model.schedule.switch), None


def _limit_table(out: Results, preds: list[Prediction], limits: tuple[Limit, ...]) -> None:
    """Per stated history, OC and target: the predicted peak with its interval, the limit, p_exceed."""
    from node.training.prediction_limits import LIMIT_RULE, limits_along, segment_risks

    def f(x: float, fmt: str = ".3f") -> str:
        return format(x, fmt) if math.isfinite(x) else "-"

    several = len(preds) > 1
    rows = []
    for p in preds:
        for r in segment_risks(p, limits_along(p, limits)):
            rows.append([*([p.label] if several else []), r.oc, r.target, f(r.peak), f(r.lo), f(r.hi),
                         f(r.limit, "g"), f(r.p_exceed)])
    header = [*(["history h"] if several else []), "OC", "target", "peak", "peak_lo", "peak_hi", "limit",
              "p_exceed"]
    out.table("limits", header, rows)
    out.line(f"({LIMIT_RULE})", "limit_rule", LIMIT_RULE)


def _engine(args: argparse.Namespace) -> EngineState | None:
    """The history --engine-state states (its one bed, or --bed), None without the option."""
    if args.engine_state is None:
        if args.bed is not None:
            raise OrdervibError("--bed names a bed of --engine-state: give the file too")
        return None
    from node.edges.engine_file import load_given_engine_states
    states = load_given_engine_states(args.engine_state)
    if args.bed is not None:
        if args.bed not in states:
            raise OrdervibError(f"--engine-state {args.engine_state} has no bed {args.bed!r} "
                                f"(has {', '.join(sorted(states)) or 'none'})")
        return states[args.bed]
    if len(states) != 1:
        raise OrdervibError(f"--engine-state {args.engine_state} holds {len(states)} beds "
                            f"({', '.join(sorted(states)) or 'none'}): name one with --bed")
    return next(iter(states.values()))


def _write(args: argparse.Namespace, preds: list[Prediction], status: int, limits: tuple[Limit, ...]) -> None:
    """The CSV, the plots, and the result on stdout: the per-OC table (with limits, the per-OC
    table of each target's peak and p_exceed) and the files written (--json: with the rows
    marked outside, per mark, and the exit ``status``)."""
    import numpy as np

    from node.training.prediction_csv import write_csv
    from node.training.prediction_reach import MARK_WORDS

    with replacing(args.out) as tmp:
        with open(tmp, "w", newline="") as f:
            rows = write_csv(preds, f, limits)
    several = len(preds) > 1
    header = ["OC", "samples"] + [f"{tg} {p.label} h" if several else f"mean {tg}"
                                  for p in preds for tg in p.targets]
    table: dict[str, list[str]] = {}
    for p in preds:
        for name, n, means in p.per_oc():
            cells = table.setdefault(name, [name, str(n)])
            cells.extend(f"{v:.3f}" if np.isfinite(v) else "-" for v in means)
    out = Results(args.json)
    out.table("ocs", header, list(table.values()))
    if limits:
        _limit_table(out, preds, limits)
    out.line(f"prediction written to {args.out} ({rows} rows)", "out", args.out)
    marks = np.concatenate([p.marks for p in preds])
    out.value("rows", rows)
    out.value("outside", {"rows": int(np.count_nonzero(marks)), "note": preds[0].reach_note(),
                          **{w: int(np.sum(marks == m)) for m, w in MARK_WORDS.items() if w}})
    out.value("exit_status", status)
    plots = []
    if args.png or args.history_png:
        from replay.views.phase_plots import save_png
        from replay.views.prediction_plots import fig_history, fig_prediction
        for path, fig in ((args.png, fig_prediction), (args.history_png, fig_history)):
            if path:
                with replacing(path) as tmp:
                    save_png(fig(preds), tmp)
                plots.append(path)
                out.line(f"plot written to {path}", "plots", plots)
    out.done()
