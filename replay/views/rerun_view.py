"""Rerun views of a recording: pure functions from time-major arrays to Rerun calls.

Entity layout (every scalar is sent in bulk with ``rr.send_columns``):

- ``/speed/<switch>``: the switch speed (rpm) over time;
- ``/state/oc``, ``/state/phase``, ``/state/flag``: lanes of a state-timeline view
  (OC intervals as bands; an empty state outside any OC);
- ``/target/{measured,predicted,upper,lower,alarm}``: the target against its
  prediction and the alarm band predicted ± band (same unit as the target);
- ``/residual/{residual,upper,lower,alarm}``: residual and ± band;
  ``/score/{score,alarm}``: the smoothed standardized residual; the flag lane
  names the rule behind an alarm ("alarm (step)");
- ``/health/*``: the node's health messages (lag, late, dropped);
- ``/curve/**``: the characteristic curve (target against speed), a static 2-D
  point cloud, one entity per run, hue by run and shade by time in the run;
- with the order's phase (the target's phase channel, or ``measured_phase`` in the
  monitor messages): ``/polar/**``, the 1x vector over the recording as static 2-D points
  (x = Re, y = Im up: radius the amplitude, angle the phase lag clockwise from 0 degrees at
  the right), measured coloured by speed, predicted (``predicted_phase``) in orange, one
  entity per run; ``/bode/{amplitude,phase}/**``, the Bode pair against speed (phase
  wrapped to [-180, 180), points); ``/residual/vector``: the node's vector residual;
- ``/log/oc``: the OC switches as text.

Two timelines: ``time`` (timestamp, the recording's clock) and ``engine_time``
(duration, s: the same with every gap of ``RUN_GAP`` or more between runs
shortened to ``GAP_SHOWN`` so several runs fit one plot). The blueprint opens on
``engine_time``.
"""

from __future__ import annotations

import colorsys
from collections.abc import Sequence

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from node.contract import RUN_GAP, Flag
from replay.views.view_data import Health, OcSwitches, Vectors, ViewData, speed_at, vectors_of

GAP_SHOWN = 10.0  # s: what a gap between runs shrinks to on engine_time
ALARM_RED = (230, 40, 40)
COLORS = {
    "speed": (70, 130, 230),
    "measured": (40, 110, 220),
    "predicted": (240, 150, 30),
    "band": (150, 150, 150),
    "residual": (60, 160, 90),
    "score": (140, 80, 200),
    "vector": (20, 170, 170),
}
# viridis at 0, 1/4, 1/2, 3/4, 1: the speed colour map (the PNG plots use matplotlib's viridis)
SPEED_MAP = np.array([[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]], dtype=float)


# ----------------------------------------------------------------------------- time


class Clock:
    """Maps epoch seconds to ``engine_time``: gaps >= RUN_GAP between samples shortened.

    Built from the sorted sample times (K,) of the speed channel.
    """

    def __init__(self, t: np.ndarray) -> None:
        t = np.asarray(t, dtype=float)
        self.t0 = float(t[0]) if len(t) else 0.0
        gaps = np.flatnonzero(np.diff(t) >= RUN_GAP)
        self.gap_ends = t[gaps + 1] if len(t) else np.empty(0)
        cut = (t[gaps + 1] - t[gaps] - GAP_SHOWN) if len(t) else np.empty(0)
        self.shift = np.concatenate([[0.0], np.cumsum(cut)])

    def __call__(self, t: np.ndarray) -> np.ndarray:
        """engine_time (s) of epoch times t (N,)."""
        t = np.asarray(t, dtype=float)
        k = np.searchsorted(self.gap_ends, t, side="right")
        return t - self.t0 - self.shift[k]

    def run_index(self, t: np.ndarray) -> np.ndarray:
        """Run number (0-based) of each time t (N,): how many run gaps precede it."""
        return np.searchsorted(self.gap_ends, np.asarray(t, dtype=float), side="right")


def time_columns(t: np.ndarray, clock: Clock) -> list[rr.TimeColumn]:
    """Index columns for epoch times t (N,): ``time`` (timestamp) and ``engine_time`` (duration)."""
    t = np.asarray(t, dtype=float)
    return [
        rr.TimeColumn("engine_time", duration=clock(t)),
        rr.TimeColumn("time", timestamp=t),
    ]


# ----------------------------------------------------------------------------- logging


def log_style(path: str, name: str, color: Sequence[int], width: float = 1.0) -> None:
    """Static line style of a series entity."""
    rr.log(path, rr.SeriesLines(colors=[color], names=[name], widths=[width]), static=True)


def log_scalars(path: str, t: np.ndarray, v: np.ndarray, clock: Clock) -> int:
    """Send one scalar series (t, v of shape (N,)); non-finite samples are skipped.

    Returns the number of samples sent.
    """
    ok = np.isfinite(v) & np.isfinite(t)
    if not ok.any():
        return 0
    rr.send_columns(
        path,
        indexes=time_columns(t[ok], clock),
        columns=rr.Scalars.columns(scalars=np.asarray(v, dtype=float)[ok]),
    )
    return int(ok.sum())


def log_points(path: str, name: str, t: np.ndarray, v: np.ndarray, clock: Clock) -> int:
    """Red cross markers at (t, v) (N,), e.g. the alarm samples. Returns how many."""
    rr.log(
        path,
        rr.SeriesPoints(colors=[ALARM_RED], markers=["cross"], names=[name], marker_sizes=[3.0]),
        static=True,
    )
    return log_scalars(path, t, v, clock)


def log_states(path: str, t: np.ndarray, states: np.ndarray, clock: Clock) -> int:
    """A state-timeline lane from per-sample states (N,) str: only the changes are sent.

    An empty string is a gap (no state). Returns the number of changes.
    """
    states = np.asarray(states, dtype=str)
    if not len(states):
        return 0
    change = np.concatenate([[True], states[1:] != states[:-1]])
    rr.send_columns(
        path,
        indexes=time_columns(np.asarray(t, dtype=float)[change], clock),
        columns=rr.StateChange.columns(state=states[change].tolist()),
    )
    return int(change.sum())


def log_switch_text(path: str, sw: OcSwitches, clock: Clock) -> None:
    """The OC switches as text-log lines ("OC3 steady")."""
    if not len(sw.t):
        return
    text = [f"{oc or '(none)'} {ph}" for oc, ph in zip(sw.oc, sw.phase)]
    rr.send_columns(path, indexes=time_columns(sw.t, clock), columns=rr.TextLog.columns(text=text))


def log_band(prefix: str, t: np.ndarray, centre: np.ndarray, band: np.ndarray, clock: Clock) -> None:
    """Upper and lower band lines centre ± band (N,) as ``<prefix>/upper`` and ``<prefix>/lower``."""
    for side, sign in (("upper", 1.0), ("lower", -1.0)):
        log_style(f"{prefix}/{side}", f"{side} band", COLORS["band"], 0.75)
        log_scalars(f"{prefix}/{side}", t, centre + sign * band, clock)


def log_monitor(data: ViewData, clock: Clock) -> None:
    """Target against prediction with band; residual with ± band; score; alarms marked."""
    m = data.monitor
    assert m is not None
    alarm = m.flag == Flag.ALARM.value
    measured = m.measured
    log_style("target/measured", f"{data.target} measured", COLORS["measured"])
    if not np.isfinite(measured).any() and data.measured is not None:  # fall back on the sensor
        log_scalars("target/measured", data.measured.t, data.measured.v, clock)
    else:
        log_scalars("target/measured", m.t, measured, clock)
    log_style("target/predicted", f"{data.target} predicted", COLORS["predicted"])
    log_scalars("target/predicted", m.t, m.predicted, clock)
    log_band("target", m.t, m.predicted, m.band, clock)
    log_points("target/alarm", "alarm", m.t[alarm], measured[alarm], clock)

    log_style("residual/residual", "residual", COLORS["residual"])
    log_scalars("residual/residual", m.t, m.residual, clock)
    log_band("residual", m.t, np.zeros_like(m.band), m.band, clock)
    if np.isfinite(m.vector_residual).any():
        log_style("residual/vector", "vector residual |measured - predicted 1x|", COLORS["vector"])
        log_scalars("residual/vector", m.t, m.vector_residual, clock)
    log_points("residual/alarm", "alarm", m.t[alarm], m.residual[alarm], clock)

    if np.isfinite(m.score).any():
        log_style("score/score", "score (standardized)", COLORS["score"])
        log_scalars("score/score", m.t, m.score, clock)
        log_points("score/alarm", "alarm", m.t[alarm], m.score[alarm], clock)
    log_states("state/flag", m.t, m.flag_labels(), clock)


def log_health(h: Health, clock: Clock) -> None:
    """The node's health: lag percentiles (ms) and counters."""
    for name, v, color in (
        ("lag_ms_p50", h.lag_p50, (70, 130, 230)),
        ("lag_ms_p99", h.lag_p99, (230, 120, 40)),
        ("late", h.late, (150, 150, 150)),
        ("missing", h.missing, (200, 60, 160)),
        ("dropped", h.dropped, ALARM_RED),
        ("malformed", h.malformed, (120, 80, 40)),
    ):
        log_style(f"health/{name}", name, color)
        log_scalars(f"health/{name}", h.t, v, clock)


# ----------------------------------------------------------------------------- curve


def nice_step(span: float, ticks: int = 5) -> float:
    """A 1-2-5 step giving about ``ticks`` intervals over span (> 0)."""
    raw = max(span, 1e-12) / ticks
    mag = 10.0 ** np.floor(np.log10(raw))
    for m in (1.0, 2.0, 5.0, 10.0):
        if raw <= m * mag:
            return float(m * mag)
    return float(10 * mag)


def run_colors(run: np.ndarray, t: np.ndarray) -> np.ndarray:
    """RGB (N, 3) uint8: a hue per run (N,), darker later in the run (by time t (N,))."""
    out = np.empty((len(run), 3), dtype=np.uint8)
    for r in np.unique(run):
        sel = run == r
        tt = t[sel]
        frac = (tt - tt.min()) / max(float(np.ptp(tt)), 1e-9)
        hue = (0.58 + 0.38 * float(r)) % 1.0  # golden-ish hue spacing
        light = 0.72 - 0.4 * frac
        rgb = np.array([colorsys.hls_to_rgb(hue, li, 0.75) for li in light])
        out[sel] = np.clip(np.rint(rgb * 255), 0, 255).astype(np.uint8)
    return out


def speed_colors(speed: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """RGB (N, 3) uint8 of speeds (N,) on the viridis map from lo to hi (rpm).

    >>> speed_colors(np.array([0.0, 50.0, 100.0]), 0.0, 100.0).tolist()
    [[68, 1, 84], [33, 145, 140], [253, 231, 37]]
    """
    frac = np.clip((np.asarray(speed, dtype=float) - lo) / max(hi - lo, 1e-9), 0.0, 1.0)
    grid = np.linspace(0.0, 1.0, len(SPEED_MAP))
    rgb = np.column_stack([np.interp(frac, grid, SPEED_MAP[:, c]) for c in range(3)])
    return np.rint(rgb).astype(np.uint8)


def curve_scale(speed_max: float, y_max: float) -> tuple[float, float]:
    """Plot units per rpm and per target unit, so the cloud is about 10 x 6 (y up is negative)."""
    return 10.0 / max(speed_max, 1e-9), 6.0 / max(y_max, 1e-9)


def log_curve(
    speed: np.ndarray,
    y: np.ndarray,
    t: np.ndarray,
    run: np.ndarray,
    switch: str,
    target: str,
    unit: str,
    alarm: np.ndarray | None = None,
) -> tuple[float, float]:
    """The characteristic curve: target y (N,) against speed (N,) as static 2-D points.

    One entity per run (``/curve/run<k>``), coloured by run and time; alarm (N,)
    bool marks samples in red. Axes with ticks are drawn as line strips and
    labels. Returns the plot extent (width, height) in plot units.
    """
    ok = np.isfinite(speed) & np.isfinite(y)
    speed, y, t, run = speed[ok], y[ok], t[ok], run[ok]
    if not len(speed):
        return 0.0, 0.0
    xmax = float(np.max(speed)) * 1.05
    ymax = max(float(np.max(y)) * 1.1, 1e-6)
    sx, sy = curve_scale(xmax, ymax)
    pos = np.column_stack([speed * sx, -y * sy])
    log_runs("curve", pos, run_colors(run, t), run)
    if alarm is not None and alarm[ok].any():
        a = alarm[ok]
        rr.log(
            "curve/alarm",
            rr.Points2D(pos[a], colors=[ALARM_RED], radii=rr.Radius.ui_points(2.5), draw_order=40.0),
            static=True,
        )
    log_axes("curve/axes", xmax, (0.0, ymax), sx, sy, switch, f"{target} ({unit})")
    return xmax * sx, ymax * sy


def log_runs(path: str, pos: np.ndarray, colors: np.ndarray | Sequence[int], run: np.ndarray,
             radius: float = 1.5) -> None:
    """Static 2-D points pos (N, 2), one entity per run (N,) as ``<path>/run<k>`` (k from 1).

    colors: (N, 3) uint8, or one RGB for all; radius in UI points; non-finite points are left out.
    """
    colors = np.broadcast_to(np.asarray(colors, dtype=np.uint8), (len(pos), 3))
    ok = np.isfinite(pos).all(axis=1)
    for r in np.unique(run[ok]):
        sel = ok & (run == r)
        rr.log(
            f"{path}/run{int(r) + 1}",
            rr.Points2D(pos[sel], colors=colors[sel], radii=rr.Radius.ui_points(radius)),
            static=True,
        )


GREY = (170, 170, 170)


def log_lines_and_labels(path: str, strips: list, pts: list, labels: list[str]) -> None:
    """Grey line strips and text labels of a plot's frame (``<path>/lines``, ``<path>/labels``)."""
    rr.log(
        f"{path}/lines",
        rr.LineStrips2D(strips, colors=[GREY], radii=rr.Radius.ui_points(1.0)),
        static=True,
    )
    rr.log(
        f"{path}/labels",
        rr.Points2D(pts, labels=labels, colors=[GREY], radii=rr.Radius.ui_points(0.1), show_labels=True),
        static=True,
    )


def log_axes(path: str, xmax: float, ylim: tuple[float, float], sx: float, sy: float, xname: str,
             yname: str, ystep: float | None = None) -> None:
    """Axes, tick marks and tick labels of a plot of x in [0, xmax] (rpm) against y in ylim.

    Plot units: x = rpm*sx, y = -value*sy; the x axis at y = ylim[0]; ticks every 1-2-5 step
    (on y every ystep when given).
    """
    ymin, ymax = ylim
    y0 = 0.0 - ymin * sy  # the x axis
    strips = [[[0.0, y0], [xmax * sx, y0]], [[0.0, y0], [0.0, -ymax * sy]]]
    pts, labels = [], []
    dx, dy = nice_step(xmax), ystep or nice_step(ymax - ymin)
    for v in np.arange(0.0, xmax + 1e-9, dx):
        strips.append([[v * sx, y0], [v * sx, y0 + 0.12]])
        pts.append([v * sx, y0 + 0.35])
        labels.append(f"{v:g}")
    for v in np.arange(ymin, ymax + 1e-9, dy):
        strips.append([[0.0, -v * sy], [-0.12, -v * sy]])
        pts.append([-0.45, -v * sy])
        labels.append(f"{v:g}")
    pts += [[xmax * sx / 2, y0 + 0.8], [0.0, -ymax * sy - 0.35]]
    labels += [f"{xname} (rpm)", yname]
    log_lines_and_labels(path, strips, pts, labels)


# ----------------------------------------------------------------------------- the order's vector


POLAR_SIZE = 5.0  # plot units: the outer grid circle's radius


def polar_grid(rmax: float) -> tuple[float, float]:
    """(step, outer radius) of the polar grid circles for vectors up to rmax (target unit)."""
    step = nice_step(max(rmax, 1e-6), 4)
    return step, step * max(np.ceil(rmax / step - 1e-9), 1.0)


def polar_points(z: np.ndarray, s: float) -> np.ndarray:
    """Plot positions (N, 2) of vectors z (N,) complex at s plot units per target unit: x = Re, y = -Im
    (Rerun's y points down, so Im is up and a lag turns clockwise)."""
    return np.column_stack([z.real, -z.imag]) * s


def log_polar(v: Vectors, switch: str, unit: str) -> int:
    """The 1x vector as static 2-D points: x = Re, y = Im (up), per run; grid, axes and speed key.

    Measured coloured by speed (viridis from the lowest to the highest speed), predicted in
    orange. Returns the number of measured vectors drawn.
    """
    meas, pred = v.measured(), v.predicted()
    both = np.concatenate([meas, pred])
    step, rmax = polar_grid(float(np.nanmax(np.abs(both))) * 1.05)
    s = POLAR_SIZE / rmax
    lo, hi = v.speed_range()
    log_runs("polar/measured", polar_points(meas, s), speed_colors(v.speed, lo, hi), v.run)
    if v.has_predicted():
        log_runs("polar/predicted", polar_points(pred, s), COLORS["predicted"], v.run, 1.0)
    circle = np.exp(1j * np.linspace(0.0, 2 * np.pi, 97))
    R, rings = rmax * s, np.arange(step, rmax + 1e-9, step)
    strips: list = [[[-R, 0.0], [R, 0.0]], [[0.0, -R], [0.0, R]]]
    strips += [polar_points(circle * r, s) for r in rings]
    pts = [[r * s + 0.1, 0.3] for r in rings]
    labels = [f"{r:g}" for r in rings]
    pts += [[R + 0.6, 0.0], [0.0, R + 0.5], [-R - 0.8, 0.0], [0.0, -R - 0.5], [0.0, -R - 1.1]]
    labels += ["0°", "90° lag", "±180°", "-90°", f"1x vector ({unit}), lag clockwise"]
    log_lines_and_labels("polar/axes", strips, pts, labels)
    key = np.linspace(lo, hi, 5)
    rr.log(
        "polar/axes/speed",
        rr.Points2D(np.column_stack([np.full(5, R + 2.0), np.linspace(R, -R, 5)]),
                    colors=speed_colors(key, lo, hi), labels=[f"{switch} {k:.0f} rpm" for k in key],
                    radii=rr.Radius.ui_points(5.0), show_labels=True),
        static=True,
    )
    return int(np.isfinite(meas).sum())


def log_bode(v: Vectors, switch: str, target: str, unit: str) -> None:
    """The Bode pair: amplitude and phase (wrapped, degrees) against speed, static 2-D points.

    ``/bode/amplitude`` and ``/bode/phase``, each with ``measured/run<k>`` coloured by run
    and time (as the curve) and ``predicted/run<k>`` in orange.
    """
    xmax = float(np.nanmax(v.speed)) * 1.05
    amax = max(float(np.nanmax(np.concatenate([v.amplitude, v.predicted_amplitude]))) * 1.1, 1e-6)
    colors = run_colors(v.run, v.t)
    for name, ylim, y, yp, yname, ystep in (
        ("amplitude", (0.0, amax), v.amplitude, v.predicted_amplitude, f"{target} ({unit})", None),
        ("phase", (-180.0, 180.0), v.phase, v.predicted_phase, f"{target} phase lag (°)", 90.0),
    ):
        sx, sy = curve_scale(xmax, ylim[1] - ylim[0])
        log_runs(f"bode/{name}/measured", np.column_stack([v.speed * sx, -y * sy]), colors, v.run)
        if v.has_predicted():
            log_runs(f"bode/{name}/predicted", np.column_stack([v.speed * sx, -yp * sy]), COLORS["predicted"],
                     v.run, 1.0)
        log_axes(f"bode/{name}/axes", xmax, ylim, sx, sy, switch, yname, ystep)


# ----------------------------------------------------------------------------- the whole view


def curve_arrays(data: ViewData, clock: Clock) -> tuple[np.ndarray, ...]:
    """(speed, y, t, run, alarm), each (N,), for the characteristic curve.

    From the monitor messages when present (their measured value and flag), else
    from the target's sensor stream; the speed is interpolated at those times
    (linear, holding over dropouts).
    """
    if data.monitor is not None and np.isfinite(data.monitor.measured).any():
        t, y = data.monitor.t, data.monitor.measured
        alarm = data.monitor.flag == Flag.ALARM.value
    elif data.measured is not None:
        t, y = data.measured.t, data.measured.v
        alarm = np.zeros(len(t), dtype=bool)
    else:
        e = np.empty(0)
        return e, e, e, e.astype(np.int64), e.astype(bool)
    return speed_at(data.speed, t), y, t, clock.run_index(t), alarm


def log_view(data: ViewData) -> dict[str, int]:
    """Log every entity of the view into the current recording. Returns sample counts."""
    clock = Clock(data.speed.t)
    return {**log_series(data, clock), **log_plots(data, clock)}


def log_series(data: ViewData, clock: Clock) -> dict[str, int]:
    """The time series of the view (speed, OC states, monitor or measured target, health):
    appended to what is logged already (a live view logs each new stretch once)."""
    counts: dict[str, int] = {}
    log_style(f"speed/{data.switch}", f"{data.switch} (rpm)", COLORS["speed"])
    counts["speed"] = log_scalars(f"speed/{data.switch}", data.speed.t, data.speed.v, clock)
    if data.switches is not None:
        counts["oc_switches"] = log_states("state/oc", data.switches.t, data.switches.oc, clock)
        log_states("state/phase", data.switches.t, data.switches.phase, clock)
        log_switch_text("log/oc", data.switches, clock)
    if data.monitor is not None:
        log_monitor(data, clock)
        counts["monitor"] = len(data.monitor.t)
        counts["alarm"] = int(np.sum(data.monitor.flag == Flag.ALARM.value))
    elif data.measured is not None:
        log_style("target/measured", f"{data.target} measured", COLORS["measured"])
        counts["measured"] = log_scalars("target/measured", data.measured.t, data.measured.v, clock)
    if data.health is not None:
        log_health(data.health, clock)
        counts["health"] = len(data.health.t)
    return counts


def log_plots(data: ViewData, clock: Clock) -> dict[str, int]:
    """The 2-D views of all the data (characteristic curve, polar, Bode): static, so logging
    them again replaces them."""
    counts: dict[str, int] = {}
    speed, y, t, run, alarm = curve_arrays(data, clock)
    counts["curve"] = int(np.sum(np.isfinite(speed) & np.isfinite(y)))
    counts["runs"] = int(run.max()) + 1 if len(run) else 0
    log_curve(speed, y, t, run, data.switch, data.target, data.target_unit, alarm)
    if (v := vectors_of(data)) is not None:
        counts["vectors"] = log_polar(v, data.switch, data.target_unit)
        log_bode(v, data.switch, data.target, data.target_unit)
    return counts


def blueprint(data: ViewData) -> rrb.Blueprint:
    """Layout: time series stacked on the left (x axes linked, all runs shown), curve and log on the right."""
    span = Clock(data.speed.t)(data.speed.t[[0, -1]]) if len(data.speed.t) else np.zeros(2)
    whole = rrb.TimeRange(
        start=rrb.TimeRangeBoundary.absolute(seconds=float(span[0])),
        end=rrb.TimeRangeBoundary.absolute(seconds=float(span[1])),
    )  # on engine_time: show every run at first
    link = rrb.TimeAxis(view_range=whole)
    legend = rrb.PlotLegend(corner=rrb.Corner2D.LeftTop)
    unit = data.target_unit
    left: list[rrb.View] = [
        rrb.TimeSeriesView(origin="/speed", name=f"{data.switch} (rpm)", axis_x=link, plot_legend=legend)
    ]
    shares = [2.0]
    if data.switches is not None or data.monitor is not None:
        left.append(rrb.StateTimelineView(origin="/state", name="OC / phase / flag", time_view=link))
        shares.append(1.5)
    title = f"{data.target} ({unit})"
    if data.monitor is not None:
        title = f"{data.target} measured vs predicted ± band ({unit})"
    left.append(rrb.TimeSeriesView(origin="/target", name=title, axis_x=link, plot_legend=legend))
    shares.append(2.0)
    if data.monitor is not None:
        left.append(
            rrb.TimeSeriesView(
                origin="/residual", name=f"residual ± band ({unit})", axis_x=link, plot_legend=legend
            )
        )
        shares.append(1.5)
        if np.isfinite(data.monitor.score).any():
            left.append(rrb.TimeSeriesView(origin="/score", name="score", axis_x=link, plot_legend=legend))
            shares.append(1.0)
    curve = rrb.Spatial2DView(
        origin="/curve",
        name=f"characteristic curve: {data.target} against {data.switch} (colour: run, shade: time)",
    )
    right: list[rrb.View | rrb.Container] = [curve]
    if vectors_of(data) is not None:
        right[0] = rrb.Tabs(
            curve,
            rrb.Spatial2DView(origin="/polar", name=f"polar: {data.target} 1x vector (x Re, y Im; lag "
                              f"clockwise; colour: {data.switch}, orange: predicted)"),
            rrb.Vertical(
                rrb.Spatial2DView(origin="/bode/amplitude", name=f"Bode: {data.target} amplitude "
                                  f"against {data.switch} (colour: run, orange: predicted)"),
                rrb.Spatial2DView(origin="/bode/phase", name=f"Bode: {data.target} phase lag, wrapped"),
                name="Bode",
            ),
        )
    rshares = [3.0]
    if data.switches is not None:
        right.append(rrb.TextLogView(origin="/log", name="OC switches"))
        rshares.append(1.0)
    if data.health is not None:
        right.append(rrb.TimeSeriesView(origin="/health", name="node health", axis_x=link))
        rshares.append(1.0)
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(*left, row_shares=shares),
            rrb.Vertical(*right, row_shares=rshares),
            column_shares=[3.0, 2.0],
        ),
        rrb.TimePanel(timeline="engine_time", expanded=False, play_state=rrb.components.PlayState.Paused),
        collapse_panels=True,
    )
