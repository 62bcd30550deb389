"""Residual thresholds with few training runs: false alarms on normal held-out runs per rule.

    python -m bench thresholds [--seeds 41,42,43,44,45] [--runs 4,8] [--normal-runs 10]
        [--workdir W] [--rules plug-in:4,predictive:1,predictive:2,predictive:4] [--few-runs 6]
        [--plateaus | --no-plateaus] [--settle | --no-settle]

Per engine and training-run count: simulates the training and normal runs (reused from the
work dir when there), trains yB once with the defaults (``node.training.fit``), then for each
rule (``RULE:UNDERCOVERAGE``; ``node.training.calibrate.threshold_levels``) sets the residual
thresholds from that training's CV peaks and replays the normal runs through the node's own
code (``replay.offline.replay``). Prints, per rule and run count, the false alarms per hour on
normal held-out runs (all rules, and the residual rule alone) beside the budget (1 per hour).
``--few-runs 0,6`` trains each engine once per value of ``node.training.train.FEW_RUNS`` (0: a
free-running model may be chosen alone whatever the number of runs; the product's: 6).
``--plateaus`` / ``--no-plateaus`` trains with or without the plateau shift (``train --plateaus``),
``--settle`` / ``--no-settle`` with or without the settle anchor (``train --settle``).
``--guard on,off`` replays each training with the curve guard on (the bundle's setting) and off
(``node.runtime.guard``; ``guard_wait_s`` 0).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import node.training.train as train_module
from harness import make
from node.console.table import print_table
from node.contract import FS
from node.contract.schedule import load_schedule
from node.models.bundle import Bundle, Model
from node.training.calibrate import FALSE_ALARMS_PER_HOUR, threshold_levels
from node.training.fit import load_runs, model_options, train_model
from replay.offline import replay

TARGET = "yB"
BUDGET_PER_H = 1.0  # the target for all rules together


def _recordings(work: Path, seed: int, n: int, m: int) -> tuple[Path, Path]:
    train, normal = work / "train.mcap", work / "normal.mcap"
    for rec, runs, skip in ((train, n, 0), (normal, n + m, n)):
        truth = rec.with_suffix(".truth.json")
        if rec.exists() and truth.exists() and len(json.loads(truth.read_text())["runs"]) == runs - skip:
            continue
        make.simulate(rec, runs=runs, seed=seed, skip=skip)
    return train, normal


class _capture:
    """While training: the calibrations before their thresholds, and the CV's OC hours and
    segments (what ``set_thresholds`` is given), to set thresholds again by other rules."""

    def __init__(self) -> None:
        self.original = train_module.set_thresholds
        self.calibs: dict = {}
        self.hours, self.segments = 0.0, 0
        train_module.set_thresholds = self  # type: ignore[assignment]

    def __call__(self, out: list, datas: list, budget: float, under: float, rule: str | None = None) -> list:
        self.calibs = {r.name: r.calibration for r in out if r.calibration is not None}
        self.hours = sum(y.size - s for d in datas for y, s in zip(d.y, d.start)) / FS / 3600.0
        self.segments = sum(len(d.runs) for d in datas)
        return self.original(out, datas, budget, under, rule)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench thresholds")
    ap.add_argument("--seeds", default="41,42,43,44,45")
    ap.add_argument("--runs", default="4,8", help="training-run counts (default 4,8)")
    ap.add_argument("--normal-runs", type=int, default=10)
    ap.add_argument("--workdir", default=None)
    ap.add_argument("--rules", default="plug-in:4,predictive:1,predictive:2,predictive:4")
    ap.add_argument("--few-runs", default=str(train_module.FEW_RUNS),
                    help="values of FEW_RUNS to train with, each a training (default: the product's)")
    ap.add_argument("--guard", default="on", help="curve guard settings to replay with: on, off or on,off")
    ap.add_argument("--plateaus", action=argparse.BooleanOptionalAction, default=None,
                    help="train with or without the plateau shift (default: the product's default)")
    ap.add_argument("--settle", action=argparse.BooleanOptionalAction, default=None,
                    help="train with or without the settle anchor (default: the product's default)")
    args = ap.parse_args(argv)
    guards = args.guard.split(",")
    if not guards or any(g not in ("on", "off") for g in guards):
        ap.error(f"--guard takes on, off or both, got {args.guard!r}")
    few_values = [int(x) for x in args.few_runs.split(",")]
    rules = [(r.split(":")[0], float(r.split(":")[1])) for r in args.rules.split(",")]
    work = Path(args.workdir or tempfile.mkdtemp(prefix="ordervib-thresholds-"))
    t0 = time.perf_counter()
    # (rule, undercoverage, n, FEW_RUNS, guard) -> [hours, episodes, residual episodes]
    tally: dict[tuple[str, float, int, int, str], list[float]] = defaultdict(lambda: [0.0, 0, 0])
    per_engine = []
    for n in [int(x) for x in args.runs.split(",")]:
        for seed in [int(x) for x in args.seeds.split(",")]:
            d = work / f"engine{seed}-n{n}"
            d.mkdir(parents=True, exist_ok=True)
            train, normal = _recordings(d, seed, n, args.normal_runs)
            runs = load_runs([str(train)], quiet=True)
            schedule = load_schedule(str(train.with_suffix(".schedule.toml")))
            for few in few_values:
                train_module.FEW_RUNS = few
                seen = _capture()
                extra = {k: v for k, v in (("plateaus", args.plateaus), ("settle", args.settle))
                         if v is not None}
                model, _ = train_model(runs, schedule, model_options(target=TARGET, **extra), None, False)
                train_module.set_thresholds = seen.original
                for guard in guards:
                    bundle = model.bundles[0]
                    if guard == "off":
                        bundle = dataclasses.replace(
                            bundle, config=dataclasses.replace(bundle.config, guard_wait_s=0.0))
                    for rule, under in rules:
                        per_engine.append(_judge(normal, bundle, seen, rule, under, few, seed, n, tally,
                                                 guard))
            print(f"[engine {seed}, {n} runs] done ({time.perf_counter() - t0:.0f} s)", flush=True)
    print()
    print_table(["engine", "training runs", "FEW_RUNS", "guard", "rule:undercoverage",
                 "median threshold, sigma", "episodes", "residual", "hours"], per_engine, markdown=True)
    print()
    rows = []
    order = sorted(tally.items(), key=lambda kv: (kv[0][2], kv[0][3], kv[0][4], kv[0][0], kv[0][1]))
    for (rule, under, n, few, guard), (h, e, r) in order:
        rows.append([str(n), str(few), guard, f"{rule}:{under:g}", f"{h:.2f}", f"{e / h:.2f}", f"{r / h:.2f}",
                     "PASS" if e / h <= BUDGET_PER_H else "FAIL"])
    print_table(["training runs", "FEW_RUNS", "guard", "rule:undercoverage", "normal hours",
                 "false alarms per hour (all rules)", "residual rule per hour",
                 f"<= {BUDGET_PER_H:g} per hour"], rows, markdown=True)
    print(f"work dir {work}; total {time.perf_counter() - t0:.0f} s")
    return 0


def _judge(normal: Path, bundle: Bundle, seen: _capture, rule: str, under: float, few: int, seed: int,
           n: int, tally: dict, guard: str) -> list[str]:
    """Thresholds by ``rule`` on ``bundle``, the normal runs replayed through the node's code:
    the engine's table row; the hours and episodes added to ``tally``."""
    levels = threshold_levels(seen.calibs, seen.hours, seen.segments, FALSE_ALARMS_PER_HOUR / 2, under, rule)
    ocs = [dataclasses.replace(r, calibration=levels[r.name]) if r.name in levels else r for r in bundle.ocs]
    rep = replay(str(normal), Model((dataclasses.replace(bundle, ocs=ocs),)), None)
    h = sum(s["samples"] for s in rep.beds.values()) / FS / 3600.0
    eps = rep.alarm_episodes
    res = sum(1 for e in eps if e["reason"] == "residual")
    t = tally[(rule, under, n, few, guard)]
    t[0] += h
    t[1] += len(eps)
    t[2] += res
    thr = sorted(c.threshold for c in levels.values())
    return [str(seed), str(n), str(few), guard, f"{rule}:{under:g}", f"{thr[len(thr) // 2]:.2f}",
            str(len(eps)), str(res), f"{h:.2f}"]


if __name__ == "__main__":
    raise SystemExit(main())
