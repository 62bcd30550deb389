"""Training speed and held-out accuracy of the switching model (docs/results.md).

    python -m bench train-speed [--runs N] [--train T.mcap --test H.mcap --schedule S.toml]

Without recordings, simulates N (``--runs``, default 8) training and 3 held-out runs of one
engine (seed 11) first. Prints the time to read the training recording, the training wall
time (cross-validation included) and its ratio to the read time, and, per method, the mean
held-out eps_td beside the characteristic-curve baseline, all measured in this one run.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from harness import make
from node.contract import FS


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench train-speed")
    ap.add_argument("--train")
    ap.add_argument("--test")
    ap.add_argument("--schedule")
    ap.add_argument("--methods", default="wdmd,delay-dmd,lasso")
    ap.add_argument("--runs", type=int, default=8, help="training runs to simulate (default 8)")
    ap.add_argument("--check-full", action="store_true",
                    help="also train the default with the full CV as before (every candidate on "
                         "every fold, each fold fitted afresh) and say whether every OC's choice is "
                         "the same")
    args = ap.parse_args(argv)
    from node.contract.schedule import load_schedule
    from node.training.calibrate import calibrate_checks
    from node.training.evaluation import baseline_eps, evaluate
    from node.training.fit import load_runs
    from node.training.train import fleet_curve, history_config, train

    tmp = Path(tempfile.mkdtemp(prefix="ordervib-bench-"))
    if not args.train:
        n = args.runs
        print(f"simulating {n} training and 3 held-out runs (seed 11) ...", flush=True)
        make.simulate(tmp / "train.mcap", runs=n, seed=11)
        make.simulate(tmp / "test.mcap", runs=n + 3, skip=n, seed=11)
        args.train, args.test = str(tmp / "train.mcap"), str(tmp / "test.mcap")
        args.schedule = str(tmp / "train.schedule.toml")
    schedule = load_schedule(args.schedule)
    t0 = time.perf_counter()
    train_runs = load_runs([args.train], quiet=True)
    t_read = time.perf_counter() - t0
    test_runs = load_runs([args.test], quiet=True)
    base = baseline_eps(train_runs, test_runs, schedule, "yB")
    rows = []
    t1 = time.perf_counter()
    fleet = fleet_curve(train_runs, schedule.switch, "yB")
    config = history_config(train_runs, schedule)
    t_common = time.perf_counter() - t1  # what ordervib train does once before every method
    default = None
    for method in args.methods.split(","):
        # as ordervib train does; without the curve candidates (the former defaults);
        # and without the derived run_curve either
        for curve, curves, label in ((fleet, True, method), (fleet, False, f"{method}, no curve candidates"),
                                     (None, False, f"{method}, neither")):
            t1 = time.perf_counter()
            results = train(train_runs, schedule, method=method, fleet=curve, curves=curves, config=config)
            calibrate_checks(train_runs, schedule, "yB", 0.25)
            t_train = time.perf_counter() - t1 + t_common
            default = default or results
            evals, _ = evaluate(results, test_runs, schedule, "yB", curve)
            held = np.nanmean([e.eps for e in evals])
            cv = np.nanmean([r.cv_eps for r in results])
            alarms = sum(e.alarm_samples for e in evals) / FS
            rows.append((label, t_read + t_train, cv, held, alarms))
    print(f"\n{len(train_runs)} training runs, {len(test_runs)} held-out runs; reading took {t_read:.1f} s")
    print("| method | train wall s (read + CV + fit) | mean CV eps_td | mean held-out eps_td | "
          "alarm s on normal runs |")
    print("|---|---|---|---|---|")
    for m, t, cv, held, al in rows:
        print(f"| {m} | {t:.1f} | {cv:.3f} | {held:.3f} | {al:.1f} |")
    print(f"| characteristic-curve baseline | - | - | {np.nanmean(base):.3f} | - |")
    first = rows[0]
    print(f"\n{first[0]} (the default): training {first[1] - t_read:.1f} s = "
          f"{(first[1] - t_read) / t_read:.1f} x the {t_read:.1f} s of reading its {len(train_runs)} runs")
    if args.check_full and default is not None:
        t1 = time.perf_counter()
        full = train(train_runs, schedule, method=args.methods.split(",")[0], fleet=fleet, config=config,
                     prune=False)
        t_full = time.perf_counter() - t1 + t_common
        same = [(a.kind, a.params, a.inputs, a.cv_eps, a.calibration) ==
                (b.kind, b.params, b.inputs, b.cv_eps, b.calibration) for a, b in zip(default, full)]
        print("the full CV as before (every candidate on every fold, each fitted afresh): "
              f"{t_full:.1f} s against "
              f"{first[1] - t_read:.1f} s; the same choice, inputs, CV eps and calibration in "
              f"{sum(same)} of {len(same)} OCs")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
