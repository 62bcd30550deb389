"""PNG plots of the target's 1x vector (matplotlib, Agg canvas; no pyplot, no Rerun).

- ``polar_figure``: the vector over the recording in polar axes, one panel per run: radius the
  amplitude, angle the phase lag measured clockwise from 0 degrees at the right (the
  Rerun view's x = Re, y = Im picture); measured as dots coloured by the switch speed (a
  colour bar), predicted as black crosses.
  Speeds are labelled along each run's longest run-up and coast-down.
- ``bode_figure``: the Bode pair of the transients, as a rotordynamics engineer reads it:
  amplitude and phase lag against speed on two stacked axes, one trace per ramp
  (``node.runtime.transient.find_transitions``: run-ups solid, coast-downs and ramps down
  dashed, a colour per run; the plateaus left out), the phase lag unwrapped along each
  run (continuous through a resonance's roll of about 180 degrees; left out where the
  amplitude is within the noise, ``PHASE_FLOOR``), optionally slow-roll
  compensated (each run's mean vector in a low speed band subtracted: the runout or bow),
  each resonance found (``transient.analyse``, on the ramps the node analyses) marked with its
  critical speed and AF, written in a strip above the data. The whole speed range is drawn:
  ramps too short for the analysis as traces, the plateaus as faint dots. The
  prediction is left to the polar plot and the Rerun view (a model predicts the plateaus'
  level, not a Bode). A recording without ramps: every sample as markers, predicted too.

Both return a matplotlib Figure on an Agg canvas; ``save_png`` writes one.
"""

from __future__ import annotations

import math
from datetime import UTC, datetime
from typing import cast

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.projections.polar import PolarAxes
from matplotlib.ticker import MaxNLocator
from matplotlib.transforms import blended_transform_factory

from node.contract.vector import order_lags
from node.runtime.transient import MIN_SPAN, Critical, Span, analyse, find_transitions
from replay.views.view_data import Vectors

DPI = 100
LAG_LABELS = ["0°", "45°", "90°", "135°", "±180°", "-135°", "-90°", "-45°"]  # every 45° clockwise from 0


PREDICTED = "black"  # the prediction in every plot


def save_png(fig: Figure, path: str) -> None:
    """Write fig as a PNG file to path (any name: the format is given)."""
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=DPI, format="png")


def _run_label(v: Vectors, r: int) -> str:
    """'run k (start UTC)' of run number r (0-based)."""
    start = datetime.fromtimestamp(float(v.t[v.run == r][0]), UTC)
    return f"run {r + 1} ({start:%Y-%m-%d %H:%M} UTC)"


def _runs(v: Vectors) -> list[int]:
    """The runs with a finite vector (measured or predicted), in order."""
    ok = np.isfinite(v.measured()) | np.isfinite(v.predicted())
    return [int(r) for r in np.unique(v.run[ok & np.isfinite(v.speed)])]


def polar_figure(v: Vectors, title: str, switch: str, unit: str) -> Figure:
    """The polar plot of the 1x vector, one panel per run, coloured by speed (rpm)."""
    runs = _runs(v)
    cols = min(len(runs), 3)
    rows = -(-len(runs) // cols)
    fig = Figure(figsize=(4.4 * cols + 1.2, 4.4 * rows + 0.8), layout="constrained")
    norm = Normalize(*v.speed_range())
    rmax = float(np.nanmax(np.abs(np.concatenate([v.measured(), v.predicted()])))) * 1.05
    axes = [cast(PolarAxes, fig.add_subplot(rows, cols, k + 1, projection="polar")) for k in range(len(runs))]
    sc = None
    for ax, r in zip(axes, runs):
        sel = v.run == r
        ax.set_theta_zero_location("E")
        ax.set_theta_direction(-1)  # a lag turns the vector clockwise
        ok = sel & np.isfinite(v.measured())
        if ok.any():
            vec = v.measured()[ok]
            sc = ax.scatter(-np.angle(vec), np.abs(vec), c=v.speed[ok], cmap="viridis", norm=norm, s=3.0,
                            marker="o", linewidths=0.0, label="measured", rasterized=True)
        ok = sel & np.isfinite(v.predicted())
        if ok.any():  # one contrasting colour: the prediction must stand out from the measured cloud
            vec = v.predicted()[ok]
            ax.scatter(-np.angle(vec), np.abs(vec), color=PREDICTED, s=4.0, marker="x", linewidths=0.5,
                       alpha=0.6, label="predicted", rasterized=True)
        _speed_labels(ax, v, r)
        ax.set_thetagrids(np.arange(0, 360, 45), LAG_LABELS)
        ax.set_rmax(rmax)
        ax.yaxis.set_major_locator(MaxNLocator(4))
        ax.set_title(_run_label(v, r), fontsize=9)
        ax.tick_params(labelsize=7)
        if v.has_predicted():
            ax.legend(loc="lower left", fontsize=7, markerscale=2.0)
    if sc is not None:
        fig.colorbar(sc, ax=axes, label=f"{switch} (rpm)", shrink=0.8)
    fig.suptitle(f"{title}\nradius: amplitude ({unit}); angle: phase lag, clockwise from 0° at the right",
                 fontsize=10)
    return fig


MAX_SPEED_LABELS = 8  # per ramp of the polar plot
MAX_SPEED = 1e6  # rpm: a speed band beyond it is a typing error
PHASE_FLOOR = 0.05  # the Bode's phase is left out below this share of the run's largest amplitude


def speed_band(text: str) -> tuple[float, float]:
    """A speed band "LO,HI" (rpm, 0 <= LO < HI <= ``MAX_SPEED``); ValueError in one line.

    >>> speed_band("1000,1500")
    (1000.0, 1500.0)
    """
    parts = text.split(",")
    try:
        lo, hi = (float(x) for x in parts) if len(parts) == 2 else (math.nan, math.nan)
    except ValueError:
        lo = hi = math.nan
    if not 0.0 <= lo < hi <= MAX_SPEED:
        raise ValueError(f"want LO,HI in rpm with 0 <= LO < HI <= {MAX_SPEED:g}, got {text!r}")
    return lo, hi


SHORT_SPAN = 0.02  # the Bode draws ramps down to this share of their top speed (the analysis: MIN_SPAN)
LABEL_WIDTH = 0.1  # a critical's label, as a share of the speed axis (another row where closer)
LABEL_ROWS = 2  # rows of labels in the strip above the data
SAME_MODE = 0.02  # criticals of the first run within this share of a labelled one: marked, not written
LABEL_ROOM = 1.6  # the amplitude axis reaches this many times the largest amplitude: labels above


def _ramps(v: Vectors, r: int, min_span: float = MIN_SPAN) -> list[tuple[Span, np.ndarray]]:
    """Run r's ramps (``find_transitions`` on its switch speed, each covering at least
    ``min_span`` of its top speed) with their rows of v."""
    rows = np.flatnonzero(v.run == r)
    return [(sp, rows[sp.start:sp.stop]) for sp in find_transitions(v.speed[rows], min_span=min_span)]


def _nice_step(span: float, most: int) -> float:
    """A round speed step (1, 2 or 5 x 10^k rpm) giving at most ``most`` labels over span."""
    raw = max(span / most, 1e-9)
    base = 10.0 ** math.floor(math.log10(raw))
    return next(m * base for m in (1.0, 2.0, 5.0, 10.0) if m * base >= raw)


def _speed_labels(ax: PolarAxes, v: Vectors, r: int) -> None:
    """Round speeds written beside the measured vector along run r's longest run-up and coast-down."""
    z = v.measured()
    longest: dict[str, tuple[Span, np.ndarray]] = {}
    for sp, idx in _ramps(v, r):
        if sp.direction not in longest or abs(sp.to_speed - sp.from_speed) > abs(
                longest[sp.direction][0].to_speed - longest[sp.direction][0].from_speed):
            longest[sp.direction] = (sp, idx)
    for sp, idx in longest.values():
        ok = idx[np.isfinite(z[idx]) & np.isfinite(v.speed[idx])]
        if len(ok) < 2:
            continue
        lo, hi = float(np.min(v.speed[ok])), float(np.max(v.speed[ok]))
        step = _nice_step(hi - lo, MAX_SPEED_LABELS)
        for mark in np.arange(math.ceil(lo / step) * step, hi, step):
            k = ok[int(np.argmin(np.abs(v.speed[ok] - mark)))]
            ax.annotate(f"{mark:,.0f}", (-float(np.angle(z[k])), float(np.abs(z[k]))), fontsize=6,
                        color="dimgray" if sp.direction == "up" else "saddlebrown",
                        xytext=(3, 3), textcoords="offset points")


def _unwrapped(phase: np.ndarray, before: float | None) -> np.ndarray:
    """A ramp's phase lag (K,) in degrees unwrapped (NaN kept), shifted by whole turns to start
    nearest ``before`` (the run's previous ramp's last value; None: its first in [-180, 180))."""
    out = np.full(phase.shape, np.nan)
    ok = np.isfinite(phase)
    if ok.any():
        u = np.degrees(np.unwrap(np.radians(phase[ok])))
        turns = np.floor((u[0] + 180.0) / 360.0) if before is None else np.round((u[0] - before) / 360.0)
        out[ok] = u - 360.0 * turns
    return out


def _compensated(v: Vectors, sel: np.ndarray,
                 band: tuple[float, float] | None) -> tuple[np.ndarray, np.ndarray]:
    """Amplitude and phase lag (degrees) of the measured vectors of rows ``sel`` less the mean
    vector of those rows whose speed lies in ``band`` (rpm; None or no such rows: as measured)."""
    amp, ph = v.amplitude[sel], v.phase[sel]
    if band is None:
        return amp, ph
    z = v.measured()[sel]
    slow = np.isfinite(z) & (v.speed[sel] >= band[0]) & (v.speed[sel] <= band[1])
    if not slow.any():
        return amp, ph
    z = z - np.mean(z[slow])
    return np.abs(z), order_lags(z)


def bode_figure(v: Vectors, title: str, switch: str, target: str, unit: str,
                slow_roll: tuple[float, float] | None = None, tracker_tau: float = 0.0) -> Figure:
    """The Bode pair of the transients (see the module), a colour per run.

    slow_roll: a speed band (rpm) whose mean 1x vector, per run, is subtracted (None: none);
    tracker_tau: the order tracker's lag (s) undone when finding the criticals (0: not undone).
    """
    ok = np.isfinite(v.amplitude) & np.isfinite(v.speed)  # a Bode of the amplitude alone where no phase
    runs = [int(r) for r in np.unique(v.run[ok])]
    ramps = {r: _ramps(v, r, SHORT_SPAN) for r in runs}
    if not any(ramps.values()):
        return _bode_markers(v, runs, title, switch, target, unit)
    fig = Figure(figsize=(11.0, 8.0))
    amp_ax, ph_ax = fig.subplots(2, 1, sharex=True)
    found: list[tuple[Critical, str]] = []
    top_all = 0.0
    for k, r in enumerate(runs):
        color = f"C{k % 10}"
        last: float | None = None
        traces = [_compensated(v, idx, slow_roll) for _, idx in ramps[r]]
        top = max((float(np.nanmax(amp, initial=0.0)) for amp, _ in traces), default=0.0)
        top_all = max(top_all, top)
        analysed = {(sp.start, sp.stop) for sp, _ in _ramps(v, r)}  # the node's ramps: criticals marked
        for n, ((sp, idx), (amp, ph)) in enumerate(zip(ramps[r], traces)):
            ph = np.where(amp >= PHASE_FLOOR * top, ph, np.nan)  # a vector lost in the noise has no phase
            style = "-" if sp.direction == "up" else "--"
            amp_ax.plot(v.speed[idx], amp, style, lw=0.8, color=color, label=None if n else _run_label(v, r))
            lag = _unwrapped(ph, last)
            ph_ax.plot(v.speed[idx], lag, style, lw=0.8, color=color)
            if np.isfinite(lag).any():
                last = float(lag[np.isfinite(lag)][-1])
            if (sp.start, sp.stop) in analysed:
                found += [(c, color if k == 0 else "") for c in _criticals(v, idx, tracker_tau)]
        rows = np.flatnonzero((v.run == r) & ok)  # the plateaus too: the whole speed range, as dots
        amp_ax.plot(v.speed[rows], v.amplitude[rows], ".", ms=1.0, alpha=0.35, color=color)
    marked = _mark_criticals(amp_ax, found, top_all)
    amp_ax.set_ylabel(f"{target} amplitude ({unit})")
    amp_ax.set_ylim(0.0, LABEL_ROOM * top_all if top_all > 0 else None)
    ph_ax.set_ylabel(f"{target} phase lag (°, unwrapped)")
    ph_ax.set_xlabel(f"{switch} (rpm)")
    for ax in (amp_ax, ph_ax):
        ax.grid(True, lw=0.4, alpha=0.5)
        ax.tick_params(labelsize=9)
    amp_ax.legend(fontsize=9, ncol=3 if len(runs) > 4 else 1)
    how = (f"slow roll {slow_roll[0]:,.0f}-{slow_roll[1]:,.0f} rpm subtracted" if slow_roll
           else "no slow-roll compensation")
    fig.suptitle(f"{title}: transients; run-ups solid, ramps down dashed; {marked} critical(s) marked ▼ "
                 f"(speed, AF by half power)\nphase unwrapped along each run, left out below "
                 f"{PHASE_FLOOR:.0%} of the run's largest amplitude; {how}", fontsize=10)
    fig.tight_layout()
    return fig


def _criticals(v: Vectors, idx: np.ndarray, tracker_tau: float) -> list[Critical]:
    """The resonances ``transient.analyse`` finds in one ramp's rows (none: too few samples)."""
    amp, ph = v.amplitude[idx], v.phase[idx]
    if np.isfinite(amp).sum() < 10:
        return []
    try:
        return list(analyse(v.speed[idx], amp, ph if np.isfinite(ph).any() else None,
                            tracker_tau=tracker_tau).criticals)
    except ValueError:  # too few samples with speed and amplitude
        return []


def _mark_criticals(ax: Axes, found: list[tuple[Critical, str]], top: float) -> int:
    """Each critical of ``found`` marked on the amplitude axis in its run's colour; those of the
    first run (colour given) written with speed and AF in the strip above the data (the axis
    reaches ``LABEL_ROOM`` x ``top``), a thin line down to the marker, one label per mode (none
    within ``SAME_MODE`` of one written), in up to ``LABEL_ROWS`` rows where neighbours would
    touch: no label covers a trace or another. How many were marked."""
    strip = blended_transform_factory(ax.transData, ax.transAxes)
    lo, hi = ax.get_xlim()
    room = LABEL_WIDTH * (hi - lo)  # labels closer than this go to another row
    rows = [-math.inf] * LABEL_ROWS  # each row's last label's speed
    written: list[float] = []
    for c, color in sorted(found, key=lambda f: f[0].speed):
        ax.plot([c.speed], [c.amplitude], "v", ms=6, color=color or "gray", mec="black", mew=0.5)
        if not color or top <= 0 or any(abs(c.speed / w - 1.0) <= SAME_MODE for w in written):
            continue
        row = next((r for r, x in enumerate(rows) if c.speed - x >= room), None)
        if row is None:
            continue  # no room left in the strip: marked, not written
        rows[row] = c.speed
        written.append(c.speed)
        ax.annotate(f"{c.speed:,.0f} rpm\nAF {c.af:.1f}", (c.speed, c.amplitude), fontsize=9,
                    xytext=(c.speed, 0.97 - 0.1 * row), textcoords=strip, ha="center", va="top",
                    arrowprops={"arrowstyle": "-", "lw": 0.5, "color": "gray"})
    return len(found)


def _bode_markers(v: Vectors, runs: list[int], title: str, switch: str, target: str, unit: str) -> Figure:
    """Amplitude and wrapped phase of every sample as markers (a recording without ramps)."""
    fig = Figure(figsize=(9.0, 7.0))
    amp_ax, ph_ax = fig.subplots(2, 1, sharex=True)
    for k, r in enumerate(runs):
        sel = v.run == r
        color = f"C{k % 10}"
        for ax, y, yp in ((amp_ax, v.amplitude, v.predicted_amplitude), (ph_ax, v.phase, v.predicted_phase)):
            ax.plot(v.speed[sel], y[sel], ".", ms=2.0, color=color, label=f"{_run_label(v, r)} measured",
                    rasterized=True)
            if np.isfinite(yp[sel]).any():
                ax.plot(v.speed[sel], yp[sel], "x", ms=3.0, mew=0.5, color=PREDICTED, alpha=0.6,
                        label=f"{_run_label(v, r)} predicted", rasterized=True)
    amp_ax.set_ylabel(f"{target} amplitude ({unit})")
    amp_ax.set_ylim(bottom=0.0)
    ph_ax.set_ylabel(f"{target} phase lag (°, wrapped)")
    ph_ax.set_ylim(-185.0, 185.0)
    ph_ax.set_yticks(np.arange(-180.0, 181.0, 90.0))
    ph_ax.set_xlabel(f"{switch} (rpm)")
    for ax in (amp_ax, ph_ax):
        ax.grid(True, lw=0.4, alpha=0.5)
        ax.tick_params(labelsize=9)
    amp_ax.legend(fontsize=9, markerscale=3.0, ncol=2)
    fig.suptitle(f"{title}\nno ramps found: every sample, phase wrapped to [-180, 180), markers", fontsize=10)
    fig.tight_layout()
    return fig
