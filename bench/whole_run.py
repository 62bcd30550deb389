"""The whole run, light-off to standstill, every sample scored, on engines held out from choosing.

    python -m bench whole-run [--seeds 11..19] [--train-runs 8] [--test-runs 3]
        [--targets yB] [--workdir W] [--reuse]

Per engine (one simulator seed: its own rotor with two or more modes inside the test's speed
range, its imbalance, a bowed rotor at each start sized by the shutdown before it, and an order
tracker lagging by its own time constant, 0.5-2 s, ``simulate --tracker drawn``, that nothing
but this bench's scoring reads): ``--train-runs`` runs train the defaults
(``ordervib train``, the lag estimated from the runs), and the next ``--test-runs`` runs of the
same engine, never trained on, are predicted by the batch path (``predict_segments``, the
node's own rules: live and replay give the same numbers) and scored on every sample from
light-off to standstill, a sample without a prediction a miss (its error its measured value).

Printed per engine and target, beside their comparisons measured in this same run:

* ``coverage``: the share of samples from light-off to standstill with a prediction (target 99 %);
* ``first OC``: the first OC's eps_td with its start from light-off, against the characteristic
  curve by direction (``DirectionCurves``: the training runs' mean amplitude per speed on rising,
  on falling and on any speed; target: no worse);
* ``rundown``: the same for the coast-down after the last OC;
* ``mean``: the mean over the OCs (the first with its start) scored on every sample, against the
  same OC models scored the way the node was judged before the start and the rundown had
  models: only the OCs' own segments, only their predicted samples (target: no worse);
* the tracker lag the training estimated beside the simulator's (scoring only).

The engines 11-19 were never used to choose a default. Recordings and models are kept in
``--workdir`` (``--reuse``: models found there are used again; say which code trained them).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import tempfile
from pathlib import Path

import numpy as np

from harness import make
from node.console.table import print_table
from node.contract.schedule import Schedule
from node.models.bundle import load_model
from node.sysid.metrics import pooled_eps
from node.training.evaluation import (
    DirectionCurves,
    SegmentPrediction,
    baseline_segment_eps,
    coverage,
    predict_segments,
    score_segments,
)
from node.training.runs import read_runs

log = logging.getLogger("bench.whole_run")


def _seeds(spec: str) -> list[int]:
    if ".." in spec:
        lo, hi = spec.split("..")
        return list(range(int(lo), int(hi) + 1))
    return [int(x) for x in spec.split(",") if x.strip()]


def predicted_only_mean(schedule: Schedule, preds: list[SegmentPrediction]) -> float:
    """The mean over the OCs of eps_td on their own segments' predicted samples only (the start
    and the rundown left out): how the node was scored before every sample counted."""
    eps = []
    for j in range(len(schedule.names)):
        pairs = [(p.measured[ok], p.predicted[ok]) for p in preds if p.oc == j
                 for ok in [np.isfinite(p.predicted) & np.isfinite(p.measured)] if ok.any()]
        if pairs:
            eps.append(pooled_eps(pairs))
    return float(np.mean(eps)) if eps else math.nan


def engine_rows(seed: int, work: Path, train_runs: int, test_runs: int, targets: list[str],
                reuse: bool) -> list[dict]:
    """Simulate (unless present), train (unless ``reuse`` and present) and score one engine: a
    dict per target."""
    train_rec, test_rec = work / f"engine{seed}.train.mcap", work / f"engine{seed}.test.mcap"
    if not (train_rec.exists() and test_rec.exists()):
        log.info("engine %d: simulating %d + %d runs", seed, train_runs, test_runs)
        make.simulate(train_rec, runs=train_runs, seed=seed, tracker="drawn")
        make.simulate(test_rec, runs=train_runs + test_runs, skip=train_runs, seed=seed, tracker="drawn")
    truth = json.loads(test_rec.with_suffix(".truth.json").read_text())  # scoring only
    folder = work / f"engine{seed}.model"
    if not (reuse and (folder / "manifest.json").exists()):
        log.info("engine %d: training %s", seed, ",".join(targets))
        make.train([train_rec], train_rec.with_suffix(".schedule.toml"), folder, target=",".join(targets))
    model = load_model(folder)
    schedule = model.schedule
    train, test = read_runs(train_rec), read_runs(test_rec)
    out = []
    for tg in targets:
        b = model[tg]
        preds = predict_segments(b.ocs, test, schedule, tg, b.curve, b.config)
        ev = score_segments(b.ocs, schedule, preds)
        base = baseline_segment_eps(schedule, preds, DirectionCurves.fit(train, schedule.switch, tg)
                                    .over(test, preds, schedule.switch))
        covered, total = coverage(test, schedule, preds, b.config)
        lag = b.transients.settings.tracker_s if b.transients is not None else None
        n = len(schedule.names)
        out.append({"engine": seed, "target": tg, "covered": covered, "samples": total,
                    "first": ev[0].eps, "first_curve": base[0],
                    "rundown": ev[n].eps, "rundown_curve": base[n],
                    "mean": float(np.mean([e.eps for e in ev[:n]])),
                    "before": predicted_only_mean(schedule, preds),
                    "lag": lag, "lag_truth": float(truth["rotor"]["tracker_s"])})
    return out


def _ok(ok: bool) -> str:
    return "ok" if ok else "FAIL"


def print_rows(rows: list[dict]) -> None:
    table = []
    for r in rows:
        cov = r["covered"] / max(r["samples"], 1)
        lag = "-" if r["lag"] is None else f"{r['lag']:.2f}"
        table.append([str(r["engine"]), r["target"], f"{cov:.2%} {_ok(cov >= 0.99)}",
                      f"{r['first']:.3f} / {r['first_curve']:.3f} {_ok(r['first'] <= r['first_curve'])}",
                      f"{r['rundown']:.3f} / {r['rundown_curve']:.3f} "
                      f"{_ok(r['rundown'] <= r['rundown_curve'])}",
                      f"{r['mean']:.3f} / {r['before']:.3f} {_ok(r['mean'] <= r['before'])}",
                      f"{lag} / {r['lag_truth']:.2f}"])
    print_table(["engine", "target", "coverage (>= 99 %)", "first OC: model / curve by direction",
                 "rundown: model / curve by direction", "mean: every sample / before (predicted only)",
                 "lag s: estimated / simulator's"], table)


def print_summary(rows: list[dict]) -> None:
    for tg in sorted({r["target"] for r in rows}):
        mine = [r for r in rows if r["target"] == tg]
        cov = sum(r["covered"] for r in mine) / max(sum(r["samples"] for r in mine), 1)
        worst = min(r["covered"] / max(r["samples"], 1) for r in mine)

        def mean(key: str, mine: list[dict] = mine) -> float:
            return float(np.mean([r[key] for r in mine]))

        print(f"{tg}, {len(mine)} held-out engines: coverage pooled {cov:.2%}, worst engine {worst:.2%} "
              f"(target 99 %) {_ok(worst >= 0.99)}")
        for what, a, b in (("first OC with its start", "first", "first_curve"),
                           ("rundown", "rundown", "rundown_curve")):
            wins = sum(r[a] <= r[b] for r in mine)
            print(f"  {what}: model {mean(a):.3f} against the curve by direction {mean(b):.3f} (held-out "
                  f"mean eps_td; no worse on {wins} of {len(mine)} engines) {_ok(mean(a) <= mean(b))}")
        print(f"  mean over the OCs, every sample: {mean('mean'):.3f} against {mean('before'):.3f} scored "
              f"on predicted OC samples only {_ok(mean('mean') <= mean('before'))}")
        lags = [abs(r["lag"] / r["lag_truth"] - 1.0) for r in mine if r["lag"]]
        print(f"  tracker lag within 20 % of the simulator's on {sum(x <= 0.2 for x in lags)} of {len(mine)} "
              "engines")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench whole-run", description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", default="11..19", help="engines (simulator seeds): a..b or a,b,c")
    ap.add_argument("--train-runs", type=int, default=8)
    ap.add_argument("--test-runs", type=int, default=3)
    ap.add_argument("--targets", default="yB", help="comma list of the orders modelled and scored")
    ap.add_argument("--workdir", default=None, help="keep recordings and models here (default: a temp dir)")
    ap.add_argument("--reuse", action="store_true", help="use the models found in --workdir")
    args = ap.parse_args(argv)
    seeds = _seeds(args.seeds)
    if not (1 <= len(seeds) <= 50 and 2 <= args.train_runs <= 40 and 1 <= args.test_runs <= 20):
        ap.error("1-50 seeds, 2-40 training runs and 1-20 held-out runs")
    targets = [t.strip() for t in args.targets.split(",") if t.strip()]
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(args.workdir) if args.workdir else Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        rows = [r for s in seeds for r in engine_rows(s, work, args.train_runs, args.test_runs, targets,
                                                      args.reuse)]
    print_rows(rows)
    print_summary(rows)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
