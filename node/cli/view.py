"""``ordervib view``: a recording in Rerun (viewer, or a saved ``.rrd``).

The arrays come from ``replay.view_data.load_view_data`` and the Rerun calls from
``replay.rerun_view``. A sensor-only recording shows its OCs when a schedule is given
(``--schedule``, or ``REC.schedule.toml`` beside it): the node's own OC detector is run
over the speed.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import time
from typing import TYPE_CHECKING

from node.cli.outputs import check_output, replacing, warn_unfinished
from node.contract import OrdervibError

if TYPE_CHECKING:
    from node.contract.schedule import Schedule
    from replay.view_data import ViewData

log = logging.getLogger(__name__)

NAME = "view"
HELP = "show a recording in the Rerun viewer, or save the Rerun file (--save OUT.rrd)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("recording", metavar="REC.mcap", help="recording (sensor-only or a node's)")
    p.add_argument("--save", metavar="OUT.rrd", default=None, help="write a Rerun file, start no viewer")
    p.add_argument("--bed", metavar="NAME", default=None, help="test bed (default: the only one)")
    p.add_argument(
        "--target",
        metavar="CH",
        default=None,
        help="modelled channel (default: the monitored one, else yB)",
    )
    p.add_argument(
        "--switch", metavar="CH", default=None, help="speed channel (default: schedule's, else nB)"
    )
    p.add_argument(
        "--schedule",
        metavar="S.toml",
        default=None,
        help="derive OCs of a sensor-only recording (default: REC.schedule.toml if present)",
    )
    p.add_argument("--quiet", action="store_true", help="no summary line")


def _schedule_for(args: argparse.Namespace) -> Schedule | None:
    """--schedule, else REC.schedule.toml beside the recording when there is one."""
    from node.contract.schedule import load_schedule

    path = args.schedule
    if path is None:
        root, _ = os.path.splitext(args.recording)
        path = root + ".schedule.toml"
        if not os.path.isfile(path):
            return None
    return load_schedule(path)


def _check(args: argparse.Namespace) -> None:
    if args.save is None:
        return
    check_output(args.save, "--save", suffix=".rrd", inputs=[args.recording])


def _has_display() -> bool:
    """Whether a native viewer window could open (always assumed off Linux)."""
    if not sys.platform.startswith("linux"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


_NO_VIEWER = "cannot start the Rerun viewer ({why}); use --save OUT.rrd and open it with `rerun OUT.rrd`"


def _log(data: ViewData) -> dict[str, int]:
    """Log the view to the Rerun sink opened (saved file or viewer), then disconnect."""
    import rerun as rr

    from replay.rerun_view import log_view

    try:
        return log_view(data)
    finally:
        rr.disconnect()


def run(args: argparse.Namespace) -> int:
    from replay.view_data import load_view_data

    _check(args)
    start = time.perf_counter()
    data, source, stats = load_view_data(args.recording, args.bed, args.target, args.switch,
                                         _schedule_for(args))
    if stats.truncated:
        warn_unfinished(log, args.recording, f"{stats.messages} messages")
    if args.save is None and not _has_display():
        raise OrdervibError(_NO_VIEWER.format(why="no display"))

    import rerun as rr

    from replay.rerun_view import blueprint

    bp = blueprint(data)
    rr.init("ordervib_view", spawn=False)
    if args.save is not None:
        with replacing(args.save) as part:  # an existing file is replaced only by a complete one
            rr.save(part, default_blueprint=bp)
            counts = _log(data)
    else:
        try:
            rr.spawn(default_blueprint=bp)
        except Exception as exc:  # viewer binary missing or unable to start
            raise OrdervibError(_NO_VIEWER.format(why=str(exc).splitlines()[0])) from None
        counts = _log(data)
    if not args.quiet:
        where = f"-> {args.save} ({os.path.getsize(args.save)} bytes)" if args.save else "-> viewer"
        extra = " (unfinished file)" if stats.truncated else ""
        print(
            f"view: bed {data.bed}, {data.switch} {counts.get('speed', 0)} samples, "
            f"{data.target} {counts.get('curve', 0)} curve points in {counts.get('runs', 0)} runs, "
            f"monitor {counts.get('monitor', 0)} ({counts.get('alarm', 0)} alarm), "
            f"OCs from {source}{extra} {where} in {time.perf_counter() - start:.2f} s"
        )
    return 0
