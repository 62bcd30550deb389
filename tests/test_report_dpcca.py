"""The report's rho_DPCCA heatmap (``replay.report.correlation``): per OC visit, the channel the
target follows there stands out, and the structure switches with the OC as it was built to."""

from __future__ import annotations

import numpy as np

from node.contract.schedule import OperatingCondition, Schedule
from node.training.runs import Run
from replay.report.correlation import MASK, dpcca_figure, dpcca_rows

SCHED = Schedule((OperatingCondition("A", 4000.0), OperatingCondition("B", 6000.0)))


def _run(seed: int) -> Run:
    """Idle, then 60 s at A, then 60 s at B (40 Hz): yB follows x1 at A and x2 at B; x3 is noise."""
    rng = np.random.default_rng(seed)
    k_idle, k_ramp, k_plat = 400, 200, 2400
    nB = np.concatenate([np.full(k_idle, 0.0), np.linspace(0, 4000, k_ramp), np.full(k_plat, 4000.0),
                         np.linspace(4000, 6000, k_ramp), np.full(k_plat, 6000.0)])
    nB = nB + rng.normal(0, 2.0, nB.size)
    n = nB.size
    x1, x2, x3 = (np.cumsum(rng.normal(0, 1, n)) for _ in range(3))
    at_b = np.arange(n) >= k_idle + k_ramp + k_plat
    yB = np.where(at_b, 0.8 * x2, 0.8 * x1) + rng.normal(0, 0.5, n)
    data = np.column_stack([nB, yB, x1, x2, x3, np.full(n, 1.0)])
    names = ("nB", "yB", "x1", "x2", "x3", "const")
    return Run(1.7e9 + seed * 1e4 + np.arange(n) / 40.0, data, names, "b", None)


def test_the_channel_the_target_follows_stands_out_per_oc():
    labels, channels, values = dpcca_rows([_run(1), _run(2)], SCHED, "yB")
    assert channels == ["const", "nB", "x1", "x2", "x3"]
    assert [lab.split(" · ")[0] for lab in labels] == ["A", "A", "B", "B"]  # grouped by OC, a row per run
    col = {c: channels.index(c) for c in channels}
    assert np.isnan(values[:, col["const"]]).all()  # a constant channel has no correlation
    for lab, row in zip(labels, values):
        own, other = ("x1", "x2") if lab.startswith("A") else ("x2", "x1")
        assert row[col[own]] > 0.6
        assert row[col[other]] < MASK and row[col["x3"]] < MASK


def test_the_figure_masks_the_weak_ones():
    labels, channels, values = dpcca_rows([_run(3)], SCHED, "yB")
    fig = dpcca_figure(labels, channels, values, "yB")
    shown = fig.axes[0].images[0].get_array()
    assert np.ma.count_masked(shown) + np.isnan(np.ma.filled(shown, np.nan)).sum() > 0
    assert np.nanmin(np.ma.filled(shown, np.nan)) >= MASK
    assert [t.get_text() for t in fig.axes[0].get_yticklabels()] == ["A", "B"]  # the OCs named
