"""The order's phase in ``ordervib view``: the 1x vector arrays, the polar and Bode views, --plots PNGs."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from test_view import _entities, _verify

from node.cli import main
from node.contract import log_time_ns, monitor_key, phase_channel, sensor_key
from node.mcap import RecordingWriter
from replay.views import rerun_view
from replay.views.view_data import load_view_data, vectors_of

T0 = 1767600000.0
RUN = 1200  # samples per run (30 s)
PNG = b"\x89PNG\r\n\x1a\n"


def _phase(run: int, k: int) -> float | None:
    """Run 1: a constant 30 degrees lag (null at k = 10); run 2: across the wrap, 179.5 and -179.5."""
    if run == 0:
        return None if k == 10 else 30.0
    return 179.5 if k % 2 else -179.5


def _write(path: Path, monitor: bool) -> Path:
    """Two runs 200 s apart: nB ramping to 3000 rpm, yB a constant 2 mm/s, yB_ph as ``_phase``
    (4 ms after the amplitude, as a channel with its own clock phase); with monitor: monitor/yB
    carrying measured_phase, predicted_phase (40 and -170 degrees) and vector_residual."""
    with RecordingWriter(path) as w:
        for run, start in enumerate((T0, T0 + 230.0)):
            for k in range(RUN):
                t = round(start + k / 40, 4)
                pub = log_time_ns(t) + 1_000_000
                w.write(sensor_key("b1", "nB"), t, {"t": t, "v": 3000.0 * k / RUN}, pub)
                w.write(sensor_key("b1", "yB"), t, {"t": t, "v": 2.0}, pub)
                tp = round(t + 0.004, 4)
                w.write(sensor_key("b1", phase_channel("yB")), tp, {"t": tp, "v": _phase(run, k)}, pub)
                if monitor:
                    w.write(monitor_key("b1", "yB"), t, {
                        "t": t, "oc": "OC1", "phase": "steady", "measured": 2.0, "predicted": 2.0,
                        "residual": 0.0, "flag": "ok", "measured_phase": _phase(run, k),
                        "predicted_phase": 40.0 if run == 0 else -170.0, "vector_residual": 0.35,
                    }, pub)
    return path


@pytest.fixture(scope="module")
def phase_rec(tmp_path_factory) -> Path:
    return _write(tmp_path_factory.mktemp("phase") / "sensors.mcap", monitor=False)


@pytest.fixture(scope="module")
def node_phase_rec(tmp_path_factory) -> Path:
    return _write(tmp_path_factory.mktemp("phase") / "node.mcap", monitor=True)


def test_vectors_from_the_phase_channel(phase_rec: Path) -> None:
    data, _, _ = load_view_data(str(phase_rec))
    v = vectors_of(data)
    assert v is not None and not v.has_predicted()
    assert v.run.tolist() == [0] * RUN + [1] * RUN
    first, second = v.measured()[:RUN], v.measured()[RUN:]
    assert np.isnan(first[10]) and np.isfinite(np.delete(first, 10)).all()  # the null phase
    assert np.allclose(np.delete(first, 10), 2.0 * np.exp(-1j * np.pi / 6))  # one point: 30 degrees lag
    assert np.allclose(second, -2.0, atol=2.0 * np.radians(0.5) + 1e-9)  # both sides of the wrap at -2
    assert set(v.phase[RUN:].tolist()) == {179.5, -179.5}  # wrapped, in [-180, 180)
    assert np.allclose(v.speed, 3000.0 * np.tile(np.arange(RUN), 2) / RUN)


def test_vectors_from_the_monitor(node_phase_rec: Path) -> None:
    data, _, _ = load_view_data(str(node_phase_rec))
    v = vectors_of(data)
    assert v is not None and v.has_predicted()
    assert np.allclose(v.predicted()[:RUN], 2.0 * np.exp(-1j * np.radians(40.0)))
    assert np.allclose(v.predicted_phase[RUN:], -170.0)
    assert data.monitor is not None and np.allclose(data.monitor.vector_residual, 0.35)


def _logged(monkeypatch, v) -> dict[str, object]:
    """What the polar and Bode views of v send with rr.log: {entity path: archetype}."""
    sent: dict[str, object] = {}
    monkeypatch.setattr(rerun_view.rr, "log", lambda path, arch, **kw: sent.__setitem__(path, arch))
    rerun_view.log_polar(v, "nB", "mm/s")
    rerun_view.log_bode(v, "nB", "yB", "mm/s")
    return sent


def _positions(arch) -> np.ndarray:
    return np.array(arch.positions.as_arrow_array().to_pylist())


def test_polar_points_in_rerun(phase_rec: Path, monkeypatch) -> None:
    data, _, _ = load_view_data(str(phase_rec))
    v = vectors_of(data)
    assert v is not None
    sent = _logged(monkeypatch, v)
    assert "polar/predicted/run1" not in sent and "polar/axes/lines" in sent
    s = rerun_view.POLAR_SIZE / rerun_view.polar_grid(2.0 * 1.05)[1]
    first = _positions(sent["polar/measured/run1"])
    assert len(first) == RUN - 1  # the null phase left out
    # x = Re, y = -Im (Rerun's y points down): a 30 degrees lag is drawn clockwise from the right
    assert np.allclose(first, [2.0 * s * np.cos(np.pi / 6), 2.0 * s * np.sin(np.pi / 6)], atol=1e-5)
    second = _positions(sent["polar/measured/run2"])
    assert np.allclose(second[:, 0], -2.0 * s, atol=1e-3) and np.abs(second[:, 1]).max() < 0.02 * s
    phase = _positions(sent["bode/phase/measured/run2"])
    sx, sy = rerun_view.curve_scale(3000.0 * (RUN - 1) / RUN * 1.05, 360.0)
    assert np.allclose(np.abs(phase[:, 1]), 179.5 * sy, atol=1e-4)  # wrapped: at the top and the bottom


def test_node_recording_with_phase(node_phase_rec: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "node.rrd"
    assert main(["view", str(node_phase_rec), "--save", str(out), "--plots", str(tmp_path)]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 2 and "with predicted" in lines[0] and f"{2 * RUN - 1} 1x vectors" in lines[1]
    _verify(out)
    printed = _entities(out)
    for entity in ("/polar/measured/run1", "/polar/predicted/run2", "/polar/axes/speed",
                   "/bode/amplitude/axes", "/bode/phase/predicted/run1", "/residual/vector", "/curve/run2"):
        assert entity in printed, entity
    for kind in ("polar", "bode"):
        assert (tmp_path / f"b1-yB-{kind}.png").read_bytes().startswith(PNG)


def test_plots_without_a_viewer(phase_rec: Path, tmp_path: Path, monkeypatch, capsys) -> None:
    monkeypatch.setattr(sys, "platform", "linux")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    for _ in range(2):  # the second time replaces both files whole
        assert main(["view", str(phase_rec), "--plots", str(tmp_path)]) == 0
    line = capsys.readouterr().out.strip()
    assert line.count("plots: bed b1, yB") == 2 and "with predicted" not in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b1-yB-bode.png", "b1-yB-polar.png"]
    import matplotlib.image

    for kind in ("polar", "bode"):
        png = tmp_path / f"b1-yB-{kind}.png"
        assert png.read_bytes().startswith(PNG)
        assert matplotlib.image.imread(png).shape[0] > 300


def test_plots_options_checked_before_output(phase_rec: Path, tmp_path: Path, capsys) -> None:
    rrd = tmp_path / "x.rrd"
    assert main(["view", str(phase_rec), "--plots", str(tmp_path / "nope"), "--save", str(rrd)]) == 2
    (tmp_path / "b1-yB-polar.png").mkdir()  # in the way of the first plot
    assert main(["view", str(phase_rec), "--plots", str(tmp_path), "--save", str(rrd)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and "nope" in err[0] and "is a directory" in err[1]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b1-yB-polar.png"]  # no rrd, no bode plot
