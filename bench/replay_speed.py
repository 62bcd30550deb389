"""Offline replay speed against merely reading and decoding the same recording.

    python -m bench replay-speed [--model MODEL] [REC.mcap]

Without a model, trains a Lasso bundle on the committed sample runs first.
Prints messages per second and the real-time factor of: reading and decoding
every message (the ceiling), the node's logic without writing, and
``ordervib replay --out`` (logic plus the output MCAP), measured in one run.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import orjson

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench replay-speed")
    ap.add_argument("recording", nargs="?", default=str(ROOT / "recordings" / "engine1_fault.mcap"))
    ap.add_argument("--model")
    args = ap.parse_args(argv)
    from node.cli import main as cli
    from node.commands.replay import replay_offline
    from node.recording import iter_messages_fast

    tmp = Path(tempfile.mkdtemp(prefix="ordervib-replay-"))
    if not args.model:
        args.model = str(tmp / "model")
        cli(["train", str(ROOT / "recordings" / "engine1_runs.mcap"), "--schedule",
             str(ROOT / "recordings" / "engine1_runs.schedule.toml"), "--out", args.model,
             "--method", "lasso", "--quiet"])
    t0 = time.perf_counter()
    n = 0
    for m in iter_messages_fast(args.recording):
        orjson.loads(m.payload)
        n += 1
    t_read = time.perf_counter() - t0
    s_logic = replay_offline(args.recording, args.model, None, quiet=True)
    span = sum(b["samples"] for b in s_logic["beds"].values()) / 40.0  # engine time, gaps excluded
    s_full = replay_offline(args.recording, args.model, str(tmp / "out.mcap"), quiet=True)
    print(f"{args.recording}: {n} messages, {span:.0f} s of data")
    print("| step | s | messages/s | x real time |")
    print("|---|---|---|---|")
    for name, sec in (("read + decode (ceiling)", t_read), ("replay, logic only", s_logic["seconds"]),
                      ("replay --out (logic + MCAP)", s_full["seconds"])):
        print(f"| {name} | {sec:.2f} | {n / sec:,.0f} | {span / sec:.0f} |")
    print(f"replay --out runs at {t_read / s_full['seconds']:.2f} of the read + decode speed")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
