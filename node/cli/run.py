"""``ordervib run``: the live node."""

from __future__ import annotations

import argparse
import glob
from pathlib import Path

from node.cli.outputs import check_new_files, check_output
from node.contract.errors import OrdervibError
from node.runtime.clock import ClockPolicy

NAME = "run"
HELP = "the live node: subscribe to test beds over Zenoh, predict, publish, record to MCAP"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--model", required=True, metavar="MODEL", help="model bundle directory")
    p.add_argument("--record", required=True, metavar="OUT.mcap",
                   help="recording to write; with --rotate-mb/--rotate-minutes, successive files "
                        "OUT.0000.mcap, OUT.0001.mcap, ... each a complete recording")
    p.add_argument("--rotate-mb", type=float, metavar="N",
                   help="start the next file once the current one holds N MB (10**6 bytes)")
    p.add_argument("--rotate-minutes", type=float, metavar="M",
                   help="start the next file once the current one spans M minutes of receive time")
    p.add_argument("--listen", action="append", metavar="ENDPOINT",
                   help="Zenoh endpoint to listen on (repeatable); the default tcp/127.0.0.1:7447 "
                        "applies only when neither --listen, --connect nor the --zenoh-config file "
                        "gives endpoints")
    p.add_argument("--connect", action="append", metavar="ENDPOINT",
                   help="Zenoh endpoint to connect to (repeatable)")
    p.add_argument("--zenoh-config", metavar="FILE.json5",
                   help="Zenoh configuration file (TLS, access control; see docs/zenoh/); "
                        "--listen replaces its listen endpoints, --connect its connect endpoints")
    p.add_argument("--engine-state", metavar="FILE.json",
                   help="each bed's engine history (last run end, energy, thermal state), loaded at "
                        "start and kept up to date (default: engine-state.json beside --record)")
    p.add_argument("--beds", default="*", metavar="PATTERN",
                   help="serve only the test beds matching PATTERN: a bed name, * (every bed, the "
                        "default) or a name with Zenoh's $* (east$*: the beds whose names start with "
                        "east); several nodes with disjoint patterns share a fleet (docs/deployment.md)")
    p.add_argument("--max-beds", type=int, default=None, metavar="N",
                   help="track N beds at once at most (default 256): a new bed beyond them is "
                        "refused and counted (node health refused.bed_limit) until one expires")
    p.add_argument("--max-channels", type=int, default=None, metavar="N",
                   help="channels per bed at most, the model's among them (default 64): a further "
                        "channel is refused and counted (health refused.channel_limit), not recorded")
    p.add_argument("--bed-expiry", type=float, default=None, metavar="S",
                   help="free a bed's state after S seconds without a message from it (default 300); "
                        "its last health message says expired, a new message admits it afresh")
    p.add_argument("--health-silence", type=float, default=None, metavar="S",
                   help="a bed silent for S seconds (receive time) leaves the health rotation until it "
                        "sends again; counted in the node's health as silent (default 30, at most 3600). "
                        "The beds' health goes out 100 a second at most: each bed's once a second up "
                        "to 100 beds, every ceil(beds / 100) s beyond")
    p.add_argument("--clock-jump", type=float, default=None, metavar="S",
                   help="a sample further than S seconds from its bed's clock is held apart until the "
                        "bed's other channels confirm the jump, else counted as a clock fault (default "
                        "1; inf: no guard); docs/clock.md")
    p.add_argument("--clock-hold", type=float, default=None, metavar="S",
                   help="bed time a held-apart clock waits for confirmation before its samples are "
                        "dropped as clock faults (default 2, above 1)")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S seconds")
    p.add_argument("--force", action="store_true",
                   help="overwrite an existing recording (or rotated files of that name); without it "
                        "an existing file is refused, and the file is created only once the Zenoh "
                        "session is up")
    p.add_argument("--quiet", action="store_true")


def run(args: argparse.Namespace) -> int:
    from node.contract import sensor_subscription
    from node.edges.engine_file import check_engine_file
    from node.edges.zenoh import DEFAULT_ENDPOINT, config_file_endpoints, zenoh_config
    from node.live.health_rate import HEALTH_SILENCE_MAX_S
    from node.live.node import run_node
    from node.mcap import RecordingWriter, RotatingRecorder
    from node.models.bundle import load_model

    try:
        sensor_subscription(args.beds)
    except ValueError as exc:
        raise OrdervibError(f"--beds: {exc}") from None
    rotating = args.rotate_mb is not None or args.rotate_minutes is not None
    inputs = [args.zenoh_config] if args.zenoh_config else []
    # written in place (a killed node's file stays recoverable): an existing one needs --force
    check_output(args.record, "--record", inputs=inputs, replace=rotating, force=args.force)
    if rotating:  # node.mcap -> node.0000.mcap, node.0001.mcap, ...
        stem = args.record.removesuffix(".mcap")
        check_new_files([glob.escape(stem) + ".[0-9][0-9][0-9][0-9]*.mcap"], "--record", args.force)
    if args.duration is not None and not args.duration > 0:
        raise OrdervibError("--duration must be > 0")
    for option, value in (("--max-beds", args.max_beds), ("--max-channels", args.max_channels)):
        if value is not None and value < 1:
            raise OrdervibError(f"{option} must be >= 1, got {value}")
    if args.bed_expiry is not None and not args.bed_expiry > 0:  # NaN too
        raise OrdervibError(f"--bed-expiry must be > 0, got {args.bed_expiry}")
    if args.health_silence is not None and not 0 < args.health_silence <= HEALTH_SILENCE_MAX_S:  # NaN too
        raise OrdervibError(f"--health-silence must be > 0 and <= {HEALTH_SILENCE_MAX_S:g}, "
                            f"got {args.health_silence}")
    given = (("max_beds", args.max_beds), ("max_channels", args.max_channels),
             ("bed_expiry_s", args.bed_expiry), ("health_silence_s", args.health_silence))
    limits = {name: value for name, value in given if value is not None}
    clock = clock_policy(args.clock_jump, args.clock_hold)
    listen = args.listen
    if not (listen or args.connect or config_file_endpoints(args.zenoh_config)):
        listen = [DEFAULT_ENDPOINT]
    zenoh_config(listen, args.connect, args.zenoh_config)  # a bad endpoint stops here, before the model
    bundle = load_model(args.model)
    engine_file = args.engine_state or str(Path(args.record).parent / "engine-state.json")
    check_engine_file(engine_file)  # a malformed one stops here, before any output is opened
    # the file is created at the first flush, after the session is up: a failed start leaves
    # no file, and an existing one is only ever opened with --force
    record: RecordingWriter | RotatingRecorder
    if rotating:
        record = RotatingRecorder(args.record, max_mb=args.rotate_mb, max_minutes=args.rotate_minutes,
                                  deferred=True, exclusive=not args.force)
    else:
        record = RecordingWriter(args.record, deferred=True, exclusive=not args.force)
    s = run_node(bundle, record, listen, args.connect, args.zenoh_config, args.duration, engine_file,
                 args.beds, clock=clock, **limits)
    print(f"stopped: {s.received} received, {s.published} published, {s.overflow} dropped; "
          f"{args.record} finished")  # the result, on stdout
    return 0


def clock_policy(jump: float | None, hold: float | None) -> ClockPolicy:
    """The clock guard ``--clock-jump`` and ``--clock-hold`` ask for (the others: the defaults);
    a value ``ClockPolicy`` refuses is one line naming the option."""
    try:
        default = ClockPolicy()
        return ClockPolicy(max_jump_s=default.max_jump_s if jump is None else jump,
                           hold_s=default.hold_s if hold is None else hold)
    except ValueError as exc:
        option = "--clock-jump" if str(exc).startswith("max_jump_s") else "--clock-hold"
        raise OrdervibError(f"{option}: {exc}") from None
