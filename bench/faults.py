"""Fault detection in replay: delay after onset per fault, false alarms per hour on normal runs.

    python -m bench faults [--seed 11] [--train-runs 8] [--normal-runs 8] [--instances 3]
                           [--method wdmd] [--workdir DIR]

One simulated engine: the first ``--train-runs`` runs train the model (the CLI's
``ordervib train``, cross-validation on those runs only); the next ``--normal-runs``
are held out, fault-free, and replayed (``replay_offline``, the node's own code) to
count alarm episodes per hour. Then the first held-out run is simulated again with
each fault (imbalance, stiffness, stuck-sensor, drift), ``--instances`` times with
different onsets (``--fault-seed``), and the delay from onset to the first alarm
episode starting at or after it is measured. Targets (issue 5): every fault flagged
within 60 s, at most 1 false alarm per hour.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from node.cli import main as cli
from node.commands.replay import replay_offline

FAULTS = ("imbalance", "stiffness", "stuck-sensor", "drift")
DELAY_TARGET_S = 60.0
FALSE_ALARM_TARGET_PER_H = 1.0


def _simulate(out: Path, runs: int, seed: int, skip: int, fault: str | None = None,
              fault_seed: int | None = None) -> dict:
    argv = ["simulate", "--runs", str(runs), "--seed", str(seed), "--skip", str(skip),
            "--out", str(out), "--quiet"]
    if fault:
        argv += ["--fault", fault, "--fault-seed", str(fault_seed)]
    if cli(argv) != 0:
        raise SystemExit(f"simulate failed: {argv}")
    return json.loads(out.with_suffix(".truth.json").read_text())


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench faults")
    ap.add_argument("--seed", type=int, default=11, help="engine seed (default 11)")
    ap.add_argument("--train-runs", type=int, default=8)
    ap.add_argument("--normal-runs", type=int, default=8)
    ap.add_argument("--instances", type=int, default=3, help="onsets per fault kind (default 3)")
    ap.add_argument("--method", default="wdmd", choices=["wdmd", "delay-dmd", "lasso"])
    ap.add_argument("--workdir", default=None, help="keep recordings and model here (reused if present)")
    args = ap.parse_args(argv)
    work = Path(args.workdir or tempfile.mkdtemp(prefix="ordervib-faults-"))
    work.mkdir(parents=True, exist_ok=True)
    n, m, seed = args.train_runs, args.normal_runs, args.seed
    t0 = time.perf_counter()

    train, normal, model = work / "train.mcap", work / "normal.mcap", work / f"model-{args.method}"
    if not train.exists():
        print(f"simulating {n} training runs (engine seed {seed}) ...", flush=True)
        _simulate(train, n, seed, 0)
    if not normal.exists():
        print(f"simulating {m} held-out normal runs ...", flush=True)
        _simulate(normal, n + m, seed, n)
    if not (model / "manifest.json").exists():
        print(f"training {args.method} on the training runs ...", flush=True)
        cli(["train", str(train), "--schedule", str(work / "train.schedule.toml"), "--out", str(model),
             "--method", args.method, "--quiet"])

    s = replay_offline(str(normal), str(model), None, quiet=True)
    hours = sum(b["samples"] for b in s["beds"].values()) / 40.0 / 3600.0
    false = s["alarm_episodes"]
    rate = len(false) / hours

    rows = []
    for fault in FAULTS:
        for i in range(1, args.instances + 1):
            rec = work / f"{fault}-{i}.mcap"
            truth_path = rec.with_suffix(".truth.json")
            if rec.exists() and truth_path.exists():
                truth = json.loads(truth_path.read_text())
            else:
                truth = _simulate(rec, n + 1, seed, n, fault, i)
            f = truth["runs"][-1]["fault"]
            r = replay_offline(str(rec), str(model), None, quiet=True)
            eps = r["alarm_episodes"]
            after = [e for e in eps if e["end"] >= f["onset"]]
            before = [e for e in eps if e["end"] < f["onset"]]
            first = after[0] if after else None
            delay = max(0.0, first["start"] - f["onset"]) if first else float("inf")
            rows.append((fault, i, f["oc"], f["onset_s"], delay, first["reason"] if first else "-",
                         len(before)))
        print(f"  {fault}: done ({time.perf_counter() - t0:.0f} s)", flush=True)

    print()
    print(f"engine seed {seed}, model {args.method} trained on {n} runs; work dir {work}")
    print()
    print("| fault | instance | onset OC | onset s into run | first alarm after onset, s | rule | "
          f"alarms before onset | within {DELAY_TARGET_S:.0f} s |")
    print("|---|---|---|---|---|---|---|---|")
    for fault, i, oc, onset_s, delay, reason, before in rows:
        ok = "PASS" if delay <= DELAY_TARGET_S else "FAIL"
        shown = f"{delay:.1f}" if delay != float("inf") else "never"
        print(f"| {fault} | {i} | {oc} | {onset_s:.0f} | {shown} | {reason} | {before} | {ok} |")
    detected = sum(1 for r in rows if r[4] <= DELAY_TARGET_S)
    print()
    print(f"faults flagged within {DELAY_TARGET_S:.0f} s: {detected}/{len(rows)}")
    reasons = {}
    for e in false:
        reasons[e["reason"]] = reasons.get(e["reason"], 0) + 1
    print(f"normal held-out runs: {m} runs, {hours:.2f} h of data, {len(false)} alarm episode(s) "
          f"{reasons or ''} = {rate:.2f} per hour (target <= {FALSE_ALARM_TARGET_PER_H:g}): "
          f"{'PASS' if rate <= FALSE_ALARM_TARGET_PER_H else 'FAIL'}")
    print(f"total {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
