"""The transient rule against the fleet: false alarms on healthy held-out runs
and the stiffness losses it finds, for a choice of k sigma and floor.

    python -m bench transient-fleet [--seeds 1,2,3] [--train 4] [--held-out 2]
        [--plateau-scale 1] [--k 4] [--floor 2.5] [--schedule ramps|builtin] [--size 1] [--workdir W]

Per engine (one simulator seed): ``--train`` runs learn the fleet's transients of yA, yB and yC
(``node.training.transients.fleet_transients``: the node's own per-sample analysis); the next
``--held-out`` runs (the same engine, its history carried on) are healthy and never trained on;
one more run carries the simulator's stiffness fault (yB's shaft 10 % softer in stiffness from a drawn
onset, ``simulate --fault stiffness``; ``--size 2``: 20 % softer, every critical about 10.6 %
lower). Each run goes through the node's ``TransientWatch`` against the fleet, as the node
publishes ``monitor/transient``. Counted: transient alarms on the held-out runs (per hour of
run) and on the fault run before its onset, and whether the fault run raises one on yB after its
onset (found), with the delay. Beside them the largest |shift| of a matched critical on healthy
runs, the margin the floor and k leave. """

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import tempfile
from pathlib import Path
from typing import Any

from bench.transients import SCHEDULE
from harness import make
from node.console.table import print_table
from node.contract import load_schedule
from node.models.transients import FLOOR_PCT, K_SIGMA
from node.training.runs import read_runs
from node.training.transients import fleet_transients, run_transients

log = logging.getLogger(__name__)

TARGETS = ("yA", "yB", "yC")
CHANNELS = "nA,nB,nC,yA,yB,yC,yA_ph,yB_ph,yC_ph"


def engine(seed: int, work: Path, n_train: int, n_held: int, plateau_scale: float, k: float,
           floor: float, schedule: Path | None, size: float = 1.0) -> dict:
    """One engine's figures (see the module docstring)."""
    tag = "" if size == 1.0 else f".size{size:g}"
    train, test = work / f"e{seed}.train.mcap", work / f"e{seed}.test{tag}.mcap"
    sched = {} if schedule is None else {"schedule": str(schedule)}
    if not train.exists():
        make.simulate(train, runs=n_train, seed=seed, plateau_scale=plateau_scale, channels=CHANNELS,
                      **sched)
    if not test.exists():
        make.simulate(test, runs=n_train + n_held + 1, skip=n_train, seed=seed, fault="stiffness",
                      fault_size=size, plateau_scale=plateau_scale, channels=CHANNELS, **sched)
    truth = json.loads(test.with_suffix(".truth.json").read_text())
    sch = load_schedule(str(train.with_suffix(".schedule.toml")))
    train_runs, test_runs = read_runs(train), read_runs(test)
    fault_run = truth["runs"][-1]
    onset = fault_run["start"] + fault_run["fault"]["onset_s"]
    out: dict[str, Any] = {"engine": seed, "hours": 0.0, "alarms": 0, "messages": 0, "max_shift": 0.0,
                           "found": None,
           "before": 0, "fault_shift": None, "detail": [], "new_healthy": [], "new_fault": []}
    for target in TARGETS:
        fleet = fleet_transients(train_runs, sch, target)
        fleet = dataclasses.replace(fleet, settings=dataclasses.replace(fleet.settings, k_sigma=k,
                                                                        floor_pct=floor))
        for j, run in enumerate(test_runs):
            msgs = run_transients(run, sch, target, fleet.settings, fleet)
            faulty = j == len(test_runs) - 1
            if target == "yA":  # healthy time: the held-out runs, the fault run before its onset
                out["hours"] += ((min(onset, run.t[-1]) if faulty else run.t[-1]) - run.t[0]) / 3600.0
            for m in msgs:
                matched = [c for c in m["criticals"] if c["shift"] is not None and c["limit"] is not None]
                after = faulty and m["t"] >= onset
                new = [(target, round(c["shaft_speed"]), round(c["af"], 1), round(c["amplitude"], 2))
                       for c in m["criticals"] if c["expected_speed"] is None]
                out["new_fault" if after else "new_healthy"] += new
                if not after:
                    out["messages"] += 1
                    out["max_shift"] = max([out["max_shift"], *(abs(c["shift"]) for c in matched)])
                    if m["reason"] is not None:
                        out["alarms" if not faulty else "before"] += 1
                        out["detail"].append((target, j, m["kind"], [round(c["shift"], 2) for c in matched]))
                elif target == "yB" and m["reason"] is not None and out["found"] is None:
                    out["found"] = m["t"] - onset
                    out["fault_shift"] = min((c["shift"] for c in matched), key=lambda x: -abs(x))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench transient-fleet", description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", default="1,2,3", help="simulated engines (default 1,2,3)")
    ap.add_argument("--train", type=int, default=4, help="training runs per engine (default 4)")
    ap.add_argument("--held-out", type=int, default=2,
                    help="healthy held-out runs per engine (default 2)")
    ap.add_argument("--plateau-scale", type=float, default=1.0, help="simulate --plateau-scale (default 1)")
    ap.add_argument("--k", type=float, default=K_SIGMA,
                    help=f"alarm beyond k fleet sigmas (default {K_SIGMA:g})")
    ap.add_argument("--floor", type=float, default=FLOOR_PCT,
                    help=f"... and never within this %% (default {FLOOR_PCT:g})")
    ap.add_argument("--schedule", choices=("ramps", "builtin"), default="ramps",
                    help="ramps: bench transients' (idle, 6500, 9800, 6500 rpm, through the criticals; "
                         "default); builtin: the simulator's 12 OCs (short ramps between them)")
    ap.add_argument("--size", type=float, default=1.0,
                    help="the stiffness fault's size: 1 a 10 %% stiffness loss (default), 2 a 20 %% loss")
    ap.add_argument("--workdir", help="keep the recordings here (default: a new temp folder)")
    args = ap.parse_args(argv)
    try:
        seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
    except ValueError:
        ap.error(f"--seeds must be integers separated by commas, got {args.seeds!r}")
    if not seeds or min(seeds) < 0 or not 2 <= args.train <= 20 or not 1 <= args.held_out <= 20:
        ap.error("--seeds must be >= 0, --train in 2..20, --held-out in 1..20")
    if not 0.1 <= args.size < 10.0:
        ap.error("--size must be in [0.1, 10)")
    if args.workdir is not None and not Path(args.workdir).is_dir():
        ap.error(f"--workdir {args.workdir} is not a folder")
    logging.basicConfig(level=logging.WARNING, format="%(message)s")
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(args.workdir or tmp)
        sched = None
        if args.schedule == "ramps":
            sched = work / "ramps.schedule.toml"
            sched.write_text(SCHEDULE)
        rows = [engine(s, work, args.train, args.held_out, args.plateau_scale, args.k, args.floor, sched,
                       args.size) for s in seeds]
    print_table(["engine", "held-out h", "messages", "false alarms", "before onset", "max |shift| %",
                 "stiffness found", "delay s", "its shift %"],
                [[str(r["engine"]), f"{r['hours']:.2f}", str(r["messages"]), str(r["alarms"]),
                  str(r["before"]), f"{r['max_shift']:.2f}", "yes" if r["found"] is not None else "no",
                  "-" if r["found"] is None else f"{r['found']:.0f}",
                  "-" if r["fault_shift"] is None else f"{r['fault_shift']:+.2f}"] for r in rows],
                title=f"transient rule: k = {args.k:g} sigma, floor {args.floor:g} %; stiffness loss "
                      f"{10 * args.size:g} %")
    for r in rows:
        for d in r["detail"]:
            print(f"  engine {r['engine']}: alarm {d}")
        print(f"  engine {r['engine']}: criticals no fleet resonance matches (target, rpm, AF, amplitude): "
              f"healthy {r['new_healthy']}, after the onset {r['new_fault']}")
    hours = sum(r["hours"] for r in rows)
    alarms = sum(r["alarms"] + r["before"] for r in rows)
    found = sum(r["found"] is not None for r in rows)
    print(f"false alarms: {alarms} in {hours:.2f} h of healthy runs "
          f"({alarms / max(hours, 1e-9):.2f} per hour); "
          f"stiffness losses found: {found} of {len(rows)}")
    return 0
