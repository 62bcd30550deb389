"""``ordervib train``: learn the switching model of every OC from recordings."""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import os
import time
from pathlib import Path
from typing import TYPE_CHECKING, TextIO

import numpy as np

from node.cli.logs import duration_text
from node.cli.outputs import check_output_dir, replacing_dir, warn_unfinished
from node.cli.table import print_table
from node.contract.errors import OrdervibError

if TYPE_CHECKING:
    from node.contract.schedule import Schedule
    from node.mcap import Run
    from node.models.bundle import Model
    from node.training.train import OCResult

log = logging.getLogger(__name__)

NAME = "train"
HELP = "train the per-OC switching model from pass-off recordings"


def add_arguments(p: argparse.ArgumentParser) -> None:
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
    p.add_argument("--target", default=None, metavar="LIST",
                   help="modelled channel(s), comma-separated: several targets in one model "
                        "(default: every tracked order, yA, yB, yC, that all the recordings hold)")
    p.add_argument("--method", default="wdmd", choices=["wdmd", "delay-dmd", "lasso", "prom"],
                   help="per-OC model (default wdmd); prom: the parametric models alone (with the "
                        "curves unless --no-curve-candidates)")
    p.add_argument("--estimator", default=None, choices=["ls", "oe", "pem"],
                   help="state-space estimator (default oe; pem also refines the poles, slower)")
    p.add_argument("--rcond-grid", default=None, metavar="LIST",
                   help="rcond candidates for the cross-validation, comma-separated "
                        "(default 1e-8: CV never preferred a larger one on the simulated engine, "
                        "and each candidate costs training time)")
    p.add_argument("--inputs", default="auto", metavar="LIST|auto",
                   help="input channels, comma-separated, or auto: MS-DPCCA top-k per OC (default)")
    p.add_argument("--n-inputs", type=int, default=4, metavar="K", help="k for --inputs auto (default 4)")
    p.add_argument("--false-alarms-per-hour", type=float, default=None, metavar="R",
                   help="false-alarm budget on normal runs, per hour of running (default 0.5), "
                        "shared by the residual rule (thresholds from every OC's cross-validation "
                        "peaks) and the step rule (from the training runs' steady plateaus)")
    p.add_argument("--cv-undercoverage", type=float, default=None, metavar="F",
                   help="how many times more often new runs exceed a cross-validated residual level "
                        "than the CV runs do (default 4, measured with 8 training runs; "
                        "1 trusts the cross-validation as it is)")
    p.add_argument("--curve-candidates", dest="curves", action=argparse.BooleanOptionalAction,
                   default=True,
                   help="each OC's characteristic curves compete in the cross-validation: the fleet "
                        "curve (rising, falling and steady speed apart, or not), run_curve, and the "
                        "curve anchored to the run's level before the switch; a grid model must beat "
                        "the best curve's CV error by the curve margin (default: on)")
    p.add_argument("--history", action=argparse.BooleanOptionalAction, default=False,
                   help="the engine-history inputs (hist_energy, hist_rate, hist_shutdown, "
                        "hist_thermal; appendix A.2.5) are candidates like any channel; the "
                        "recordings are then one engine's, in time order (default: off)")
    p.add_argument("--prom", action=argparse.BooleanOptionalAction, default=True,
                   help="parametric models compete in each OC's cross-validation: a WDMD per "
                        "training run interpolated in pole-residue form to the run's engine-history "
                        "value at the switch (dissertation section 6.4); the recordings are then one "
                        "engine's, in time order (default: on)")
    p.add_argument("--phase", action=argparse.BooleanOptionalAction, default=True,
                   help="use the orders' phase channels (yA_ph..yC_ph) where every recording has the "
                        "target's: the vector rule watches the 1x vector; --no-phase: an amplitude-only "
                        "model whatever the recordings hold (default: use them)")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="parallel processes (default: up to 2)")
    p.add_argument("--allow-empty", action="store_true",
                   help="write the model even when no OC could be trained (such a node flags "
                        "every sample no-model); without it that is an error")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")


def load_runs(paths: list[str], quiet: bool = False) -> list[Run]:
    """Runs of every recording, in order; one status line per file unless quiet."""
    from node.mcap import ReadStats, read_runs
    runs: list[Run] = []
    for path in paths:
        stats = ReadStats()
        found = read_runs(path, stats=stats)
        if stats.truncated:
            warn_unfinished(log, path, f"{stats.messages} messages, {len(found)} run(s)")
        if not quiet:
            extra = f", {stats.malformed} malformed payloads skipped" if stats.malformed else ""
            log.info("read %s: %d run(s)%s", path, len(found), extra)
        runs += found
    if not runs:
        raise OrdervibError("the recordings hold no pass-off run")
    return runs


def resolve_targets(spec: str | None, runs: list[Run]) -> list[str]:
    """The targets of ``--target`` (a comma list), each held by every run; default: every tracked
    order (``ORDER_CHANNELS``) all the runs hold, else those some run holds."""
    from node.contract import ORDER_CHANNELS
    if spec is None:
        targets = [c for c in ORDER_CHANNELS if all(c in r.channels for r in runs)]
        targets = targets or [c for c in ORDER_CHANNELS if any(c in r.channels for r in runs)]
        if not targets:
            raise OrdervibError(f"the recordings hold no tracked order ({', '.join(ORDER_CHANNELS)}): "
                                "name the modelled channel with --target")
        return targets
    targets = [c.strip() for c in spec.split(",") if c.strip()]
    if not targets:
        raise OrdervibError(f"--target names no channel: {spec!r}")
    repeated = sorted({c for c in targets if targets.count(c) > 1})
    if repeated:
        raise OrdervibError(f"--target repeats {', '.join(repeated)}")
    for c in targets:
        if not all(c in r.channels for r in runs):
            held = sum(c in r.channels for r in runs)
            raise OrdervibError(f"--target {c}: the channel is missing from {len(runs) - held} of "
                                f"{len(runs)} run(s) of the recordings")
    return targets


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


# The options that make the model (stored with the kept runs: ``--update`` trains with them).
MODEL_OPTIONS = ("target", "method", "estimator", "rcond_grid", "inputs", "n_inputs",
                 "false_alarms_per_hour", "cv_undercoverage", "curves", "history", "prom", "phase")


def run(args: argparse.Namespace) -> int:
    from node.contract.schedule import load_schedule
    from node.models.bundle import MANIFEST, load_model, save_model, sha256_file
    from node.training.kept_runs import load_kept_runs, save_kept_runs

    if args.workers is not None and args.workers < 1:
        raise OrdervibError("--workers must be at least 1")
    t0 = time.perf_counter()
    if args.update is None:
        if args.schedule is None:
            raise OrdervibError("--schedule is required (the pass-off schedule, TOML)")
        check_output_dir(args.out, "--out", inputs=[*args.recordings, args.schedule])
        options = {k: getattr(args, k) for k in MODEL_OPTIONS}
        _check_options(options)
        schedule = load_schedule(args.schedule)
        old_runs: list[Run] = []
        old_recordings: list[dict] = []
    else:
        given = [k for k in ("schedule", *MODEL_OPTIONS) if getattr(args, k) != _DEFAULTS[k]]
        if given:
            raise OrdervibError(f"--update trains with the model's own schedule and options: "
                                f"{', '.join('--' + k.replace('_', '-') for k in given)} cannot be given")
        check_output_dir(args.out, "--out",
                         inputs=[*args.recordings, os.path.join(args.update, MANIFEST)])
        schedule = load_model(args.update).schedule
        old_runs, options, old_recordings = load_kept_runs(args.update)
        _check_options(options)
        log.info("model %s: %d kept run(s) of %d recording(s)", args.update, len(old_runs),
                 len(old_recordings))
    recordings = old_recordings + [{"path": p, "sha256": sha256_file(p)} for p in args.recordings]
    runs = old_runs + load_runs(args.recordings, args.quiet)
    model, trained = _train_model(runs, schedule, options, args.workers, args.allow_empty)
    model = dataclasses.replace(model, bundles=tuple(
        dataclasses.replace(b, training={"recordings": recordings, "runs": len(runs),
                                         "seconds": round(time.perf_counter() - t0, 1)})
        for b in model.bundles))
    with replacing_dir(args.out) as tmp:  # an existing model is replaced only by a complete one
        save_model(model, tmp)
        if args.keep_runs:
            save_kept_runs(runs, tmp, options, recordings)
    for target, results in trained:
        if len(trained) > 1:
            print(f"target {target}:")
        if options["inputs"] is None:
            print_ranking(results)
        print_results(results)
        if len(trained) > 1:
            print()
    print(f"model written to {Path(args.out)} ({time.perf_counter() - t0:.1f} s)")
    return 0


def _defaults() -> dict:
    p = argparse.ArgumentParser()
    add_arguments(p)
    return {a.dest: a.default for a in p._actions}


def _check_options(o: dict) -> None:
    """The model options' values, checked before anything is read (one-line errors)."""
    from node.training.train import Method

    if o["n_inputs"] < 1:
        raise OrdervibError("--n-inputs must be at least 1")
    if o["false_alarms_per_hour"] is not None and not o["false_alarms_per_hour"] > 0:
        raise OrdervibError("--false-alarms-per-hour must be positive")
    under = o["cv_undercoverage"]
    if under is not None and not (under >= 1.0 and math.isfinite(under)):
        raise OrdervibError("--cv-undercoverage must be a number >= 1")
    if o["rcond_grid"]:
        rconds = _rconds(o["rcond_grid"])
        if not all(0 < x < 1 for x in rconds):
            raise OrdervibError("--rcond-grid values must lie in (0, 1)")
    try:
        Method(o["method"])
    except ValueError:
        raise OrdervibError(f"unknown method {o['method']!r}") from None


def _rconds(spec: str) -> list[float]:
    try:
        return [float(x) for x in spec.split(",")]
    except ValueError:
        raise OrdervibError(f"--rcond-grid must be numbers separated by commas, got {spec!r}") from None


def _train_model(runs: list[Run], schedule: Schedule, o: dict, workers: int | None,
                 allow_empty: bool) -> tuple[Model, list[tuple[str, list[OCResult]]]]:
    """The model of ``runs`` with the model options ``o`` (``MODEL_OPTIONS``), and per target its
    OCs' results; training's provenance is left to the caller."""
    from node.models.bundle import Bundle, Model
    from node.models.config import RuntimeConfig
    from node.training.calibrate import CV_UNDERCOVERAGE, FALSE_ALARMS_PER_HOUR, calibrate_checks
    from node.training.train import (
        CURVE_CANDIDATES,
        DEFAULT_GRIDS,
        PROM_CANDIDATES,
        Method,
        fleet_curve,
        history_config,
        train,
    )

    t0 = time.perf_counter()
    budget = FALSE_ALARMS_PER_HOUR if o["false_alarms_per_hour"] is None else o["false_alarms_per_hour"]
    per_rule = budget / 2  # shared half and half by the residual and the step rules
    under = CV_UNDERCOVERAGE if o["cv_undercoverage"] is None else o["cv_undercoverage"]
    inputs = None if o["inputs"] in (None, "auto") else \
        [c.strip() for c in o["inputs"].split(",") if c.strip()]
    method = o["method"]
    grid = dict(DEFAULT_GRIDS[Method(method)])
    if method in ("wdmd", "delay-dmd"):
        grid["estimator"] = [o["estimator"]] if o["estimator"] else ["oe"]
        if o["rcond_grid"]:
            grid["rcond"] = _rconds(o["rcond_grid"])
    targets = resolve_targets(o["target"], runs)
    config = RuntimeConfig()
    if o["history"] or o["prom"] or method == "prom":  # (the engine history's cooling)
        config = history_config(runs, schedule, config)
        log.info("engine history: cooling %.3g rpm min per hour of shutdown%s", config.history_cooling,
                 "" if config.history_cooling != RuntimeConfig().history_cooling
                 else " (the text's value: too few runs after a known one to estimate it)")
    bundles: list[Bundle] = []
    trained: list[tuple[str, list[OCResult]]] = []
    use_prom = o["prom"] or method == "prom"
    n_models = (_count(grid) if grid else 0) + (len(PROM_CANDIDATES) if use_prom else 0)
    for target in targets:
        log.info("training %s for %s on %d run(s), %d OCs, leave-one-run-out CV over %d model candidates "
                 "per OC%s", method, target, len(runs), len(schedule.ocs), n_models,
                 f" and up to {len(CURVE_CANDIDATES)} curves" if o["curves"] else "")

        t_target = time.perf_counter()

        def progress(r: OCResult, done: int, total: int, t_target: float = t_target) -> None:
            """A line per OC trained (they finish out of order), with the rate and the time left."""
            cv = f"CV eps_td {r.cv_eps:.3f}" if r.model is not None else r.note
            spent = time.perf_counter() - t_target
            left = f", {duration_text(spent * (total - done) / done)} left" if done < total else ""
            log.info("  [%d/%d] %s: %s (%.0f s; %.1f OCs/min%s)", done, total, r.name, cv,
                     time.perf_counter() - t0, 60.0 * done / max(spent, 1e-9), left)

        curve = fleet_curve(runs, schedule.switch, target)
        results = train(runs, schedule, target=target, method=method, inputs=inputs,
                        n_inputs=o["n_inputs"], grid=grid, workers=workers, progress=progress,
                        false_alarms_per_hour=per_rule, cv_undercoverage=under,
                        fleet=curve, curves=o["curves"], config=config, history=o["history"],
                        phase=o["phase"], prom=use_prom)
        if not any(r.model is not None for r in results) and not allow_empty:
            notes = sorted({r.note for r in results if r.note})
            which = f"target {target}: " if len(targets) > 1 else ""
            raise OrdervibError(f"{which}no OC could be trained ({'; '.join(notes) or 'no segment'}): "
                                f"no model written (--allow-empty writes one that flags every sample "
                                f"no-model)")
        checks = calibrate_checks(runs, schedule, target, per_rule, use_phase=o["phase"])
        checks["residual_cv_undercoverage"] = under  # recorded: the residual thresholds assume it
        bundles.append(Bundle(method, target, schedule, results, config, {}, curve, checks))
        trained.append((target, results))
    return Model(tuple(bundles)), trained


def _count(grid: dict[str, list[object]]) -> int:
    n = 1
    for v in grid.values():
        n *= len(v)
    return n


_DEFAULTS = _defaults()
