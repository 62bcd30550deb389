"""``ordervib replay``: run the node offline over a recording, or publish a recording to Zenoh."""

from __future__ import annotations

import argparse
import sys
import time

from node.errors import OrdervibError

NAME = "replay"
HELP = "run the node offline over a recording (--model), or publish it to Zenoh (--publish)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("recording", metavar="REC.mcap")
    p.add_argument("--model", metavar="MODEL", help="model bundle: run the node offline")
    p.add_argument("--out", metavar="OUT.mcap", help="with --model: write what a live node would log")
    p.add_argument("--publish", action="store_true", help="publish the recording's sensor messages")
    p.add_argument("--connect", metavar="ENDPOINT",
                   help="with --publish: Zenoh endpoint to connect to (default tcp/127.0.0.1:7447 "
                        "unless the --zenoh-config file gives endpoints)")
    p.add_argument("--zenoh-config", metavar="FILE.json5",
                   help="with --publish: Zenoh configuration file (e.g. TLS root CA; see docs/zenoh/)")
    p.add_argument("--speed", type=float, default=1.0, metavar="X",
                   help="with --publish: X times real time (default 1; 0: as fast as possible)")
    p.add_argument("--quiet", action="store_true", help="no summary on stderr")


def replay_offline(recording: str, model: str, out: str | None, quiet: bool = False) -> dict:
    """Feed every sensor message, in file order, through the node's logic; returns a summary."""
    from node.alarms import EpisodeLog
    from node.bundle import load_bundle
    from node.core import NodeCore
    from node.recording import ReadStats, RecordingWriter, iter_messages_fast

    bundle = load_bundle(model)
    core = NodeCore(bundle)
    stats = ReadStats()
    t0 = time.perf_counter()
    writer = RecordingWriter(out) if out else None
    alarms = EpisodeLog()
    n_in = 0
    try:
        for m in iter_messages_fast(recording, stats=stats):
            if "/monitor/" in m.topic:  # a node's own recording: recompute, do not copy
                continue
            n_in += 1
            if writer:
                writer.write(m.topic, m.log_time / 1e9, m.payload, m.publish_time)
            for key, msg in core.handle(m.topic, m.payload):
                if writer:
                    writer.write(key, msg["t"], msg, m.log_time)
                alarms.add(key, msg)
        for key, msg in core.finish():
            alarms.add(key, msg)
            if writer:
                writer.write(key, msg["t"], msg, round(msg["t"] * 1e9))
    finally:
        if writer:
            writer.close()
    elapsed = time.perf_counter() - t0
    summary = {"inputs": n_in, "published": core.stats.published, "malformed": core.stats.malformed,
               "seconds": elapsed, "truncated": stats.truncated,
               "alarm_episodes": alarms.episodes,
               "beds": {b: {"samples": s.aligner.stats.samples, "alarm_samples": s.alarms,
                            "late": s.aligner.stats.late} for b, s in core.stats.beds.items()}}
    if not quiet:
        span = sum(s.aligner.stats.samples for s in core.stats.beds.values()) / 40.0
        print(f"replayed {n_in} input messages ({span:.0f} s of data) in {elapsed:.1f} s "
              f"({span / max(elapsed, 1e-9):.0f}x real time); published {core.stats.published} "
              f"monitor messages; {core.stats.malformed} malformed skipped", file=sys.stderr)
        for b, s in core.stats.beds.items():
            n_ep = sum(1 for e in alarms.episodes if e["key"].split("/")[1] == b)
            print(f"  {b}: {s.aligner.stats.samples} samples, {s.alarms} alarm samples "
                  f"in {n_ep} episode(s), "
                  f"missing {dict(s.aligner.stats.missing)}", file=sys.stderr)
        if out:
            print(f"wrote {out}", file=sys.stderr)
    return summary


def run(args: argparse.Namespace) -> int:
    if args.publish == bool(args.model):
        raise OrdervibError("give either --model (offline node) or --publish (to Zenoh)")
    if args.model:
        replay_offline(args.recording, args.model, args.out, args.quiet)
        return 0
    if args.speed < 0:
        raise OrdervibError("--speed must be >= 0")
    from node.live import publish_recording
    publish_recording(args.recording, args.connect, args.speed, args.quiet,
                      config_file=args.zenoh_config)
    return 0
