"""Soak: hours of recorded data through the live node, faster than real time.

    python -m bench soak [--hours 4] [--speed 40] [--model MODEL] [REC.mcap]

The recording's sensor data (its runs, over and over, each pass shifted after the
last; gaps between runs squeezed out of the pacing) is published over Zenoh on
loopback into ``ordervib run`` at ``--speed`` x real time. Reports hours pushed,
inputs lost (sent minus recorded), monitor coverage, the node's RSS at the start
and end (and its largest), and the end-to-end latency (publish of a sample's last
needed message -> its monitor message) p50 / p99 / max. PASS when nothing is lost,
every sample has its monitor message, RSS grows by less than ``RSS_GROWTH_MB`` after
the first minute, and the latency max stays under ``LATENCY_MAX_MS``.
Without ``--model`` a Lasso bundle is trained on the committed sample runs first.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from harness.live import ROOT, soak

RSS_GROWTH_MB = 50.0
LATENCY_MAX_MS = 1000.0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench soak")
    ap.add_argument("recording", nargs="?", default=str(ROOT / "recordings" / "engine1_runs.mcap"))
    ap.add_argument("--model")
    ap.add_argument("--hours", type=float, default=4.0, help="sensor data to push, h (default 4)")
    ap.add_argument("--speed", type=float, default=40.0, help="x real time (default 40)")
    args = ap.parse_args(argv)
    from harness import make
    from node.console.table import print_table
    tmp = Path(tempfile.mkdtemp(prefix="ordervib-soak-"))
    if not args.model:
        args.model = make.sample_model(tmp / "model")
    r = soak(args.model, args.recording, args.hours, args.speed, tmp)
    after_warmup = [m for s, m in r.rss_mb if s >= 60.0] or [m for _, m in r.rss_mb]
    growth = after_warmup[-1] - after_warmup[0]
    lat = r.lat_ms
    p50, p99, worst = (float(np.percentile(lat, q)) if len(lat) else float("nan") for q in (50, 99, 100))
    checks = {"lost": r.lost == 0, "coverage": r.recorded_monitor == r.samples,
              "rss": growth < RSS_GROWTH_MB, "latency": worst < LATENCY_MAX_MS, "exit": r.exit_code == 0}

    def res(k: str) -> str:
        return "PASS" if checks[k] else "FAIL"
    rows = [
        ["hours of data pushed", f"{r.hours:.2f} h in {r.wall_s:.0f} s ({r.hours * 3600 / r.wall_s:.0f} x "
         f"real time)", f"{args.hours:g} h at {args.speed:g} x", ""],
        ["inputs lost (sent - recorded)", f"{r.lost} ({r.sent:,} sent)", "0", res("lost")],
        ["monitor coverage (recorded; received live)", f"{r.recorded_monitor:,} / {r.samples:,} samples "
         f"({r.monitored:,} live before the stop)", "all", res("coverage")],
        ["node RSS start -> end (max)", f"{r.rss_mb[0][1]:.0f} -> {r.rss_mb[-1][1]:.0f} MB "
         f"({max(m for _, m in r.rss_mb):.0f})", "", ""],
        ["RSS growth after the first minute", f"{growth:+.1f} MB", f"< {RSS_GROWTH_MB:g} MB", res("rss")],
        ["latency p50 / p99 / max", f"{p50:.1f} / {p99:.1f} / {worst:.1f} ms", f"max < {LATENCY_MAX_MS:g} ms",
         res("latency")],
        ["node exit / last health", f"{r.exit_code}; received {r.health.get('received')}, dropped "
         f"{r.health.get('dropped')}, recording {r.health.get('recording')}", "0", res("exit")],
    ]
    print_table(["figure", "measured", "target", "result"], rows, markdown=True,
                title=f"Soak: {args.recording} through ordervib run")
    return 0 if all(checks.values()) else 1


if __name__ == "__main__":
    raise SystemExit(main())
