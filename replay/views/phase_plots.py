"""PNG plots of the target's 1x vector (matplotlib, Agg canvas; no pyplot, no Rerun).

- ``polar_figure``: the vector over the recording in polar axes, one panel per run: radius the
  amplitude, angle the phase lag measured clockwise from 0 degrees at the right (the
  Rerun view's x = Re, y = Im picture); measured as dots coloured by the switch speed (a
  colour bar), predicted as black crosses.
- ``bode_figure``: the Bode pair, amplitude and phase against speed on two stacked axes
  sharing speed; the phase wrapped to [-180, 180) and drawn as markers (no line across
  a wrap); measured dots in a colour per run, predicted black crosses.

Both return a matplotlib Figure on an Agg canvas; ``save_png`` writes one.
"""

from __future__ import annotations

from datetime import UTC, datetime
from typing import cast

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.projections.polar import PolarAxes
from matplotlib.ticker import MaxNLocator

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


def bode_figure(v: Vectors, title: str, switch: str, target: str, unit: str) -> Figure:
    """The Bode pair (amplitude and wrapped phase against speed), a colour per run."""
    fig = Figure(figsize=(9.0, 7.0))
    amp_ax, ph_ax = fig.subplots(2, 1, sharex=True)
    for k, r in enumerate(_runs(v)):
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
        ax.tick_params(labelsize=8)
    amp_ax.legend(fontsize=7, markerscale=3.0, ncol=2)
    fig.suptitle(f"{title}\nphase wrapped to [-180, 180), markers", fontsize=10)
    fig.tight_layout()
    return fig
