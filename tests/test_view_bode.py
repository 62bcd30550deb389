"""The engineer's Bode and polar PNGs (``replay.views.phase_plots``): ramps as separate traces,
the phase unwrapped through a resonance, slow roll subtracted, criticals marked, speeds labelled."""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib.lines import Line2D

from replay.views.phase_plots import bode_figure, polar_figure, speed_band
from replay.views.view_data import Vectors

FS = 40.0
NC, ZETA = 5000.0, 0.04  # the mode's critical (rpm) and damping
RUNOUT = 0.4 * np.exp(-1j * np.radians(60.0))  # a constant 1x vector (mm/s): the slow roll


def _run(lag0: float, runout: complex = 0) -> tuple[np.ndarray, np.ndarray]:
    """Speed (K,) of one run: up from 500 to 9000 rpm at 100 rpm/s, 30 s on the plateau, down at
    100 rpm/s; its 1x vector (K,): a single mode's unbalance response plus ``runout``, the lag
    offset by lag0 degrees so that the roll through the critical crosses the wrap."""
    up = np.arange(500.0, 9000.0, 100.0 / FS)
    idle = np.full(200, 500.0)
    speed = np.concatenate([idle, up, np.full(int(30 * FS), 9000.0), up[::-1], idle])
    r = speed / NC
    z = 10.0 * r ** 2 / (1 - r ** 2 + 2j * ZETA * r) * np.exp(-1j * np.radians(lag0)) + runout
    return speed, z


def _vectors(runs: list[tuple[np.ndarray, np.ndarray]]) -> Vectors:
    speed = np.concatenate([s for s, _ in runs])
    z = np.concatenate([z for _, z in runs])
    run = np.concatenate([np.full(len(s), k) for k, (s, _) in enumerate(runs)])
    t = 1.77e9 + np.arange(len(speed)) / FS + 600.0 * run
    lag = np.degrees(-np.angle(z))
    nan = np.full(len(speed), np.nan)
    return Vectors(t, speed, run, np.abs(z), (lag + 180.0) % 360.0 - 180.0, nan, nan)


def _traces(ax) -> list[Line2D]:
    return [ln for ln in ax.get_lines() if ln.get_linestyle() in ("-", "--") and len(ln.get_xdata()) > 10]


def test_bode_separates_run_up_and_coast_down_and_unwraps_the_roll():
    fig = bode_figure(_vectors([_run(150.0), _run(100.0)]), "t", "nB", "yB", "mm/s")
    amp_ax, ph_ax = fig.axes
    styles = sorted(ln.get_linestyle() for ln in _traces(amp_ax))
    assert styles == ["-", "-", "--", "--"]  # one run-up and one coast-down per run
    for ln in _traces(ph_ax):
        y = np.asarray(ln.get_ydata(), dtype=float)
        y = y[np.isfinite(y)]
        assert np.max(np.abs(np.diff(y))) < 20.0  # continuous: no jump of a wrap
        assert 150.0 < abs(y[-1] - y[0]) < 185.0  # the roll through the critical, whole
    # the critical marked on every ramp, written with its speed and AF (AF = 1 / (2 zeta) = 12.5)
    marks = [ln for ln in amp_ax.get_lines() if ln.get_marker() == "v"]
    assert len(marks) == 4
    texts = [t.get_text() for t in amp_ax.texts]
    assert texts and all("AF" in t for t in texts)
    for t in texts:
        speed = float(t.split(" rpm")[0].replace(",", ""))
        af = float(t.split("AF ")[1])
        assert abs(speed / NC - 1.0) < 0.01
        assert abs(af / 12.5 - 1.0) < 0.2


def test_slow_roll_compensation_removes_the_runout():
    v = _vectors([_run(0.0, RUNOUT)])
    plain = bode_figure(v, "t", "nB", "yB", "mm/s")
    comp = bode_figure(v, "t", "nB", "yB", "mm/s", slow_roll=(500.0, 800.0))

    def low(fig) -> float:  # the largest plotted amplitude at 500-550 rpm
        lines = _traces(fig.axes[0])
        return max(float(np.max(np.asarray(ln.get_ydata())[np.asarray(ln.get_xdata()) <= 550.0], initial=0.0))
                   for ln in lines)
    assert low(plain) > 0.35  # the runout's 0.4 mm/s shows at slow roll (the mode's response: 0.1)
    assert low(comp) < 0.05  # subtracted, with the band's mean response
    assert "slow roll 500-800 rpm subtracted" in comp.texts[0].get_text()


def test_polar_labels_speeds_along_the_ramps():
    fig = polar_figure(_vectors([_run(0.0)]), "t", "nB", "mm/s")
    labels = [t.get_text() for t in fig.axes[0].texts]
    speeds = sorted({float(x.replace(",", "")) for x in labels})
    assert len(speeds) >= 4 and speeds[0] >= 500.0 and speeds[-1] < 9000.0
    assert all(s % 500.0 == 0 for s in speeds)  # round speeds


def test_a_recording_without_ramps_keeps_every_sample():
    speed = np.full(400, 3000.0)
    z = np.full(400, 2.0 + 0j)
    fig = bode_figure(_vectors([(speed, z)]), "t", "nB", "yB", "mm/s")
    assert "no ramps found" in fig.texts[0].get_text()


@pytest.mark.parametrize("bad", ["1000", "5,1", "a,b", "-1,5", "0,1e7", "nan,5"])
def test_a_bad_speed_band_is_one_line(bad):
    with pytest.raises(ValueError, match="want LO,HI in rpm"):
        speed_band(bad)


def test_the_bode_covers_the_whole_speed_range_and_its_labels_cover_no_data():
    """A short last ramp (9,000 to 9,400 rpm, under the analysis' 10 % of top speed) and the
    plateaus are drawn; every critical's label sits in the strip above the highest amplitude."""
    speed, _ = _run(0.0)
    top = int(np.argmax(speed))
    short = np.linspace(9000.0, 9400.0, 160)
    speed = np.concatenate([speed[:top], short, np.full(1200, 9400.0), short[::-1], speed[top:]])
    r = speed / NC
    z = 10.0 * r ** 2 / (1 - r ** 2 + 2j * ZETA * r)
    fig = bode_figure(_vectors([(speed, z)]), "t", "nB", "yB", "mm/s")
    amp_ax = fig.axes[0]
    xs = np.concatenate([np.asarray(ln.get_xdata(), float) for ln in amp_ax.get_lines()])
    assert xs.max() >= 9400.0 - 1e-9  # the top plateau and the short ramps are there
    ys = np.concatenate([np.asarray(ln.get_ydata(), float) for ln in amp_ax.get_lines()])
    top_frac = np.nanmax(ys) / amp_ax.get_ylim()[1]  # the highest datum, in axes fractions
    labels = [t for t in amp_ax.texts if "AF" in t.get_text()]
    assert labels
    fig.canvas.draw()
    inv = amp_ax.transAxes.inverted()
    boxes = [t.get_window_extent() for t in labels]
    for box in boxes:
        (x0, y0), _ = inv.transform([[box.x0, box.y0], [box.x1, box.y1]])
        assert y0 > top_frac  # the label's lower edge above every datum
    assert not any(a.overlaps(b) for i, a in enumerate(boxes) for b in boxes[i + 1:])  # nor each other
