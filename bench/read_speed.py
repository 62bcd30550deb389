"""Read speed: ``node.mcap.read_runs`` against the plain mcap + json loop.

    .venv/bin/python bench/read_speed.py [REC.mcap]

Without an argument it reads recordings/engine1_runs.mcap. Prints both
throughputs (messages per second) and their ratio, measured in one run.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from mcap.reader import make_reader

from node.mcap import ReadStats
from node.training.runs import read_runs

DEFAULT = Path(__file__).resolve().parent.parent / "recordings" / "engine1_runs.mcap"


def plain(path: Path) -> int:
    """The baseline: default reader (log-time order) and json.loads per message."""
    n = 0
    with open(path, "rb") as f:
        for _schema, _channel, message in make_reader(f).iter_messages():
            json.loads(message.data)
            n += 1
    return n


def fast(path: Path) -> int:
    """read_runs: file-order scan, orjson, vectorised alignment into runs."""
    stats = ReadStats()
    read_runs(path, stats=stats)
    return stats.messages


def main(argv: list[str]) -> int:
    path = Path(argv[0]) if argv else DEFAULT
    if not path.exists():
        print(f"read_speed: no recording {path} (make one with: ordervib simulate)", file=sys.stderr)
        return 2
    rates = {}
    for name, fn in (("plain make_reader + json.loads", plain), ("node.mcap.read_runs", fast)):
        start = time.perf_counter()
        n = fn(path)
        dt = time.perf_counter() - start
        rates[name] = n / dt
        print(f"{name:34s} {n:9d} messages in {dt:6.2f} s = {n / dt:10.0f} msg/s")
    ratio = rates["node.mcap.read_runs"] / rates["plain make_reader + json.loads"]
    print(f"{'speed-up':34s} {ratio:.1f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
