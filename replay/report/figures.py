"""The report's matplotlib figures (also ``ordervib evaluate``'s plot); each returns a Figure.

Figures are made with ``matplotlib.figure.Figure`` (no pyplot state, the Agg canvas), so a
caller may save or embed them (``replay.report.document.figure_html``) from any thread.
Runs keep one colour across a report's figures (``run_colours``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal

import numpy as np
from matplotlib.figure import Figure

from node.training.evaluation import SegmentPrediction
from node.training.runs import Run
from replay.views.style import LABEL, SMALL


def run_colours(n: int) -> list[tuple[float, float, float, float]]:
    """One viridis colour per run, in order (n >= 0)."""
    from matplotlib import colormaps
    cmap = colormaps["viridis"]
    return [cmap(x) for x in np.linspace(0.0, 0.9, max(n, 1))][:n]


def _grid(n: int, cols: int, width: float, height: float,
          layout: Literal["constrained", "tight"] | None = None) -> tuple[Figure, np.ndarray]:
    """A figure of n panels in rows of ``cols``, each width x height inches; unused panels hidden;
    layout: matplotlib's layout engine (None: none, the caller lays it out)."""
    cols = max(1, min(cols, n))
    rows = -(-n // cols)
    fig = Figure(figsize=(width * cols, height * rows), layout=layout)
    axes = fig.subplots(rows, cols, squeeze=False).ravel()
    for ax in axes[n:]:
        ax.axis("off")
    return fig, axes


def segments_figure(names: Sequence[str], preds: list[SegmentPrediction], target: str,
                    colours: Sequence | None = None) -> Figure | None:
    """Predicted (dashed) against measured (solid) per OC, each segment from its OC switch;
    None when ``preds`` is empty. colours: one per run index (default: matplotlib's cycle)."""
    present = sorted({p.oc for p in preds})
    if not present:
        return None
    fig, axes = _grid(len(present), 3, 3.6, 2.6)
    for ax, oc in zip(axes, present):
        for p in [q for q in preds if q.oc == oc]:
            t = p.t - p.t[0]
            kw = {} if colours is None else {"color": colours[p.run]}
            line, = ax.plot(t, p.measured, lw=1.0, **kw)
            ax.plot(t, p.predicted, "--", lw=1.0, color=line.get_color())
        ax.set_title(names[oc], fontsize=LABEL)
        ax.set_xlabel("s since the OC switch", fontsize=SMALL)
        ax.set_ylabel(f"{target} (mm/s)", fontsize=SMALL)
        ax.tick_params(labelsize=SMALL)
    fig.tight_layout()
    return fig


def curve_figure(runs: Sequence[Run], labels: Sequence[str], switch: str, target: str,
                 curve: tuple[np.ndarray, np.ndarray], oc_speeds: Sequence[tuple[str, float]]) -> Figure:
    """The target's amplitude against the switch speed, a line per run, the characteristic curve
    ``(speeds, means)`` in black, the OCs' nominal speeds (name, rpm) as dotted lines."""
    fig = Figure(figsize=(11.0, 4.6))
    ax = fig.subplots()
    for run, label, c in zip(runs, labels, run_colours(len(runs))):
        if switch in run.channels and target in run.channels:
            ax.plot(run.column(switch), run.column(target), lw=0.6, color=c, alpha=0.8, label=label)
    ax.plot(curve[0], curve[1], color="black", lw=1.6, label="characteristic curve")
    top = ax.get_ylim()[1]
    for name, speed in oc_speeds:
        ax.axvline(speed, color="grey", lw=0.6, ls=":")
        ax.text(speed, top, name, rotation=90, va="top", ha="right", fontsize=SMALL, color="dimgrey")
    ax.set_xlabel(f"{switch} (rpm)")
    ax.set_ylabel(f"{target}, tracked order amplitude (mm/s)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=SMALL, loc="upper left")
    fig.tight_layout()
    return fig


def _short(x: float) -> str:
    """A number in at most 4 significant digits and few characters (no exponent from 1e4 to 1e6).

    >>> [_short(v) for v in (12162.4, 0.34241, 24.0, 3.2e7)]
    ['12162', '0.3424', '24', '3.2e+07']
    """
    return f"{x:.0f}" if 1e4 <= abs(x) < 1e6 else f"{x:.4g}"


def parallel_figure(panels: Sequence[tuple[str, Sequence[str], np.ndarray]], labels: Sequence[str],
                    ) -> Figure | None:
    """Parallel coordinates, one panel per (title, axis names (n,), values (runs, n)): each axis
    scaled to the runs' range (its minimum and maximum written at its ends), a line per run in
    its colour; None without panels."""
    if not panels:
        return None
    n_runs = len(labels)
    colours = run_colours(n_runs)
    fig, axes = _grid(len(panels), 2, 5.4, 3.2, layout="constrained")
    for ax, (title, names, values) in zip(axes, panels):
        values = np.asarray(values, float).reshape(n_runs, len(names))
        lo = np.nanmin(np.where(np.isfinite(values), values, np.inf), axis=0)
        hi = np.nanmax(np.where(np.isfinite(values), values, -np.inf), axis=0)
        span = np.where(hi > lo, hi - lo, 1.0)
        scaled = np.where(hi > lo, (values - lo) / span, 0.5)
        x = np.arange(len(names))
        for i in range(n_runs):
            ax.plot(x, scaled[i], "-o", ms=3, lw=1.0, color=colours[i], label=labels[i])
        for j in x:
            ax.axvline(j, color="black", lw=0.6)
            if np.isfinite(lo[j]):
                ax.text(j, -0.06, _short(lo[j]), ha="center", va="top", fontsize=SMALL)
                ax.text(j, 1.06, _short(hi[j]), ha="center", va="bottom", fontsize=SMALL)
        ax.set_xticks(x, list(names), rotation=30, ha="right", fontsize=SMALL)
        ax.set_yticks([])
        ax.set_ylim(-0.2, 1.2)
        ax.set_xlim(-0.3, max(len(names) - 0.7, 0.3))
        ax.set_title(title, fontsize=LABEL, pad=14)
        for side in ("top", "right", "left"):
            ax.spines[side].set_visible(False)
    fig.legend(*axes[0].get_legend_handles_labels(), fontsize=SMALL, loc="outside upper center",
               ncol=min(n_runs, 6))
    return fig


def score_figure(names: Sequence[str],
                 scores: Sequence[tuple[str, Sequence[float], Sequence[float], float | None]]) -> Figure:
    """Bar charts per OC, one panel per (metric, model's values, curve's values, floor): the
    model's bar beside the characteristic curve's (a missing value: no bar); a value below the
    floor (None: none) is drawn cut at it, with its value written."""
    fig, axes = _grid(len(scores), 2, 5.4, 3.2)
    x = np.arange(len(names))
    for ax, (metric, model, curve, floor) in zip(axes, scores):
        any_cut = False
        for dx, values, label, colour in ((-0.2, model, "model", "tab:blue"),
                                          (0.2, curve, "characteristic curve", "tab:grey")):
            v = np.asarray(values, float)
            cut = np.zeros(v.shape, bool) if floor is None else v < floor
            shown = np.where(cut, floor if floor is not None else 0.0, v)
            bars = ax.bar(x + dx, shown, 0.4, label=label, color=colour)
            any_cut |= bool(cut.any())
            for bar, value, c in zip(bars, v, cut):
                if c:
                    ax.text(bar.get_x() + bar.get_width() / 2, float(floor or 0.0), f"{value:.3g}",
                            rotation=90, ha="center", va="bottom", fontsize=SMALL,
                            bbox={"facecolor": "white", "edgecolor": "none", "pad": 0.5})
        if any_cut:
            ax.set_ylim(bottom=floor)
        ax.set_xticks(x, list(names), rotation=45, ha="right", fontsize=SMALL)
        ax.tick_params(axis="y", labelsize=SMALL)
        ax.set_ylabel(metric, fontsize=LABEL)
        ax.axhline(0.0, color="black", lw=0.6)
        ax.grid(axis="y", alpha=0.3)
        ax.legend(fontsize=SMALL)
    fig.tight_layout()
    return fig


def runs_figure(runs: Sequence[Run], labels: Sequence[str], preds: list[SegmentPrediction],
                switch: str, target: str) -> Figure | None:
    """Per run: what it measured over the whole run (grey), the model's prediction of every OC
    segment (coloured), the switch speed on a second axis; None without runs."""
    if not runs:
        return None
    fig, axes = _grid(len(runs), 1, 11.0, 2.4)
    colours = run_colours(len(runs))
    for i, (ax, run, label) in enumerate(zip(axes, runs, labels)):
        t0 = float(run.t[0])
        ax.plot(run.t - t0, run.column(target), lw=0.6, color="grey", label="measured")
        for k, p in enumerate(q for q in preds if q.run == i):
            ax.plot(p.t - t0, p.predicted, lw=0.9, color=colours[i], label="predicted" if k == 0 else None)
        ax.set_ylabel(f"{target} (mm/s)", fontsize=SMALL)
        ax.set_title(label, fontsize=LABEL)
        ax.tick_params(labelsize=SMALL)
        ax.legend(fontsize=SMALL, loc="upper left")
        speed = ax.twinx()
        speed.plot(run.t - t0, run.column(switch), lw=0.5, color="tab:orange", alpha=0.6)
        speed.set_ylabel(f"{switch} (rpm)", fontsize=SMALL, color="tab:orange")
        speed.tick_params(labelsize=SMALL)
    axes[len(runs) - 1].set_xlabel("s since the run started", fontsize=SMALL)
    fig.tight_layout()
    return fig
