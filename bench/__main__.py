"""Run a benchmark: ``python -m bench NAME [options]`` (``python -m bench`` lists them)."""

from __future__ import annotations

import importlib
import sys

BENCHMARKS = {
    "beam": "bench.beam",
    "parametric": "bench.parametric",
    "prom-engine": "bench.prom_engine",
    "prom-table": "bench.prom_table",
    "prom-family": "bench.prom_family",
    "prom-pseudo": "bench.prom_pseudo",
    "faults": "bench.faults",
    "generalise": "bench.generalise",
    "read-speed": "bench.read_speed",
    "import-speed": "bench.import_speed",
    "train-speed": "bench.train_speed",
    "replay-speed": "bench.replay_speed",
    "worker-speed": "bench.worker_speed",
    "rotor": "bench.rotor",
    "live": "bench.live",
    "soak": "bench.soak",
    "hostile": "bench.hostile",
    "top-curves": "bench.top_curves",
    "stiffness-drift": "bench.stiffness_drift",
    "thresholds": "bench.thresholds",
    "plans": "bench.plans",
    "transients": "bench.transients",
    "transient-fleet": "bench.transient_fleet",
    "whole-run": "bench.whole_run",
    "verdict": "bench.verdict",
}


def main(argv: list[str]) -> int:
    if not argv or argv[0] not in BENCHMARKS:
        print("usage: python -m bench {" + "|".join(BENCHMARKS) + "} [options]", file=sys.stderr)
        return 2
    from node import native
    # every figure is of the modules that ran: the compiled ones or the pure Python ones (node.native)
    print(f"per-sample modules: {native.state()} (ordervib native state)", file=sys.stderr)
    mod = importlib.import_module(BENCHMARKS[argv[0]])
    return int(mod.main(argv[1:]) or 0)


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
