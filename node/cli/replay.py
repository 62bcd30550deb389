"""``ordervib replay``: run the node offline over a recording, or publish a recording to Zenoh."""

from __future__ import annotations

import argparse
import logging
import math
from typing import Any

from node.cli.outputs import check_output, replacing
from node.cli.results import add_json_option, print_json
from node.contract import FS, bed_of
from node.contract.errors import OrdervibError
from node.mcap import warn_unfinished

log = logging.getLogger(__name__)

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
    p.add_argument("--max-gap", type=float, default=None, metavar="S",
                   help="with --publish and --speed > 0: shorten every gap longer than S seconds between "
                        "messages (the engine standing between runs) to S (default: the recording's own "
                        "timing, shutdowns included)")
    p.add_argument("--wait", type=float, default=5.0, metavar="S",
                   help="with --publish: how long to wait for a subscriber before giving up "
                        "(default 5 s; exit status 2 if none matched)")
    p.add_argument("--workers", type=int, choices=(0, 1), default=None,
                   help="with --model: 1 runs the node's logic in a second process while this one "
                        "reads and writes, 0 keeps it in one (default: 1 on 2+ cores)")
    p.add_argument("--engine-state", metavar="FILE.json",
                   help="with --model: each bed's engine history before the recording (a live "
                        "node's state file; read only). Default: the recording's first run is a cold start")
    p.add_argument("--quiet", action="store_true",
                   help="no progress on stderr (the result still goes to stdout)")
    add_json_option(p)


def replay_offline(recording: str, model: str, out: str | None, quiet: bool = False,
                   workers: int | None = None, engine_state: str | None = None,
                   result: bool = False, as_json: bool = False) -> dict[str, Any]:
    """Feed every sensor message, in file order, through the node's logic; returns a summary.

    quiet: no progress on stderr; result: print the summary (what was replayed and written) on
    stdout; as_json: print it as one JSON object instead (the returned summary with ``out``).

    workers: 1 runs the logic in a worker process, 0 in this one; None picks (see replay.offline).
    """
    from node.cli.logs import Progress
    from replay.offline import replay_model_file
    bar = Progress("replay", log)

    def progress(fraction: float, n: int) -> None:
        if not quiet:
            bar(fraction, n, "messages")

    if out is None:
        r = replay_model_file(recording, model, None, workers, engine_state, progress)
    else:
        with replacing(out) as tmp:  # an existing output is replaced only by a complete one
            r = replay_model_file(recording, model, tmp, workers, engine_state, progress)
    if r.truncated:
        warn_unfinished(log, recording, f"{r.inputs} sensor messages")
    span = sum(s["samples"] for s in r.beds.values()) / FS
    summary = {"inputs": r.inputs, "published": r.published, "malformed": r.malformed,
               "seconds": r.seconds, "truncated": r.truncated, "workers": r.workers,
               "alarm_episodes": r.alarm_episodes, "span_s": span,
               "beds": {b: {k: s[k] for k in ("samples", "alarm_samples", "late", "missing")}
                        for b, s in r.beds.items()}}
    if as_json:
        print_json({**summary, "out": out})
    elif result:  # the result, on stdout (progress and other status go to stderr)
        print(f"replayed {r.inputs} input messages ({span:.0f} s of data) in {r.seconds:.1f} s "
              f"({span / max(r.seconds, 1e-9):.0f}x real time); published {r.published} monitor "
              f"messages; {r.malformed} malformed skipped")
        for b, s in r.beds.items():
            n_ep = sum(1 for e in r.alarm_episodes if bed_of(e["key"]) == b)
            print(f"  {b}: {s['samples']} samples, {s['alarm_samples']} alarm samples in {n_ep} "
                  f"episode(s), {_missing(s['missing'])}")
        if out:
            print(f"wrote {out}")
    return summary


def _missing(counts: dict[str, int]) -> str:
    """The missing samples per channel in words: "missing nA 1, yB 3", or "none missing".

    >>> _missing({"nA": 1, "nB": 0, "yB": 3}), _missing({"nB": 0})
    ('missing nA 1, yB 3', 'none missing')
    """
    some = [f"{c} {n}" for c, n in sorted(counts.items()) if n]
    return f"missing {', '.join(some)}" if some else "none missing"


def run(args: argparse.Namespace) -> int:
    from node.mcap import open_recording

    if args.publish == bool(args.model):
        raise OrdervibError("give either --model (offline node) or --publish (to Zenoh)")
    with open_recording(args.recording):  # one line for a missing or non-MCAP file, before any output
        pass
    if args.model:
        if args.out:
            check_output(args.out, "--out", suffix=".mcap", inputs=[args.recording, args.model])
        replay_offline(args.recording, args.model, args.out, args.quiet, args.workers, args.engine_state,
                       result=True, as_json=args.json)
        return 0
    if args.out:
        raise OrdervibError("--out goes with --model (the node offline), not with --publish")
    if args.json:
        raise OrdervibError("--json goes with --model (the node offline's summary), not with --publish")
    if args.engine_state:
        raise OrdervibError("--engine-state goes with --model (the node offline), not with --publish")
    if not args.speed >= 0:
        raise OrdervibError("--speed must be >= 0")
    if not args.wait >= 0:
        raise OrdervibError("--wait must be >= 0")
    if args.max_gap is not None and not (args.max_gap > 0 and math.isfinite(args.max_gap)):
        raise OrdervibError("--max-gap must be a number of seconds > 0")
    from node.cli.logs import Progress
    from replay.publish import publish_recording
    bar = Progress("publish", log)
    publish_recording(args.recording, args.connect, args.speed, args.quiet,
                      wait_s=args.wait, config_file=args.zenoh_config, max_gap_s=args.max_gap,
                      progress=None if args.quiet else (lambda f, n: bar(f, n, "messages")))
    return 0
