"""Figures of the contextual characteristic curves (the toolbox's panel I, figures 3.4-3.6;
matplotlib Figures on no canvas, no pyplot, no file I/O: ``replay.views.phase_plots.save_png``).

- ``fig_context_clusters``: per OC one row: (a) the clusters in temperature space (two of the
  channels, the third as the marker size), (b) carried onto the speed profile over time
  since the plateau start, a line per run, (c) onto the characteristic curve (speed against
  amplitude), each cluster's posterior mean of the amplitude marked.
- ``fig_context_timeline``: figure 3.5 (b): every OC's clusters over the plateau's normalised
  time, a row per run.
- ``fig_context_violins``: figure 3.6 (b): per OC, violins of the posterior of each cluster's
  mean amplitude mu, and below those of its standard deviation sigma.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from matplotlib.figure import Figure

from node.training.context import OCContext
from replay.views.style import LABEL, SMALL, WIDTH

COLORS = ("tab:blue", "tab:orange", "tab:purple", "tab:green", "tab:red", "tab:brown", "tab:pink",
          "tab:olive")


def _color(k: int) -> str:
    return COLORS[k % len(COLORS)]


def fig_context_clusters(ctxs: Sequence[OCContext], unit: str = "mm/s") -> Figure:
    """Figures 3.4 / 3.5 for the OCs ``ctxs`` (``node.training.context.context_curves``)."""
    if not ctxs:
        raise ValueError("no OC to draw")
    target = ctxs[0].target
    fig = Figure(figsize=(WIDTH, 3.0 * len(ctxs)), layout="constrained")
    axes = fig.subplots(len(ctxs), 3, squeeze=False)
    for row, c in zip(axes, ctxs):
        a, b, cc = row
        ch = c.channels
        size = None
        if len(ch) > 2:
            z = c.X[:, 2]
            span = float(np.ptp(z)) or 1.0
            size = 6 + 30 * (z - z.min()) / span
        for k in range(c.n_clusters):
            mine = c.labels == k
            a.scatter(c.X[mine, 0], c.X[mine, 1] if len(ch) > 1 else c.y[mine], label=f"cluster {k + 1}",
                      s=8 if size is None else size[mine], color=_color(k), alpha=0.7, lw=0)
            cc.scatter(c.speed[mine], c.y[mine], s=8, color=_color(k), alpha=0.7, lw=0)
            mu = float(np.mean(c.posteriors[k].mu))
            cc.axhline(mu, color=_color(k), lw=1.0, ls="--")
        a.set_xlabel(f"{ch[0]} (°C)", fontsize=SMALL)
        a.set_ylabel(f"{ch[1]} (°C)" if len(ch) > 1 else f"{target} ({unit})", fontsize=SMALL)
        a.set_title(f"{c.name}: (a) clusters on the temperatures" + (f" (size: {ch[2]})" if size is not None
                                                                     else ""), fontsize=LABEL, loc="left")
        a.legend(fontsize=SMALL, markerscale=1.5)
        for r in np.unique(c.run).tolist():
            mine = c.run == r
            e, s, lab = c.elapsed[mine], c.speed[mine], c.labels[mine]
            b.plot(e, s, color="0.75", lw=0.8, zorder=0)
            b.scatter(e, s, s=9, c=[_color(k) for k in lab.tolist()], lw=0)
        b.set_xlabel("s since the plateau start", fontsize=SMALL)
        b.set_ylabel("speed (rpm)", fontsize=SMALL)
        b.set_title("(b) on the speed profile, each run", fontsize=LABEL, loc="left")
        cc.set_xlabel("speed (rpm)", fontsize=SMALL)
        cc.set_ylabel(f"{target} ({unit})", fontsize=SMALL)
        cc.set_title("(c) on the curve (dashed: posterior mean)", fontsize=LABEL, loc="left")
        for ax in row:
            ax.tick_params(labelsize=SMALL)
    return fig


def fig_context_timeline(ctxs: Sequence[OCContext]) -> Figure:
    """Figure 3.5 (b): every OC's clusters over the plateau's normalised time (0 its start, 1
    its end), a thin row per run within each OC's band: the clusters following one another."""
    if not ctxs:
        raise ValueError("no OC to draw")
    fig = Figure(figsize=(9, 0.45 * len(ctxs) + 1.2), layout="constrained")
    ax = fig.subplots()
    for i, c in enumerate(ctxs):
        runs = np.unique(c.run).tolist()
        h = 0.8 / len(runs)
        for j, r in enumerate(runs):
            mine = np.flatnonzero(c.run == r)
            mine = mine[np.argsort(c.tau[mine], kind="stable")]
            tau, lab = c.tau[mine], c.labels[mine]
            ends = np.r_[tau[1:], 1.0]  # each sample's bar reaches the next sample
            cut = np.flatnonzero(np.diff(lab) != 0) + 1
            for lo, hi in zip(np.r_[0, cut], np.r_[cut, lab.size]):  # one bar per stretch of a cluster
                ax.broken_barh([(tau[lo], ends[hi - 1] - tau[lo])], (i - 0.4 + j * h, 0.9 * h),
                               color=_color(int(lab[lo])), lw=0)
    ax.set_yticks(range(len(ctxs)), [c.name for c in ctxs], fontsize=SMALL)
    ax.invert_yaxis()
    ax.set_xlim(0, 1)
    ax.set_xlabel("time within the plateau (fraction of its length); a row per run", fontsize=SMALL)
    ax.set_title("clusters over time, per OC (colours: cluster 1, 2, ... in time order)", fontsize=LABEL,
                 loc="left")
    return fig


def fig_context_violins(ctxs: Sequence[OCContext], unit: str = "mm/s", cols: int = 4) -> Figure:
    """Figure 3.6 (b): per OC (``cols`` OCs a row, each its own scale) the posterior violins of
    each cluster's mean mu (upper panel) and standard deviation sigma (lower panel)."""
    if not ctxs:
        raise ValueError("no OC to draw")
    target = ctxs[0].target
    cols = min(cols, len(ctxs))
    rows = -(-len(ctxs) // cols)
    fig = Figure(figsize=(WIDTH / 4 * cols, 4.2 * rows), layout="constrained")
    axes = fig.subplots(2 * rows, cols, squeeze=False)
    for i, c in enumerate(ctxs):
        top, bottom = axes[2 * (i // cols), i % cols], axes[2 * (i // cols) + 1, i % cols]
        for k, p in enumerate(c.posteriors):
            for ax, s in ((top, p.mu), (bottom, p.sigma)):
                parts = ax.violinplot([s], positions=[k + 1], widths=0.8, showmeans=True, showextrema=False)
                for body in parts["bodies"]:
                    body.set_facecolor(_color(k))
                    body.set_alpha(0.6)
                parts["cmeans"].set_color(_color(k))
        top.set_title(c.name, fontsize=LABEL)
        top.set_ylabel(f"mu ({unit})", fontsize=SMALL)
        bottom.set_ylabel(f"sigma ({unit})", fontsize=SMALL)
        ticks = list(range(1, c.n_clusters + 1))
        top.set_xticks(ticks, [""] * len(ticks))
        bottom.set_xticks(ticks, [str(k) for k in ticks])
        bottom.set_xlabel("cluster (time order)", fontsize=SMALL)
        for ax in (top, bottom):
            ax.tick_params(labelsize=SMALL)
            ax.set_xlim(0.4, max(c.n_clusters, 1) + 0.6)
    for j in range(len(ctxs), rows * cols):
        axes[2 * (j // cols), j % cols].axis("off")
        axes[2 * (j // cols) + 1, j % cols].axis("off")
    fig.suptitle(f"posterior of each cluster's {target} mean and spread (Gibbs sampling, Student-t "
                 "likelihood); colours as in the cluster figure", fontsize=10)
    return fig
