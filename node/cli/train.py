"""``ordervib train``: learn the switching model of every OC from recordings."""

from __future__ import annotations

import argparse
import logging
import os
import time
from pathlib import Path
from typing import TYPE_CHECKING, TextIO

import numpy as np

from node.cli.outputs import check_output_dir, replacing_dir
from node.console.table import print_table
from node.contract.errors import OrdervibError
from node.training.fit import DEFAULT_OPTIONS

if TYPE_CHECKING:
    from node.training.train import OCResult

log = logging.getLogger(__name__)

NAME = "train"
HELP = "train the per-OC switching model from pass-off recordings"


def add_arguments(p: argparse.ArgumentParser) -> None:
    D = DEFAULT_OPTIONS
    p.add_argument("recordings", nargs="+", metavar="REC.mcap",
                   help="training recordings (with --update: the new ones)")
    p.add_argument("--schedule", metavar="S.toml", help="pass-off schedule (TOML; required unless --update)")
    p.add_argument("--out", required=True, metavar="MODEL", help="model bundle directory to write")
    p.add_argument("--update", metavar="MODEL",
                   help="add the recordings' runs to this model's: the model --out is the one training "
                        "on all of them would give, without reading the old recordings again (the "
                        "model keeps its runs and training options; those options cannot be given)")
    p.add_argument("--keep-runs", action=argparse.BooleanOptionalAction, default=True,
                   help="the model keeps its training runs (training-runs.npz, about a seventh of the "
                        "recordings' size) so that --update can add runs to it (default: keep)")
    p.add_argument("--target", default=D["target"], metavar="LIST",
                   help="modelled channel(s), comma-separated: several targets in one model "
                        "(default: every tracked order, yA, yB, yC, that all the recordings hold)")
    p.add_argument("--method", default=D["method"], choices=["wdmd", "delay-dmd", "lasso", "prom"],
                   help="per-OC model (default wdmd); prom: the parametric models alone (with the "
                        "curves unless --no-curve-candidates)")
    p.add_argument("--estimator", default=D["estimator"], choices=["ls", "oe", "pem"],
                   help="state-space estimator (default oe; pem also refines the poles, slower)")
    p.add_argument("--rcond-grid", default=D["rcond_grid"], metavar="LIST",
                   help="rcond candidates for the cross-validation, comma-separated "
                        "(default 1e-8: CV never preferred a larger one on the simulated engine, "
                        "and each candidate costs training time)")
    p.add_argument("--inputs", default=D["inputs"], metavar="LIST|auto",
                   help="input channels, comma-separated, or auto: MS-DPCCA top-k per OC (default)")
    p.add_argument("--n-inputs", type=int, default=D["n_inputs"], metavar="K",
                   help="k for --inputs auto (default 4)")
    p.add_argument("--false-alarms-per-hour", type=float, default=D["false_alarms_per_hour"], metavar="R",
                   help="false-alarm budget on normal runs, per hour of running (default 0.5), "
                        "shared by the residual rule (thresholds from every OC's cross-validation "
                        "peaks) and the step rule (from the training runs' steady plateaus)")
    p.add_argument("--cv-undercoverage", type=float, default=D["cv_undercoverage"], metavar="F",
                   help="how many times more often new runs exceed a cross-validated residual level "
                        "than the CV runs do (default 4, measured with 8 training runs; "
                        "1 trusts the cross-validation as it is)")
    p.add_argument("--curve-candidates", dest="curves", action=argparse.BooleanOptionalAction,
                   default=D["curves"],
                   help="each OC's characteristic curves compete in the cross-validation: the fleet "
                        "curve (rising, falling and steady speed apart, or not), run_curve, and the "
                        "curve anchored to the run's level before the switch; a grid model must beat "
                        "the best curve's CV error by the curve margin (default: on)")
    p.add_argument("--history", action=argparse.BooleanOptionalAction, default=D["history"],
                   help="the engine-history inputs (hist_energy, hist_rate, hist_shutdown, "
                        "hist_thermal; appendix A.2.5) are candidates like any channel; the "
                        "recordings are then one engine's, in time order (default: off)")
    p.add_argument("--prom", action=argparse.BooleanOptionalAction, default=D["prom"],
                   help="parametric models compete in each OC's cross-validation: a WDMD per "
                        "training run interpolated in pole-residue form to the run's engine-history "
                        "value at the switch (dissertation section 6.4); the recordings are then one "
                        "engine's, in time order (default: on)")
    p.add_argument("--phase", action=argparse.BooleanOptionalAction, default=D["phase"],
                   help="use the orders' phase channels (yA_ph..yC_ph) where every recording has the "
                        "target's: the vector rule watches the 1x vector; --no-phase: an amplitude-only "
                        "model whatever the recordings hold (default: use them)")
    p.add_argument("--fade", action=argparse.BooleanOptionalAction, default=D["fade"],
                   help="an anchored curve may learn that part of the run's deviation at the switch "
                        "fades (a rotor bowed by a hot shutdown straightens within minutes); "
                        "--no-fade: the anchor is held through the OC (default: learn it)")
    p.add_argument("--plateaus", action=argparse.BooleanOptionalAction, default=D["plateaus"],
                   help="each OC also learns what the run's earlier plateaus (at other speeds) add to its "
                        "model's plateau level, kept where its cross-validation says it helps; "
                        "--no-plateaus: the OC models as they are (default: learn it)")
    p.add_argument("--settle", action=argparse.BooleanOptionalAction, default=D["settle"],
                   help="each OC also learns how much of what its model missed as a visit settled (15 s "
                        "after the switch) stays for the rest of the visit, and moves its prediction by "
                        "it, kept where its cross-validation says it helps; --no-settle: the OC models as "
                        "they are (default: learn it)")
    p.add_argument("--chirp-rate", action=argparse.BooleanOptionalAction, default=D["chirp_rate"],
                   help="offer the switch speed's rate (rpm/s over the last second, derived by the node: "
                        "the chirp rate of section 3.3) to the cross-validation as a candidate input "
                        "(default: not offered)")
    p.add_argument("--tracker-s", type=float, default=D["tracker_s"], metavar="S",
                   help="the vibration unit's order-tracker lag in seconds (its tracking filter's time "
                        "constant, from its datasheet), undone in the transient analysis: on a ramp the "
                        "tracked peak trails the critical by the ramp rate times it (default: estimated from "
                        "the training runs' resonance crossings and kept in the bundle with how it was "
                        "found; 0: not undone)")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="parallel processes (default: up to 2)")
    p.add_argument("--allow-empty", action="store_true",
                   help="write the model even when no OC could be trained (such a node flags "
                        "every sample no-model); without it that is an error")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")


def _hyper_parameters(params: dict) -> str:
    """"k=v, ..."; an average: each member's, "name(k=v, ...) + ..." (a curve named by its variant).

    >>> _hyper_parameters({"levels": 3, "rcond": 1e-08})
    'levels=3, rcond=1e-08'
    >>> _hyper_parameters({"members": [{"params": {"variant": "run"}, "inputs": ["run_curve"]},
    ...     {"method": "wdmd", "params": {"levels": 2}, "inputs": ["nB"]}], "inputs": ["run_curve", "nB"]})
    'run() + wdmd(levels=2)'
    """
    if "members" in params:
        from node.models.average import member_name

        return " + ".join(f"{member_name(m)}("
                          f"{_hyper_parameters({k: v for k, v in m['params'].items() if k != 'variant'})})"
                          for m in params["members"])
    return ", ".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}" for k, v in params.items())


def print_results(results: list[OCResult], file: TextIO | None = None) -> None:
    """Per-OC table of the trained models, then the mean cross-validated eps_td.

    A "model" column names each OC's model kind when they differ (a characteristic curve won
    some OC's cross-validation).
    """
    header = ["OC", "inputs", "states", "hyper-parameters", "train eps_td", "CV eps_td", "sigma",
              "alarm at", "note"]
    rows = []
    for r in results:
        if r.model is None:
            rows.append([r.name, "-", "-", "-", "-", "-", "-", "-", r.note or "no model"])
            continue
        states = str(r.model.n_states)
        hp = _hyper_parameters(r.params)
        rows.append([r.name, ",".join(r.inputs), states, hp, f"{r.train_eps:.3f}", f"{r.cv_eps:.3f}",
                     f"{r.calibration.sigma:.3g}" if r.calibration else "-",
                     f"{r.calibration.threshold:.2f} sigma" if r.calibration else "-", r.note])
    kinds = [r.kind for r in results]
    if len({k for k in kinds if k != "-"}) > 1:
        header.insert(1, "model")
        for row, kind in zip(rows, kinds):
            row.insert(1, kind)
    print_table(header, rows, file=file)
    cv = [r.cv_eps for r in results if r.model is not None and np.isfinite(r.cv_eps)]
    if cv:
        print(f"mean cross-validated eps_td over {len(cv)} OCs: {np.mean(cv):.3f}", file=file)


def print_ranking(results: list[OCResult], top: int = 6, file: TextIO | None = None) -> None:
    """MS-DPCCA ranking per OC: mean |rho_DPCCA| of each candidate with the target."""
    print("MS-DPCCA ranking of the inputs per OC (mean |rho_DPCCA| with the target over scales):",
          file=file)
    for r in results:
        if r.ranking:
            ranks = ", ".join(f"{c} {s:.2f}" for c, s in r.ranking[:top])
            print(f"  {r.name:6s} {ranks}", file=file)
    print(file=file)


def run(args: argparse.Namespace) -> int:
    from node.contract.schedule import load_schedule
    from node.models.bundle import MANIFEST
    from node.training.fit import MODEL_OPTIONS, check_options, save_trained, train_recordings

    t0 = time.perf_counter()
    if args.update is None:
        if args.schedule is None:
            raise OrdervibError("--schedule is required (the pass-off schedule, TOML)")
        check_output_dir(args.out, "--out", inputs=[*args.recordings, args.schedule])
        given_options = {k: getattr(args, k) for k in MODEL_OPTIONS}
        check_options(given_options)
        options: dict | None = given_options
        schedule = load_schedule(args.schedule)
    else:
        given = [k for k in ("schedule", *MODEL_OPTIONS) if getattr(args, k) != _DEFAULTS[k]]
        if given:
            raise OrdervibError(f"--update trains with the model's own schedule and options: "
                                f"{', '.join('--' + k.replace('_', '-') for k in given)} cannot be given")
        check_output_dir(args.out, "--out",
                         inputs=[*args.recordings, os.path.join(args.update, MANIFEST)])
        options, schedule = None, None
    trained = train_recordings(args.recordings, schedule, options, args.update, args.workers,
                               args.allow_empty, args.quiet)
    with replacing_dir(args.out) as tmp:  # an existing model is replaced only by a complete one
        save_trained(trained, tmp, args.keep_runs)
    for target, results in trained.results:
        if len(trained.results) > 1:
            print(f"target {target}:")
        if trained.options["inputs"] is None:
            print_ranking(results)
        print_results(results)
        if len(trained.results) > 1:
            print()
    print(f"model written to {Path(args.out)} ({time.perf_counter() - t0:.1f} s)")
    return 0


_DEFAULTS = {"schedule": None, **DEFAULT_OPTIONS}
