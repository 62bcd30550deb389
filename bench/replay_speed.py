"""Offline replay speed against merely reading and decoding the same recording.

    python -m bench replay-speed [--model MODEL] [--repeat N] [REC.mcap]

Without a model, trains a Lasso bundle on the committed sample runs first.
Prints messages per second and the real-time factor of: reading and decoding
every message (the ceiling: ``iter_messages_fast`` + ``orjson.loads``, the very
reader replay uses), the node's logic without writing, and ``ordervib replay
--out`` (logic plus the output MCAP), in one process (``--workers 0``) and with
the logic in a worker process (the default on two cores or more), all
measured in one run, each the best of ``--repeat`` runs.

Targets (PASS/FAIL lines): the default ``replay --out`` at >= 50x real time,
and at >= 0.5 of the read + decode speed (time ratio ceiling / replay).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import orjson

from node.contract import FS

ROOT = Path(__file__).resolve().parents[1]
TARGET_X = 50.0  # x real time
TARGET_RATIO = 0.5  # of the read + decode speed


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench replay-speed")
    ap.add_argument("recording", nargs="?", default=str(ROOT / "recordings" / "engine1_fault.mcap"))
    ap.add_argument("--model")
    ap.add_argument("--repeat", type=int, default=3, help="runs per figure, the best kept (default 3)")
    args = ap.parse_args(argv)
    from harness import make
    from node.mcap import iter_messages_fast
    from replay.offline import ReplayReport, default_workers

    tmp = Path(tempfile.mkdtemp(prefix="ordervib-replay-"))
    if not args.model:
        args.model = make.sample_model(tmp / "model")

    def read_decode() -> float:
        t0 = time.perf_counter()
        for m in iter_messages_fast(args.recording):
            orjson.loads(m.payload)
        return time.perf_counter() - t0

    last: list[ReplayReport] = []

    def replay(out: str | None, workers: int) -> float:
        last[:] = [make.replay(args.recording, args.model, out, workers)]
        return last[0].seconds

    workers = default_workers()
    steps = [("read + decode (ceiling)", read_decode),
             ("replay, logic only", lambda: replay(None, workers)),
             ("replay --out, one process (--workers 0)", lambda: replay(str(tmp / "out0.mcap"), 0)),
             (f"replay --out (logic + MCAP; --workers {workers}, the default)",
              lambda: replay(str(tmp / "out.mcap"), workers))]
    best = {name: float("inf") for name, _ in steps}
    for _ in range(max(1, args.repeat)):  # interleaved, so that a busy moment hits every step
        for name, run in steps:
            best[name] = min(best[name], run())
    n = sum(1 for _ in iter_messages_fast(args.recording))
    span = sum(b["samples"] for b in last[0].beds.values()) / FS  # engine time, gaps excluded
    print(f"{args.recording}: {n} messages, {span:.0f} s of data; best of {args.repeat} runs each")
    print("| step | s | messages/s | x real time |")
    print("|---|---|---|---|")
    for name, sec in best.items():
        print(f"| {name} | {sec:.2f} | {n / sec:,.0f} | {span / sec:.0f} |")
    t_read, t_out = best[steps[0][0]], best[steps[-1][0]]
    x, ratio = span / t_out, t_read / t_out
    print(f"replay --out runs at {ratio:.2f} of the read + decode speed "
          f"(one process: {t_read / best[steps[2][0]]:.2f})")
    print(f"{'PASS' if x >= TARGET_X else 'FAIL'}: replay --out at {x:.0f}x real time "
          f"(target >= {TARGET_X:.0f}x)")
    print(f"{'PASS' if ratio >= TARGET_RATIO else 'FAIL'}: replay --out at {ratio:.2f} of the "
          f"read + decode speed (target >= {TARGET_RATIO})")
    return 0 if x >= TARGET_X and ratio >= TARGET_RATIO else 1


if __name__ == "__main__":
    raise SystemExit(main())
