"""Fault detection in replay: delay after onset per fault, false alarms per hour on normal runs.

    python -m bench faults [--seeds 11,12] [--train-runs 8] [--normal-runs 10] [--instances 3]
                           [--method wdmd] [--workdir DIR] [--faults drift,stiffness]
                           [--sizes 1,2,4] [--schedule S.toml] [--noise-scale X]

Per simulated engine (one per seed): the first ``--train-runs`` runs train the model (the CLI's
``ordervib train``, cross-validation on those runs only); the next ``--normal-runs``
are held out, fault-free, and replayed (``harness.make.replay``, the node's own code) to
count alarm episodes per hour. Then the first held-out run is simulated again with
each fault (imbalance, stiffness, stuck-sensor, drift), ``--instances`` times with
different onsets (``--fault-seed``), and the delay from onset to the first alarm
episode at or after it is measured; an episode the same run also raises without the
fault (a false alarm that happens to follow the onset) does not count. Targets: every fault flagged
within 60 s, at most 1 false alarm per hour. Per fault it also prints how many onsets any rule
found before the run ended (the coast-down's transient analysis included) and by which rules.

Beside each delay, how large the fault is as the node sees it (``harness.fault_effect``): the
largest change it makes to the target within 60 s (fault run minus the first held-out run,
which is the same run without the fault), and that change over the residual alarm band. A
fault whose effect stays below the band cannot be flagged by the residual rule in time; the
step and flatline rules see other signatures (a jump, a stuck value).

``--sizes`` repeats the fault runs with the fault scaled (``simulate --fault-size``, same
onsets), to find the smallest fault flagged within 60 s; ``--faults`` picks the kinds. Size 1
keeps the recording names ``{fault}-{i}.mcap``, other sizes are ``{fault}-{i}-x{size}.mcap``.
The false-alarm part does not depend on either.

``--schedule`` and ``--noise-scale`` go to every simulation (``simulate --schedule``,
``--noise-scale``): the engines run that schedule's OCs, with that sensor noise. Every
recording's truth JSON records both (and which runs it holds); a recording in the work dir
made with other ones is simulated again, and a model whose training data or code changed (its
stamp ``model-METHOD.trained-on.json`` names the sha256 of the training truth JSON and of the
``node`` package's sources) is trained again.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import shutil
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np

from harness import make
from harness.fault_effect import SMOOTH_S, FaultEffect, band_per_sample, fault_effect, on_common_samples
from node.contract import FS
from node.contract.errors import OrdervibError
from node.models.bundle import Bundle, load_bundle
from node.training.runs import Run, read_runs
from replay.offline import ReplayReport
from simulator.campaign import FAULTS
from simulator.schedule import BUILT_IN_SCHEDULE, SimSchedule, load_sim_schedule

DELAY_TARGET_S = 60.0
FALSE_ALARM_TARGET_PER_H = 1.0


class Setup:
    """What every simulation of a bench run shares: the schedule and the noise scale; whether the
    model uses the order phases the recordings always hold (``train --no-phase`` when not)."""

    def __init__(self, schedule: SimSchedule = BUILT_IN_SCHEDULE, noise_scale: float = 1.0,
                 phase: bool = True, guard: bool = True, plateaus: bool | None = None,
                 settle: bool | None = None) -> None:
        self.schedule = schedule
        self.noise_scale = float(noise_scale)
        self.phase = phase
        self.guard = guard  # False: the replays run the model with its curve guard off
        self.plateaus = plateaus  # train --plateaus / --no-plateaus (None: the product's default)
        self.settle = settle  # train --settle / --no-settle (None: the product's default)

    def model_name(self, method: str) -> str:
        """The model's folder in an engine's work dir (with and without phase side by side)."""
        plateaus = {None: "", True: "-plateaus", False: "-noplateaus"}[self.plateaus]
        settle = {None: "", True: "-settle", False: "-nosettle"}[self.settle]
        return f"model-{method}" + ("" if self.phase else "-nophase") + plateaus + settle

    def settings(self) -> dict:
        """The simulator settings (``simulator.files.Simulation``) of this setup."""
        return {"schedule": None if self.schedule.built_in else self.schedule.source,
                "noise_scale": self.noise_scale}

    def matches(self, truth: dict | None, first: int, count: int) -> bool:
        """Whether a recording's truth JSON is this setup's, with runs first .. first + count - 1.

        Truth files from before --schedule / --noise-scale carry neither: built-in and 1; those
        from before the phase channels carry no ``phase``: simulated again.
        """
        if truth is None or truth.get("phase") is None:
            return False
        digest = truth.get("schedule", {}).get("sha256", BUILT_IN_SCHEDULE.digest())
        return (digest == self.schedule.digest()
                and truth.get("noise_scale", 1.0) == self.noise_scale
                and [r.get("index") for r in truth.get("runs", [])] == list(range(first, first + count)))


def _code_hash() -> str:
    """sha256 of the node package's sources: a model trained by other code is trained again."""
    h = hashlib.sha256()
    root = Path(__file__).resolve().parents[1] / "node"
    for f in sorted(root.rglob("*.py")):
        h.update(f.relative_to(root).as_posix().encode() + b"\0" + f.read_bytes())
    return h.hexdigest()


def _truth(rec: Path) -> dict | None:
    """The truth JSON beside a recording, None if either is missing."""
    path = rec.with_suffix(".truth.json")
    return json.loads(path.read_text()) if rec.exists() and path.exists() else None


def _simulate(out: Path, runs: int, seed: int, skip: int, fault: str | None = None,
              fault_seed: int | None = None, size: float = 1.0, setup: Setup | None = None) -> dict:
    faulty = {"fault": fault, "fault_seed": fault_seed,
              "fault_size": size if size != 1.0 else None} if fault else {}
    return make.simulate(out, runs=runs, seed=seed, skip=skip, **(setup or Setup()).settings(), **faulty)


def _fault_name(fault: str, i: int, size: float) -> str:
    return f"{fault}-{i}.mcap" if size == 1.0 else f"{fault}-{i}-x{size:g}.mcap"


def _fault_row(work: Path, seed: int, n: int, model: Path, s: ReplayReport, fault: str, i: int,
               size: float, bundle: Bundle, twin: Run, setup: Setup) -> tuple:
    """One fault recording (simulated unless present), replayed; its row of the table.

    twin: the first normal held-out run, which is this run without the fault.
    """
    rec = work / _fault_name(fault, i, size)
    truth = _truth(rec)
    # recordings made before --fault-size carry no size: they are size 1
    if (not setup.matches(truth, n, 1) or "fault" not in truth["runs"][-1]
            or truth["runs"][-1]["fault"].get("size", 1.0) != size):
        truth = _simulate(rec, n + 1, seed, n, fault, i, size, setup)
    f = truth["runs"][-1]["fault"]
    eps = make.replay(rec, model).alarm_episodes
    # an alarm the same run raises by the same rule without the fault is not a detection
    eps = [e for e in eps if not any(n["start"] - 1.0 <= e["end"] and e["start"] <= n["end"] + 1.0
                                     and n["reason"] == e["reason"] for n in s.alarm_episodes)]
    after = [e for e in eps if e["end"] >= f["onset"]]
    before = [e for e in eps if e["end"] < f["onset"]]
    first = after[0] if after else None
    delay = max(0.0, first["start"] - f["onset"]) if first else float("inf")
    cols = [bundle.schedule.switch, bundle.target]
    run, twin = on_common_samples(read_runs(rec, cols)[-1], twin)
    try:
        effect = fault_effect(run, twin, bundle.target, f["onset"],
                              band_per_sample(run, bundle, bundle.schedule), DELAY_TARGET_S)
    except ValueError as e:
        print(f"[engine {seed}] {rec.name}: no fault effect measured: {e}", flush=True)
        effect = FaultEffect(math.nan, math.nan)
    return (seed, fault, size, i, f["oc"], f["onset_s"], delay, first["reason"] if first else "-",
            len(before), effect)


def engine_rows(work: Path, seed: int, n: int, m: int, instances: int, method: str, t0: float,
                faults: tuple[str, ...] = FAULTS, sizes: tuple[float, ...] = (1.0,),
                setup: Setup | None = None) -> tuple[list[tuple], float, list[dict]]:
    """One engine: simulate, train, replay; returns (fault rows, hours of normal data, false episodes).

    Recordings and the model already in ``work`` are reused only if they match ``setup`` and
    the run counts (see ``Setup.matches`` and the model's stamp).
    """
    setup = setup or Setup()
    work.mkdir(parents=True, exist_ok=True)
    train, normal, model = work / "train.mcap", work / "normal.mcap", work / setup.model_name(method)
    stamp = model.with_name(model.name + ".trained-on.json")
    if not setup.matches(_truth(train), 0, n):
        print(f"[engine {seed}] simulating {n} training runs ...", flush=True)
        stamp.unlink(missing_ok=True)  # the model, if any, was trained on other data
        _simulate(train, n, seed, 0, setup=setup)
    if not setup.matches(_truth(normal), n, m):
        print(f"[engine {seed}] simulating {m} held-out normal runs ...", flush=True)
        _simulate(normal, n + m, seed, n, setup=setup)
    truth_sha = hashlib.sha256(train.with_suffix(".truth.json").read_bytes()).hexdigest()
    trained_on = {"train_truth_sha256": truth_sha, "code_sha256": _code_hash()}
    old = json.loads(stamp.read_text()) if stamp.exists() else None
    if not (model / "manifest.json").exists() or old != trained_on:
        print(f"[engine {seed}] training {method} on the training runs ...", flush=True)
        stamp.unlink(missing_ok=True)
        extra = {k: v for k, v in (("plateaus", setup.plateaus), ("settle", setup.settle)) if v is not None}
        make.train([train], work / "train.schedule.toml", model, method=method, target="yB",
                   phase=setup.phase, **extra)
        stamp.write_text(json.dumps(trained_on) + "\n")
    if not setup.guard:
        model = _unguarded_copy(model)
    s = make.replay(normal, model)
    hours = sum(b["samples"] for b in s.beds.values()) / FS / 3600.0
    bundle = load_bundle(model)
    twin = read_runs(normal, [bundle.schedule.switch, bundle.target])[0]
    rows = []
    for fault in faults:
        for size in _sizes_of(fault, sizes):
            for i in range(1, instances + 1):
                rows.append(_fault_row(work, seed, n, model, s, fault, i, size, bundle, twin, setup))
            print(f"[engine {seed}] {fault} x{size:g}: done ({time.perf_counter() - t0:.0f} s)",
                  flush=True)
    return rows, hours, s.alarm_episodes


def _unguarded_copy(model: Path) -> Path:
    """A copy of the model folder beside it (``-unguarded``) with the curve guard off
    (``runtime.guard_wait_s`` 0; ``node.runtime.guard``), made afresh each time."""
    out = model.with_name(model.name + "-unguarded")
    shutil.rmtree(out, ignore_errors=True)
    shutil.copytree(model, out)
    manifest = json.loads((out / "manifest.json").read_text())
    manifest["runtime"]["guard_wait_s"] = 0.0
    (out / "manifest.json").write_text(json.dumps(manifest))
    return out


def _sizes_of(fault: str, sizes: tuple[float, ...]) -> tuple[float, ...]:
    """The sizes a fault kind is run at: a stuck sensor has no size, so once."""
    return (1.0,) if fault == "stuck-sensor" else sizes


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench faults")
    ap.add_argument("--seeds", default="11,12", help="engine seeds, comma-separated (default 11,12)")
    ap.add_argument("--train-runs", type=int, default=8)
    ap.add_argument("--normal-runs", type=int, default=10)
    ap.add_argument("--instances", type=int, default=3, help="onsets per fault kind (default 3)")
    ap.add_argument("--method", default="wdmd", choices=["wdmd", "delay-dmd", "lasso"])
    ap.add_argument("--workdir", default=None, help="keep recordings and models here (reused if present)")
    ap.add_argument("--faults", default=",".join(FAULTS),
                    help=f"fault kinds, comma-separated (default all: {','.join(FAULTS)})")
    ap.add_argument("--sizes", default="1",
                    help="fault sizes (simulate --fault-size), comma-separated (default 1)")
    ap.add_argument("--schedule", default=None, metavar="S.toml",
                    help="simulate this schedule's OCs (simulate --schedule; default the built-in 12)")
    ap.add_argument("--noise-scale", type=float, default=1.0, metavar="X",
                    help="scale every sensor's noise (simulate --noise-scale; default 1)")
    ap.add_argument("--no-phase", dest="phase", action="store_false",
                    help="the model ignores the order phases (train --no-phase; same recordings, "
                         "its own model folder model-METHOD-nophase)")
    ap.add_argument("--guard", choices=["on", "off"], default="on",
                    help="replay with the curve guard on (the product's) or off (node.runtime.guard)")
    ap.add_argument("--plateaus", action=argparse.BooleanOptionalAction, default=None,
                    help="train with or without the plateau shift (train --plateaus; its own model "
                         "folder; default: the product's default)")
    ap.add_argument("--settle", action=argparse.BooleanOptionalAction, default=None,
                    help="train with or without the settle anchor (train --settle; its own model folder; "
                         "default: the product's default)")
    args = ap.parse_args(argv)
    if not (math.isfinite(args.noise_scale) and args.noise_scale > 0):
        ap.error(f"--noise-scale must be > 0 and finite, got {args.noise_scale!r}")
    try:
        setup = Setup(BUILT_IN_SCHEDULE if args.schedule is None else load_sim_schedule(args.schedule),
                      args.noise_scale, args.phase, args.guard == "on", args.plateaus, args.settle)
    except OrdervibError as e:
        ap.error(f"--schedule: {e}")
    faults = tuple(x.strip() for x in args.faults.split(",") if x.strip())
    if not faults or any(f not in FAULTS for f in faults) or len(set(faults)) != len(faults):
        ap.error(f"--faults must be distinct names among {','.join(FAULTS)}, got {args.faults!r}")
    try:
        sizes = tuple(float(x) for x in args.sizes.split(",") if x.strip())
    except ValueError:
        sizes = ()
    if not sizes or not all(math.isfinite(x) and x > 0 for x in sizes) or len(set(sizes)) != len(sizes):
        ap.error(f"--sizes must be distinct numbers > 0, comma-separated, got {args.sizes!r}")
    work = Path(args.workdir or tempfile.mkdtemp(prefix="ordervib-faults-"))
    seeds = [int(x) for x in args.seeds.split(",") if x.strip()]
    t0 = time.perf_counter()
    rows, hours, false = [], 0.0, []
    for seed in seeds:
        r, h, f = engine_rows(work / f"engine{seed}", seed, args.train_runs, args.normal_runs,
                              args.instances, args.method, t0, faults, sizes, setup)
        rows += r
        hours += h
        false += f
    rate = len(false) / hours

    print()
    print(f"engines {seeds}: {args.method} trained on each engine's first {args.train_runs} runs; "
          f"work dir {work}")
    print(f"schedule {setup.schedule.source} ({len(setup.schedule.ocs)} OCs: "
          f"{', '.join(f'{o.name} {o.speed:g}' for o in setup.schedule.ocs)} rpm); "
          f"noise scale {setup.noise_scale:g}; "
          f"order phases {'used' if setup.phase else 'ignored (--no-phase)'}; "
          f"curve guard {'on' if setup.guard else 'off'}")
    print()
    w = f"{DELAY_TARGET_S:.0f} s"
    print("| engine | fault | size | instance | onset OC | onset s into run | first alarm after onset, s "
          f"| rule | alarms before onset | largest effect in {w}, mm/s | effect / band | within {w} |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for seed, fault, size, i, oc, onset_s, delay, reason, before, eff in rows:
        ok = "PASS" if delay <= DELAY_TARGET_S else "FAIL"
        shown = f"{delay:.1f}" if delay != float("inf") else "never"
        print(f"| {seed} | {fault} | {size:g} | {i} | {oc} | {onset_s:.0f} | {shown} | {reason} | {before} "
              f"| {eff.peak:.2f} | {eff.ratio:.2f} | {ok} |")
    print()
    print(f"effect / band: the fault's {SMOOTH_S:g} s mean effect on the target (fault run minus the same "
          f"run without it) over the residual alarm band; below 1 the fault moves the target by less "
          f"than the model's error allowance on a normal run")
    for fault in faults:
        for size in _sizes_of(fault, sizes):
            mine = [r for r in rows if r[1] == fault and r[2] == size]
            hit = sum(1 for r in mine if r[6] <= DELAY_TARGET_S)
            big = sum(1 for r in mine if r[9].ratio >= 1.0)
            ratios = [r[9].ratio for r in mine if r[9].ratio == r[9].ratio]
            med = f"{float(np.median(ratios)):.2f}" if ratios else "n/a"
            found = [r for r in mine if r[6] != float("inf")]
            rules = dict(Counter(str(r[7]) for r in found))
            print(f"{fault} size {size:g}: flagged within {w} in {hit}/{len(mine)}; found before the run "
                  f"ends (the coast-down included) in {len(found)}/{len(mine)} {rules or ''}; effect reaches "
                  f"the band in {big}/{len(mine)} (median effect / band {med})")
    reasons = dict(Counter(str(e["reason"]) for e in false))  # Reason values, as the contract writes them
    print(f"normal held-out runs: {len(seeds)} x {args.normal_runs} runs, {hours:.2f} h of data, "
          f"{len(false)} alarm episode(s) {reasons or ''} = {rate:.2f} per hour "
          f"(target <= {FALSE_ALARM_TARGET_PER_H:g}): "
          f"{'PASS' if rate <= FALSE_ALARM_TARGET_PER_H else 'FAIL'}")
    print(f"total {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
