"""The rho_DPCCA heatmap of the report's panel II (dissertation section 3.4.2, figure 3.8).

For each OC visit of each run (``segment_runs``: its transition and plateau), the mean
|rho_DPCCA| over the usable scales between the target and every other channel the run holds
(``node.training.features.segment_term``, the very measure training ranks its inputs by),
one row per (OC, run), the rows grouped by OC; values below ``MASK`` are left white, as the
figure of the dissertation masks the weak ones. The correlation structure changing from OC to
OC is what makes a switching model worth it; its rows varying within an OC are the runs'
thermal and operating differences.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from matplotlib.figure import Figure

from node.contract import is_phase_channel
from node.contract.schedule import Schedule
from node.training.dataset import fill_gaps, segment_runs
from node.training.features import segment_term
from node.training.runs import Run

MASK = 0.2  # |rho_DPCCA| below it is not drawn (figure 3.8 masks the weak correlations alike)
MIN_SAMPLES = 400  # an OC visit shorter than 10 s at 40 Hz gives no row
MAX_ROWS = 240  # rows beyond it (OC visits) are left out of the figure, said in its caption


def dpcca_rows(runs: Sequence[Run], schedule: Schedule, target: str
               ) -> tuple[list[str], list[str], np.ndarray]:
    """(row labels "OC · run k", channels (C,), |rho_DPCCA| (rows, C), NaN where a channel does not
    vary in the visit): every OC visit of every run with the target, in OC order then run order."""
    channels = sorted({c for r in runs for c in r.channels if c != target and not is_phase_channel(c)})
    rows: list[tuple[int, int, np.ndarray]] = []
    for s in segment_runs(list(runs), schedule):
        run = runs[s.run]
        if target not in run.channels or s.length < MIN_SAMPLES:
            continue
        have = [c for c in channels if c in run.channels]
        X = fill_gaps(np.column_stack([run.column(c)[s.start:s.stop] for c in [target, *have]]))
        keep = np.isfinite(X).all(axis=0)  # a channel missing from the visit's start: left out
        if not keep[0] or keep.sum() < 2:
            continue
        X, have = X[:, keep], [c for c, ok in zip(have, keep[1:].tolist()) if ok]
        term = segment_term(X, 0)
        value = np.full(len(channels), np.nan)
        if term is not None:
            cols, score, k = term
            for col, v in zip(cols.tolist(), (score / k).tolist()):
                if col > 0:
                    value[channels.index(have[col - 1])] = v
        rows.append((s.oc, s.run, value))
    rows.sort(key=lambda x: (x[0], x[1]))
    labels = [f"{schedule.segments[o]} · run {r + 1}" for o, r, _ in rows]
    return labels, channels, np.array([v for _, _, v in rows]).reshape(len(rows), len(channels))


def dpcca_figure(labels: Sequence[str], channels: Sequence[str], values: np.ndarray, target: str) -> Figure:
    """The heatmap (rows: OC visits, grouped by OC; columns: channels), masked below ``MASK``."""
    n = min(len(labels), MAX_ROWS)
    fig = Figure(figsize=(min(11.5, max(6.0, 0.45 * len(channels) + 2.5)), max(4.0, 0.1 * n + 1.8)),
                 layout="constrained")
    ax = fig.subplots()
    shown = np.where(values[:n] >= MASK, values[:n], np.nan)
    im = ax.imshow(shown, aspect="auto", cmap="viridis", vmin=MASK, vmax=1.0, interpolation="nearest")
    ax.set_xticks(range(len(channels)), channels, rotation=60, ha="right", fontsize=10)
    ocs = [lab.split(" · ")[0] for lab in labels[:n]]
    starts = [k for k in range(n) if k == 0 or ocs[k] != ocs[k - 1]]
    for k in starts[1:]:  # a line between OCs
        ax.axhline(k - 0.5, color="black", lw=0.8)
    ends = [*starts[1:], n]
    ax.set_yticks([(a + b - 1) / 2 for a, b in zip(starts, ends)], [ocs[a] for a in starts], fontsize=10)
    ax.set_ylabel("OC (a row per run, in run order)")
    fig.colorbar(im, ax=ax, label=f"|rho_DPCCA| with {target}")
    ax.set_title(f"{target}: |rho_DPCCA| per OC visit (below {MASK} not drawn)", fontsize=11)
    return fig
