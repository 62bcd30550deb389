"""``ordervib view``: a recording in Rerun (viewer, or a saved ``.rrd``).

The arrays come from ``replay.views.view_data.load_view_data`` and the Rerun calls from
``replay.views.rerun_view``. A sensor-only recording shows its OCs when a schedule is given
(``--schedule``, or ``REC.schedule.toml`` beside it): the node's own OC detector is run
over the speed. With the order's phase (the target's phase channel, e.g. ``yB_ph``) the view
adds the polar plot and the Bode pair; ``--plots DIR`` writes them as PNG files
(``DIR/<bed>-<target>-polar.png``, ``-bode.png``; ``replay.views.phase_plots``) and starts no viewer.
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import sys
import time
from typing import TYPE_CHECKING

from node.cli.outputs import check_output, replacing
from node.contract import OrdervibError, monitor_key, phase_channel, sensor_key
from node.mcap import warn_unfinished

if TYPE_CHECKING:
    from node.contract.schedule import Schedule
    from replay.views.live_view import LiveView
    from replay.views.view_data import Vectors, ViewData

log = logging.getLogger(__name__)

NAME = "view"
HELP = ("show a recording in the Rerun viewer, or save the Rerun file (--save OUT.rrd); "
        "polar and Bode PNG plots of the order's phase (--plots DIR)")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("recording", metavar="REC.mcap", nargs="?", default=None,
                   help="recording (sensor-only or a node's); or --connect")
    p.add_argument("--connect", metavar="ENDPOINT", default=None,
                   help="the live view: subscribe to a running node's topics and the test bed's sensors "
                   "at this Zenoh endpoint (e.g. tcp/127.0.0.1:7447) instead of reading a recording")
    p.add_argument("--zenoh-config", metavar="FILE.json5", default=None,
                   help="with --connect: Zenoh configuration file (e.g. TLS root CA; see docs/zenoh/)")
    p.add_argument("--duration", metavar="S", type=float, default=None,
                   help="with --connect: stop after S seconds (default: at Ctrl-C)")
    p.add_argument("--refresh", metavar="S", type=float, default=1.0,
                   help="with --connect: seconds between updates of the view (default 1)")
    p.add_argument("--save", metavar="OUT.rrd", default=None, help="write a Rerun file, start no viewer")
    p.add_argument(
        "--plots",
        metavar="DIR",
        default=None,
        help="write DIR/<bed>-<target>-polar.png and -bode.png (needs the target's phase channel), "
        "start no viewer",
    )
    p.add_argument("--slow-roll", metavar="LO,HI", default=None,
                   help="with --plots: subtract each run's mean 1x vector between LO and HI rpm of the "
                   "switch speed (the runout or bow at slow roll) in the Bode plot")
    p.add_argument("--tracker-s", type=float, metavar="S", default=0.0,
                   help="with --plots: the order tracker's lag undone when the Bode plot finds the "
                   "criticals (s; a model's is in its transients settings; default 0: not undone)")
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
    """--schedule, else REC.schedule.toml beside the recording when there is one (live: --schedule)."""
    from node.contract.schedule import load_schedule

    path = args.schedule
    if path is None:
        if args.recording is None:
            return None
        root, _ = os.path.splitext(args.recording)
        path = root + ".schedule.toml"
        if not os.path.isfile(path):
            return None
    return load_schedule(path)


def _check(args: argparse.Namespace) -> None:
    if (args.recording is None) == (args.connect is None):
        raise OrdervibError("give a recording REC.mcap or --connect ENDPOINT (one of them)")
    if args.connect is None:
        for opt in ("zenoh_config", "duration"):
            if getattr(args, opt) is not None:
                raise OrdervibError(f"--{opt.replace('_', '-')} needs --connect")
    else:
        if args.plots is not None:
            raise OrdervibError("--plots needs a recording, not --connect")
        if args.duration is not None and not args.duration > 0:
            raise OrdervibError(f"--duration must be positive, got {args.duration:g}")
        if not args.refresh > 0:
            raise OrdervibError(f"--refresh must be positive, got {args.refresh:g}")
    if args.save is not None:
        check_output(args.save, "--save", suffix=".rrd", inputs=[args.recording] if args.recording else [])
    if args.plots is not None and not os.path.isdir(args.plots):
        raise OrdervibError(f"--plots {args.plots} is not a directory")
    if args.tracker_s != 0.0:
        from node.models.transients import TRACKER_S_MAX

        if args.plots is None:
            raise OrdervibError("--tracker-s needs --plots")
        if not 0.0 <= args.tracker_s <= TRACKER_S_MAX:
            raise OrdervibError(f"--tracker-s must be in [0, {TRACKER_S_MAX:g}] s, got {args.tracker_s:g}")
    if args.slow_roll is not None:
        from replay.views.phase_plots import speed_band

        if args.plots is None:
            raise OrdervibError("--slow-roll needs --plots")
        try:
            args.slow_roll = speed_band(args.slow_roll)
        except ValueError as e:
            raise OrdervibError(f"--slow-roll: {e}") from None


def _png_paths(args: argparse.Namespace, data: ViewData) -> list[str]:
    """The polar and Bode PNG paths of --plots, checked (before anything is written)."""
    paths = [os.path.join(args.plots, f"{data.bed}-{data.target}-{kind}.png") for kind in ("polar", "bode")]
    for path in paths:
        check_output(path, "--plots", suffix=".png", inputs=[args.recording])
    return paths


def _write_plots(data: ViewData, vectors: Vectors, paths: list[str],
                 slow_roll: tuple[float, float] | None = None, tracker_s: float = 0.0) -> str:
    """The polar and Bode plots to paths, each replaced only by a complete file; the summary line."""
    import numpy as np

    from replay.views.phase_plots import bode_figure, polar_figure, save_png

    title = f"{data.bed} {data.target}: 1x vector"
    figures = (polar_figure(vectors, title, data.switch, data.target_unit),
               bode_figure(vectors, title, data.switch, data.target, data.target_unit, slow_roll, tracker_s))
    for fig, path in zip(figures, paths):
        with replacing(path) as part:
            save_png(fig, part)
        log.info("wrote %s", path)
    ok = np.isfinite(vectors.measured())
    return (f"plots: bed {data.bed}, {data.target} {int(ok.sum())} 1x vectors in "
            f"{len(np.unique(vectors.run[ok]))} runs{', with predicted' if vectors.has_predicted() else ''} "
            f"-> {', '.join(paths)}")


def _vectors(data: ViewData) -> Vectors:
    """The target's 1x vectors for --plots; one-line OrdervibError when the recording has no phase."""
    from replay.views.view_data import vectors_of

    vectors = vectors_of(data)
    if vectors is None:
        ph, bed = phase_channel(data.target), data.bed
        raise OrdervibError(f"--plots: no phase of {data.target} in the recording (no {ph} in "
                            f"{sensor_key(bed, ph)}, no measured_phase in {monitor_key(bed, data.target)})")
    return vectors


def _has_display() -> bool:
    """Whether a native viewer window could open (always assumed off Linux)."""
    if not sys.platform.startswith("linux"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


_NO_VIEWER = "cannot start the Rerun viewer ({why}); use --save OUT.rrd and open it with `rerun OUT.rrd`"


def _log(data: ViewData) -> dict[str, int]:
    """Log the view to the Rerun sink opened (saved file or viewer), then disconnect."""
    import rerun as rr

    from replay.views.rerun_view import log_view

    try:
        return log_view(data)
    finally:
        rr.disconnect()


def _live(args: argparse.Namespace) -> tuple[LiveView, dict[str, int]]:
    """--connect: stream the topics to Rerun until --duration or Ctrl-C; the view and its counts."""
    import rerun as rr

    from node.contract import MONITOR_SUBSCRIPTION, SENSOR_SUBSCRIPTION
    from node.edges.zenoh import open_session, zenoh_config
    from replay.views.live_view import LiveView

    view = LiveView(args.bed, args.target, args.switch, _schedule_for(args))
    session = open_session(zenoh_config(None, [args.connect], args.zenoh_config))
    counts: dict[str, int] = {}
    try:
        def on_sample(sample) -> None:  # noqa: ANN001 - a zenoh.Sample
            view.add(str(sample.key_expr), sample.payload.to_bytes())

        subs = [session.declare_subscriber(k, on_sample) for k in (SENSOR_SUBSCRIPTION, MONITOR_SUBSCRIPTION)]
        log.info("live view: subscribed at %s (%s)", args.connect,
                 f"{args.duration:g} s" if args.duration else "Ctrl-C to stop")
        end = math.inf if args.duration is None else time.monotonic() + args.duration
        try:
            while time.monotonic() < end:
                time.sleep(min(args.refresh, max(0.0, end - time.monotonic())))
                _add_counts(counts, view.refresh())
        except KeyboardInterrupt:
            pass
        _add_counts(counts, view.refresh(final=True))
        for sub in subs:
            sub.undeclare()
    finally:
        session.close()
        rr.disconnect()
    if view.data is None:
        raise OrdervibError(f"nothing to show: {view.received} message(s) received at {args.connect}, "
                            f"no speed of a test bed among them")
    return view, counts


def _run_live(args: argparse.Namespace) -> int:
    """--connect into the viewer, or into --save (replaced only by a complete file)."""
    import rerun as rr

    if args.save is None and not _has_display():
        raise OrdervibError(_NO_VIEWER.format(why="no display"))
    rr.init("ordervib_view", spawn=False)
    if args.save is not None:
        with replacing(args.save) as part:
            rr.save(part)
            view, counts = _live(args)
    else:
        try:
            rr.spawn()
        except Exception as exc:  # viewer binary missing or unable to start
            raise OrdervibError(_NO_VIEWER.format(why=str(exc).splitlines()[0])) from None
        view, counts = _live(args)
    if not args.quiet and view.data is not None:
        where = f"-> {args.save} ({os.path.getsize(args.save)} bytes)" if args.save else "-> viewer"
        print(f"view: live from {args.connect}, {view.received} messages; bed {view.data.bed}, "
              f"{view.data.switch} {counts.get('speed', 0)} samples, monitor {counts.get('monitor', 0)} "
              f"({counts.get('alarm', 0)} alarm) of {view.data.target}, OCs from {view.source} {where}")
    return 0


_SUMMED = ("speed", "monitor", "alarm", "health", "measured")  # log_series's counts: per stretch


def _add_counts(counts: dict[str, int], new: dict[str, int] | None) -> None:
    """A refresh's counts into the totals: the time series' samples add up, the 2-D views'
    are of everything received (the last refresh's)."""
    for k, v in (new or {}).items():
        counts[k] = counts.get(k, 0) + v if k in _SUMMED else v


def run(args: argparse.Namespace) -> int:
    from replay.views.view_data import load_view_data

    _check(args)
    if args.connect is not None:
        return _run_live(args)
    start = time.perf_counter()
    data, source, stats = load_view_data(args.recording, args.bed, args.target, args.switch,
                                         _schedule_for(args))
    if stats.truncated:
        warn_unfinished(log, args.recording, f"{stats.messages} messages")
    if args.plots is not None:
        vectors = _vectors(data)
        paths = _png_paths(args, data)
        line = _write_plots(data, vectors, paths, args.slow_roll, args.tracker_s)
        if not args.quiet:
            print(line)
        if args.save is None:
            return 0
    if args.save is None and not _has_display():
        raise OrdervibError(_NO_VIEWER.format(why="no display"))

    import rerun as rr

    from replay.views.rerun_view import blueprint

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
        vec = f"{counts['vectors']} 1x vectors, " if "vectors" in counts else ""
        print(
            f"view: bed {data.bed}, {data.switch} {counts.get('speed', 0)} samples, "
            f"{data.target} {counts.get('curve', 0)} curve points in {counts.get('runs', 0)} runs, "
            f"{vec}"
            f"monitor {counts.get('monitor', 0)} ({counts.get('alarm', 0)} alarm), "
            f"OCs from {source}{extra} {where} in {time.perf_counter() - start:.2f} s"
        )
    return 0
