"""Training from recordings, the one entry of ``ordervib train`` and of the benchmarks.

``train_recordings`` reads the recordings (each once: its runs and its sha256 from the same
mapping), adds them to a kept model's runs when updating, and trains the switching model of
every target with the model options (``MODEL_OPTIONS``, defaults ``DEFAULT_OPTIONS``, checked
by ``check_options``); ``save_trained`` writes it into a model folder. The command line
parses the options, checks its outputs, calls these and prints the tables.

>>> check_options({**DEFAULT_OPTIONS, "n_inputs": 0})
Traceback (most recent call last):
...
node.contract.errors.OrdervibError: --n-inputs must be at least 1
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
import time
from collections.abc import Sequence
from typing import Any

from node.console.durations import duration_text
from node.contract.errors import OrdervibError
from node.contract.schedule import Schedule
from node.mcap import ReadStats, warn_unfinished
from node.models.bundle import Bundle, Model, load_model, save_model
from node.models.config import RuntimeConfig
from node.models.result import OCResult
from node.models.transients import TRACKER_S_MAX, TransientSettings
from node.runtime.history import COOLING_GRID
from node.training.provenance import training_record
from node.training.runs import Run, read_runs

log = logging.getLogger(__name__)

# The options that make the model, with their defaults (``ordervib train``'s; stored with the
# kept runs: ``--update`` trains with them). Each is the ``--option`` of the same name, with
# "-" for "_" (``curves``: ``--curve-candidates``).
DEFAULT_OPTIONS: dict[str, Any] = {
    "target": None,  # comma list; None: every tracked order all the recordings hold
    "method": "wdmd",
    "estimator": None,  # None: oe
    "rcond_grid": None,  # comma list; None: the method's grid
    "inputs": "auto",  # comma list, or auto: MS-DPCCA top n_inputs per OC
    "n_inputs": 4,
    "false_alarms_per_hour": None,  # None: FALSE_ALARMS_PER_HOUR
    "cv_undercoverage": None,  # None: CV_UNDERCOVERAGE
    "curves": True,
    "history": False,
    "prom": True,
    "phase": True,
    "fade": True,
    "plateaus": True,  # each OC learns what the run's earlier plateaus add (node.models.plateau)
    "settle": True,  # each OC learns its re-anchor on the visit's settled level (node.models.settle)
    "chirp_rate": False,  # the switch speed's rate (``node.runtime.chirp``) among the candidate inputs
    "tracker_s": None,  # the vibration unit's order-tracker lag (s) the transient analysis undoes; 0: none;
    # None: estimated from the training runs' resonance crossings (node.runtime.tracker_lag)
}
MODEL_OPTIONS = tuple(DEFAULT_OPTIONS)


def check_options(o: dict) -> None:
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
    try:  # the bundle's own rule for the setting (TransientSettings)
        if o["tracker_s"] is not None:
            TransientSettings.from_dict({"tracker_s": o["tracker_s"]})
    except ValueError:
        raise OrdervibError(f"--tracker-s must be a number of seconds in [0, {TRACKER_S_MAX:g}], "
                            f"got {o['tracker_s']!r}") from None
    try:
        Method(o["method"])
    except ValueError:
        raise OrdervibError(f"unknown method {o['method']!r}") from None


def model_options(**given: Any) -> dict:
    """``DEFAULT_OPTIONS`` with ``given`` in their place, checked (``check_options``).

    >>> model_options(target="yB", phase=False)["phase"]
    False
    >>> model_options(color="red")
    Traceback (most recent call last):
    ...
    node.contract.errors.OrdervibError: unknown model option(s): color
    """
    unknown = sorted(set(given) - set(DEFAULT_OPTIONS))
    if unknown:
        raise OrdervibError(f"unknown model option(s): {', '.join(unknown)}")
    options = {**DEFAULT_OPTIONS, **given}
    check_options(options)
    return options


def _rconds(spec: str) -> list[float]:
    try:
        return [float(x) for x in spec.split(",")]
    except ValueError:
        raise OrdervibError(f"--rcond-grid must be numbers separated by commas, got {spec!r}") from None


def read_recordings(paths: Sequence[str], quiet: bool = False) -> tuple[list[Run], list[dict]]:
    """Runs of every recording, in order, and each recording's ``{"path", "sha256"}``: each file
    read once; one status line per file unless quiet."""
    runs, recordings, _ = read_sourced(paths, quiet)
    return runs, recordings


def read_sourced(paths: Sequence[str], quiet: bool = False) -> tuple[list[Run], list[dict], list[int]]:
    """``read_recordings``, and per run the index of its recording among ``paths`` (its
    sha256: ``recordings[i]["sha256"]``, for ``node.training.provenance``)."""
    runs: list[Run] = []
    recordings: list[dict] = []
    source: list[int] = []
    for path in paths:
        stats = ReadStats()
        found = read_runs(path, stats=stats, sha256=True)
        if stats.truncated:
            warn_unfinished(log, path, f"{stats.messages} messages, {len(found)} run(s)")
        if not quiet:
            extra = f", {stats.malformed} malformed payloads skipped" if stats.malformed else ""
            log.info("read %s: %d run(s)%s", path, len(found), extra)
        runs += found
        source += [len(recordings)] * len(found)
        recordings.append({"path": path, "sha256": stats.sha256})
    if not runs:
        raise OrdervibError("the recordings hold no pass-off run")
    return runs, recordings, source


def load_runs(paths: Sequence[str], quiet: bool = False) -> list[Run]:
    """Runs of every recording, in order (``read_recordings`` without the hashes)."""
    return read_recordings(paths, quiet)[0]


def resolve_targets(spec: str | None, runs: list[Run]) -> list[str]:
    """The targets of ``--target`` (a comma list), each held by every run; default: every tracked
    order (``ORDER_CHANNELS``) all the runs hold, else those some run holds."""
    from node.contract import ORDER_CHANNELS, RESERVED_NAMES
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
        if c in RESERVED_NAMES:
            raise OrdervibError(f"--target {c}: never a target's name (monitor/{c} is another topic)")
        if not all(c in r.channels for r in runs):
            held = sum(c in r.channels for r in runs)
            raise OrdervibError(f"--target {c}: the channel is missing from {len(runs) - held} of "
                                f"{len(runs)} run(s) of the recordings")
    return targets


@dataclasses.dataclass(frozen=True, eq=False)
class Trained:
    """What ``train_recordings`` gives: the model (with its provenance), per target its OCs'
    results, the runs it was trained on (old kept ones first), the recordings read (path,
    sha256) and the model options."""

    model: Model
    results: list[tuple[str, list[OCResult]]]
    runs: list[Run]
    recordings: list[dict]
    options: dict


def train_recordings(paths: Sequence[str], schedule: Schedule | None, options: dict | None = None,
                     update: str | None = None, workers: int | None = None, allow_empty: bool = False,
                     quiet: bool = False) -> Trained:
    """The model of the recordings ``paths`` (options: ``model_options``; default the defaults).

    update: a model folder that kept its runs: train on its runs and the recordings', with its
    schedule and options (``schedule`` and ``options`` must then be None).
    workers: parallel processes (None: up to 2).
    """
    from node.training.kept_runs import load_kept_runs

    if workers is not None and workers < 1:
        raise OrdervibError("--workers must be at least 1")
    t0 = time.perf_counter()
    old_runs: list[Run] = []
    old_recordings: list[dict] = []
    if update is None:
        if schedule is None:
            raise OrdervibError("--schedule is required (the pass-off schedule, TOML)")
        options = dict(DEFAULT_OPTIONS) if options is None else options
        check_options(options)
    else:
        if schedule is not None or options is not None:
            raise OrdervibError("an update trains with the model's own schedule and options")
        schedule = load_model(update).schedule
        old_runs, options, old_recordings = load_kept_runs(update)
        check_options(options)
        log.info("model %s: %d kept run(s) of %d recording(s)", update, len(old_runs),
                 len(old_recordings))
    new_runs, new_recordings = read_recordings(paths, quiet)
    runs, recordings = old_runs + new_runs, old_recordings + new_recordings
    model, trained = train_model(runs, schedule, options, workers, allow_empty)
    record = training_record(recordings, runs, time.perf_counter() - t0)  # spans: every run, kept first
    model = dataclasses.replace(model, bundles=tuple(
        dataclasses.replace(b, training=dict(record)) for b in model.bundles))
    return Trained(model, trained, runs, recordings, options)


def save_trained(trained: Trained, folder: str | os.PathLike, keep_runs: bool = True) -> None:
    """Write the model into the (new, empty) folder; with ``keep_runs`` also its training runs,
    options and recordings (``node.training.kept_runs``), so that an update can add runs."""
    from node.training.kept_runs import save_kept_runs

    save_model(trained.model, folder)
    if keep_runs:
        save_kept_runs(trained.runs, folder, trained.options, trained.recordings)


def train_model(runs: list[Run], schedule: Schedule, o: dict, workers: int | None,
                allow_empty: bool) -> tuple[Model, list[tuple[str, list[OCResult]]]]:
    """The model of ``runs`` with the model options ``o`` (``MODEL_OPTIONS``), and per target its
    OCs' results; training's provenance is left to the caller."""
    from node.runtime.chirp import add_chirp_rate
    from node.training.calibrate import CV_UNDERCOVERAGE, FALSE_ALARMS_PER_HOUR, calibrate_checks
    from node.training.dataset import label_runs
    from node.training.forecast import peak_table
    from node.training.train import (
        CURVE_CANDIDATES,
        DEFAULT_GRIDS,
        PROM_CANDIDATES,
        Method,
        fleet_curve,
        history_config,
        train,
    )
    from node.training.transients import fleet_transients, transient_settings

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
    schedule.check_targets(targets)
    config = RuntimeConfig()
    use_prom = o["prom"] or method == "prom"
    use_history = o["history"] or use_prom  # (the engine history's cooling)
    if use_history:
        config = history_config(runs, schedule, config)
    bundles: list[Bundle] = []
    trained: list[tuple[str, list[OCResult]]] = []
    if o["chirp_rate"]:  # a derived candidate input, as the node derives it (section 3.3)
        runs = [add_chirp_rate(r, schedule.switch) for r in runs]
    labels = label_runs(runs, schedule, models=True)  # once for every target: segments, run_curve, checks
    n_models = (_count(grid) if grid else 0) + (len(PROM_CANDIDATES) if use_prom else 0)
    lag = _tracker_lag(runs, schedule, targets, o["tracker_s"])
    for target in targets:
        log.info("training %s for %s on %d run(s), %d OCs and the rundown, leave-one-run-out CV over %d "
                 "model candidates "
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
                        phase=o["phase"], prom=use_prom, fade=o["fade"], labels=labels,
                        plateaus=o["plateaus"], settle=o["settle"])
        if not any(r.model is not None for r in results) and not allow_empty:
            notes = sorted({r.note for r in results if r.note})
            which = f"target {target}: " if len(targets) > 1 else ""
            raise OrdervibError(f"{which}no OC could be trained ({'; '.join(notes) or 'no segment'}): "
                                f"no model written (--allow-empty writes one that flags every sample "
                                f"no-model)")
        checks = calibrate_checks(runs, schedule, target, per_rule, use_phase=o["phase"], labels=labels)
        checks["residual_cv_undercoverage"] = under  # recorded: the residual thresholds assume it
        settings = dataclasses.replace(transient_settings(runs, schedule, target), **lag)
        transients = fleet_transients(runs, schedule, target, settings)
        # the training runs' peaks per segment, for the verdict's forecast (a limited target's)
        peaks = peak_table(runs, schedule, target, labels) if schedule.limits_of(target) else None
        bundles.append(Bundle(method, target, schedule, results, config, {}, curve, checks, transients,
                              peaks))
        trained.append((target, results))
    if use_history:  # said once the model stands (a failure: one line)
        log.log(*cooling_note(config.history_cooling))
    return Model(tuple(bundles)), trained


def _tracker_lag(runs: list[Run], schedule: Schedule, targets: list[str], given: float | None
                 ) -> dict[str, Any]:
    """The transient settings' tracker lag: ``given`` (``--tracker-s``), else estimated from the
    runs (``node.training.transients.tracker_lag``, pooled over the targets; 0 where no crossing
    pins it), logged with how it was found."""
    from node.training.transients import tracker_lag, transient_settings

    if given is not None:
        return {"tracker_s": float(given), "tracker_from": "given" if given > 0 else "none"}
    settings = {t: transient_settings(runs, schedule, t) for t in targets}
    est, fits = tracker_lag(runs, schedule, targets, settings)
    if est is None:
        log.warning("order tracker's lag: no resonance crossing of the training runs pins it (%d fitted): "
                    "not undone (--tracker-s gives it)", len(fits))
        return {"tracker_s": 0.0, "tracker_from": "none"}
    log.info("order tracker's lag: %.2f s (spread %.2f s) estimated from %d resonance crossing(s) "
             "(%d fitted)", est.tau, est.spread, est.crossings, est.fitted)
    return {"tracker_s": round(est.tau, 4), "tracker_from": "estimated",
            "tracker_spread": round(est.spread, 4), "tracker_crossings": est.crossings}


def cooling_note(cooling: float) -> tuple[int, str]:
    """The log level and line that tell the engine history's cooling rate (rpm min per hour of
    shutdown) and whether the training runs identified it.

    >>> cooling_note(2.5e4)
    (20, 'engine history: cooling 2.5e+04 rpm min per hour of shutdown')
    >>> cooling_note(100.0)[1].split(", ", 1)[1]
    'at the bound of the rates searched (100-1e+07): not identified by these runs'
    >>> cooling_note(RuntimeConfig().history_cooling)[0] == logging.WARNING
    True
    """
    line = f"engine history: cooling {cooling:.3g} rpm min per hour of shutdown"
    if cooling == RuntimeConfig().history_cooling:
        return logging.WARNING, f"{line}, the text's value: not identified (too few runs after a known one)"
    if cooling in COOLING_GRID:
        return logging.WARNING, (f"{line}, at the bound of the rates searched ({COOLING_GRID[0]:g}-"
                                 f"{COOLING_GRID[1]:g}): not identified by these runs")
    return logging.INFO, line


def _count(grid: dict[str, list[object]]) -> int:
    n = 1
    for v in grid.values():
        n *= len(v)
    return n
