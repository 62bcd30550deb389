"""``ordervib predict``: the expected order amplitudes for a planned speed profile and a stated
engine history (``node.training.prediction``; the toolbox's panel IV, appendix A.2.4-A.2.5)."""

from __future__ import annotations

import argparse
import logging
import math
import os
from typing import TYPE_CHECKING

from node.cli.outputs import check_output, replacing
from node.contract.errors import OrdervibError

if TYPE_CHECKING:
    from node.models.bundle import Model
    from node.runtime.history import EngineState
    from node.training.prediction import Prediction, Profile
    from node.training.prediction_aids import AmplitudeBound, InputFill, IntervalWidths
    from node.training.runs import Run

log = logging.getLogger(__name__)

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
                        "(.toml): its plateaus in order, each held --plateau-s")
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


def run(args: argparse.Namespace) -> int:
    from node.models.bundle import load_model
    from node.runtime.history import HISTORY_CHANNELS
    from node.runtime.ocdetect import OCDetector
    from node.training.prediction import predict_profile, stated_history, takes_history

    model = load_model(args.model)
    profile = _profile(args, model)
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
    training, source = _training_runs(args, model)
    fill = _fill(args, model, profile, training, source)
    bound, widths, levels = _limits(model, training, source)
    runs = profile.runs(OCDetector(model.schedule, model.config).off_level)
    start = _first_on(runs, model)
    preds = []
    for h in hours:
        state = stated_history(start, h, args.energy, engine)
        label = "" if h is None else f"{h:g}"
        preds.append(predict_profile(model, profile, state, fill, args.seed, label, bound, widths, levels))
        if not preds[-1].per_oc():
            log.warning("the node found no OC of the schedule in the profile: nothing is predicted "
                        "(does it hold each plateau for some seconds, within the schedule's tolerance?)")
        for line in preds[-1].bound_notes():
            stood = f" ({h:g} h stood)" if h is not None else ""
            (log.warning if "capped" in line else log.info)("bounds%s: %s", stood, line)
        for line in preds[-1].envelope_notes():
            stood = f" ({h:g} h stood)" if h is not None else ""
            (log.warning if "OUTSIDE" in line else log.info)("envelope%s: %s", stood, line)
        if not args.quiet:
            log.info("predicted %d samples%s", preds[-1].t.size,
                     f" for {h:g} h stood" if h is not None else "")
    _write(args, preds)
    return 0


def _profile(args: argparse.Namespace, model: Model) -> Profile:
    """The planned profile: a schedule's plateaus (.toml) or a CSV (validated, one-line errors)."""
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
        return schedule_profile(sched, args.plateau_s)
    return read_profile(args.profile, model.schedule.switch)


def _engine(args: argparse.Namespace) -> EngineState | None:
    """The history --engine-state states (its one bed, or --bed), None without the option."""
    if args.engine_state is None:
        if args.bed is not None:
            raise OrdervibError("--bed names a bed of --engine-state: give the file too")
        return None
    from node.live.engine_file import load_given_engine_states
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


def _training_runs(args: argparse.Namespace, model: Model) -> tuple[list[Run], str]:
    """The training runs that fill the channels a profile lacks and set the bound and the
    interval, and what they are: --train's recordings; else the runs the model keeps
    (``node.training.kept_runs``); else its training recordings, when they are where and as
    they were; else none (an empty list, and why)."""
    from node.training.fit import load_runs
    from node.training.kept_runs import RUNS_META, load_kept_runs

    if args.train:
        return load_runs(args.train, args.quiet), f"runs of {', '.join(args.train)}"
    if os.path.isfile(os.path.join(args.model, RUNS_META)):
        runs = load_kept_runs(args.model)[0]
        log.info("the model keeps %d training run(s)", len(runs))
        return runs, "training runs the model keeps"
    paths = _training_recordings(model)
    if paths:
        return load_runs(paths, args.quiet), f"training runs of {', '.join(paths)}"
    return [], "the model keeps no training runs and its training recordings are not at hand"


def _fill(args: argparse.Namespace, model: Model, profile: Profile, runs: list[Run],
          source: str) -> InputFill | None:
    """The InputFill of the channels the profile lacks, from the training ``runs``; None when
    the profile holds every channel the node needs."""
    from node.runtime.history import SLOW_TEMPERATURES
    from node.training.prediction import needed_channels
    from node.training.prediction_aids import InputFill

    need = needed_channels(model)
    lacking = [c for c in need if c not in profile.channels]
    if not lacking:
        return None
    if not runs:
        raise OrdervibError(f"the profile lacks {', '.join(lacking)}, which the model takes: add them as "
                            "columns, or give --train REC.mcap (recordings of this engine) to fill them from")
    want = sorted({*lacking, *(c for c in SLOW_TEMPERATURES if c not in profile.channels)})
    fill = InputFill.fit(runs, model.schedule, want, source)
    still = [c for c in lacking if c not in fill.channels]
    if still:
        raise OrdervibError(f"the profile lacks {', '.join(still)}, which the model takes, and the "
                            f"{source} do not hold it either")
    log.info("filled %s from %d %s, at the planned %s in each OC", ", ".join(lacking), len(runs), source,
             model.schedule.switch)
    return fill


def _limits(model: Model, runs: list[Run], source: str
            ) -> tuple[AmplitudeBound | None, IntervalWidths | None, InputFill | None]:
    """The upper bound, the interval's widths and the targets' mean amplitude per OC (for the
    1x-vector models' mean modulus) from the training ``runs`` (none: no bound above, the
    interval from the CV residuals alone, the fleet curve; said once)."""
    from node.training.prediction import fit_interval_widths
    from node.training.prediction_aids import AmplitudeBound, InputFill

    if not runs:
        log.warning("%s: the prediction is bounded at 0 only, not above, and its interval is the CV "
                    "residuals' alone (narrower than a plan's error); give --train REC.mcap", source)
        return None, None, None
    bound = AmplitudeBound.fit(runs, model.schedule, model.targets)
    levels = InputFill.fit(runs, model.schedule, model.targets, source)
    log.info("interval: the chained prediction of %d %s", len(runs), source)
    return bound, fit_interval_widths(model, runs, bound, levels=levels), levels


def _training_recordings(model: Model) -> list[str]:
    """The model's training recordings, if every one is still there with its sha256."""
    from node.models.bundle import sha256_file

    recs = model.bundles[0].training.get("recordings") or []
    paths = []
    for r in recs:
        path = r.get("path") if isinstance(r, dict) else None
        if not path or not os.path.isfile(path) or sha256_file(path) != r.get("sha256"):
            log.info("the model's training recording %s is not there as it was: not used", path)
            return []
        paths.append(path)
    return paths


def _first_on(runs: list[Run], model: Model) -> float:
    """The time the engine first runs in the profile (s): a stated shutdown ends there."""
    import numpy as np

    from node.runtime.ocdetect import OCDetector

    on = OCDetector(model.schedule, model.config).off_level
    speed = runs[0].column(model.schedule.switch)
    k = np.flatnonzero(speed >= on)
    return float(runs[0].t[int(k[0]) if k.size else 0])


def _write(args: argparse.Namespace, preds: list[Prediction]) -> None:
    """The CSV, the plots, and the per-OC table on stdout."""
    import numpy as np

    from node.console.table import print_table
    from node.training.prediction_csv import write_csv

    with replacing(args.out) as tmp:
        with open(tmp, "w", newline="") as f:
            rows = write_csv(preds, f)
    several = len(preds) > 1
    header = ["OC", "samples"] + [f"{tg} {p.label} h" if several else f"mean {tg}"
                                  for p in preds for tg in p.targets]
    table: dict[str, list[str]] = {}
    for p in preds:
        for name, n, means in p.per_oc():
            cells = table.setdefault(name, [name, str(n)])
            cells.extend(f"{v:.3f}" if np.isfinite(v) else "-" for v in means)
    print_table(header, list(table.values()))
    print(f"prediction written to {args.out} ({rows} rows)")
    if args.png or args.history_png:
        from replay.views.phase_plots import save_png
        from replay.views.prediction_plots import fig_history, fig_prediction
        for path, fig in ((args.png, fig_prediction), (args.history_png, fig_history)):
            if path:
                with replacing(path) as tmp:
                    save_png(fig(preds), tmp)
                print(f"plot written to {path}")
