"""ordervib view --save: Rerun files of a node recording and of a sensor-only one, checked by Rerun's CLI."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from node.cli import main
from node.contract import log_time_ns, sensor_key
from node.mcap import RecordingWriter
from replay.views.rerun_view import GAP_SHOWN, Clock

ROOT = Path(__file__).resolve().parents[1]
FAULT = ROOT / "recordings" / "engine1_fault.mcap"
T0 = 1767600000.0


def _rerun_cli() -> str | None:
    """Rerun's CLI beside this Python (the venv), else on PATH."""
    local = Path(sys.executable).parent / "rerun"
    return str(local) if local.exists() else shutil.which("rerun")


def _verify(rrd: Path) -> None:
    cli = _rerun_cli()
    if cli is None:
        pytest.skip("Rerun CLI not available")
    res = subprocess.run([cli, "rrd", "verify", str(rrd)], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr[-2000:]


def _entities(rrd: Path) -> str:
    cli = _rerun_cli()
    if cli is None:
        pytest.skip("Rerun CLI not available")
    return subprocess.run([cli, "rrd", "print", str(rrd)], capture_output=True, text=True, timeout=120).stdout


@pytest.fixture(scope="module")
def node_rec(tmp_path_factory) -> Path:
    """A small node recording: two runs 120 s apart, sensors + monitor/yB, monitor/oc, health."""
    path = tmp_path_factory.mktemp("view") / "node.mcap"
    with RecordingWriter(path) as w:
        for start in (T0, T0 + 40.0 + 120.0):
            t = start + np.arange(1600) / 40
            nb = np.clip(np.minimum(t - start, 40 - (t - start)) * 400, 0, 4000)
            yb = 0.5 + nb / 4000 + np.where(t - start > 30, 1.0, 0.0)  # a step fault late in the run
            pred = 0.5 + nb / 4000
            score = 0.0
            state = None
            for k in range(len(t)):
                tk = round(float(t[k]), 4)
                pub = log_time_ns(tk) + 1_000_000
                w.write(sensor_key("b1", "nB"), tk, {"t": tk, "v": float(nb[k])}, pub)
                w.write(sensor_key("b1", "yB"), tk, {"t": tk, "v": None if k == 50 else float(yb[k])}, pub)
                oc = "OC1" if nb[k] > 3900 else None
                phase = "steady" if oc else "off"
                if (oc, phase) != state:
                    w.write(
                        "testbed/b1/monitor/oc",
                        tk,
                        {"t": tk, "oc": oc, "phase": phase, "previous": state[0] if state else None},
                        pub,
                    )
                    state = (oc, phase)
                r = float(yb[k] - pred[k])
                score = 0.9 * score + 0.1 * r / 0.1
                flag = "no-model" if oc is None else ("alarm" if abs(score) > 3 else "ok")
                w.write(
                    "testbed/b1/monitor/yB",
                    tk,
                    {
                        "t": tk,
                        "oc": oc,
                        "phase": phase,
                        "measured": float(yb[k]),
                        "predicted": float(pred[k]),
                        "residual": r,
                        "flag": flag,
                        "score": score,
                        "band": 0.3,
                        "model": "test",
                    },
                    pub,
                )
                if k % 40 == 0:
                    w.write(
                        "testbed/b1/monitor/health",
                        tk,
                        {
                            "t": tk,
                            "samples": k,
                            "late": 0,
                            "missing": {"nB": 0, "yB": 1},
                            "malformed": 0,
                            "dropped": 0,
                            "lag_ms_p50": 0.5,
                            "lag_ms_p99": 2.0,
                        },
                        pub,
                    )
    return path


def test_clock_shortens_gaps_between_runs() -> None:
    t = np.concatenate([T0 + np.arange(10) / 40, T0 + 500 + np.arange(10) / 40])
    clock = Clock(t)
    e = clock(t)
    assert e[0] == 0.0 and np.isclose(e[10] - e[9], GAP_SHOWN)
    assert np.allclose(np.diff(e[:10]), 1 / 40) and np.allclose(np.diff(e[10:]), 1 / 40)
    assert clock.run_index(t).tolist() == [0] * 10 + [1] * 10


def test_view_node_recording(node_rec: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "node.rrd"
    assert main(["view", str(node_rec), "--save", str(out)]) == 0
    line = capsys.readouterr().out.strip()
    assert "2 runs" in line and "monitor 3200" in line and "OCs from monitor/oc" in line
    assert out.stat().st_size > 10_000 and not Path(str(out) + ".part").exists()
    _verify(out)
    printed = _entities(out)
    for entity in (
        "/speed/nB",
        "/target/predicted",
        "/target/upper",
        "/target/alarm",
        "/residual/residual",
        "/score/score",
        "/state/oc",
        "/curve/run1",
        "/curve/run2",
        "/health/lag_ms_p99",
    ):
        assert entity in printed, entity


# the data entities of node_rec's view (its view before the order's phase was shown)
NO_PHASE_ENTITIES = {
    "/speed/nB", "/state/oc", "/state/phase", "/state/flag", "/log/oc",
    "/target/measured", "/target/predicted", "/target/upper", "/target/lower", "/target/alarm",
    "/residual/residual", "/residual/upper", "/residual/lower", "/residual/alarm",
    "/score/score", "/score/alarm",
    "/health/lag_ms_p50", "/health/lag_ms_p99", "/health/late", "/health/missing", "/health/dropped",
    "/health/malformed",
    "/curve/run1", "/curve/run2", "/curve/alarm", "/curve/axes/lines", "/curve/axes/labels",
}


def _origins(container) -> list[str]:
    """The views' origins in a blueprint container, depth first (Tabs as "tabs")."""
    out = ["tabs"] if type(container).__name__ == "Tabs" else []
    for c in container.contents:
        out += _origins(c) if hasattr(c, "contents") and not hasattr(c, "origin") else [str(c.origin)]
    return out


def test_no_phase_view_is_unchanged(node_rec: Path, tmp_path: Path, capsys) -> None:
    from replay.views.rerun_view import blueprint
    from replay.views.view_data import load_view_data, vectors_of

    data, _, _ = load_view_data(str(node_rec))
    assert vectors_of(data) is None
    assert _origins(blueprint(data).root_container) == [
        "/speed", "/state", "/target", "/residual", "/score", "/curve", "/log", "/health"]
    out = tmp_path / "node.rrd"
    assert main(["view", str(node_rec), "--save", str(out)]) == 0
    assert "1x vectors" not in capsys.readouterr().out
    data_entities = {e for e in re.findall(r" - (/\S+) - ", _entities(out))
                     if not e.startswith(("/view/", "/container/", "/viewport", "/__properties"))
                     and not e.endswith("_panel")}
    assert data_entities == NO_PHASE_ENTITIES
    # --plots needs the order's phase: one line naming the channel, nothing written
    plots = tmp_path / "plots"
    plots.mkdir()
    assert main(["view", str(node_rec), "--plots", str(plots), "--save", str(tmp_path / "x.rrd")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "yB_ph" in err[0] and "testbed/b1/sensor/yB_ph" in err[0]
    assert not any(plots.iterdir()) and not (tmp_path / "x.rrd").exists()


def test_view_sensor_only_recording(tmp_path: Path, capsys) -> None:
    out = tmp_path / "fault.rrd"
    assert main(["view", str(FAULT), "--save", str(out)]) == 0
    line = capsys.readouterr().out
    assert "monitor 0" in line and "schedule (OC detector)" in line  # the sidecar schedule
    _verify(out)


@pytest.mark.parametrize("content", [b"", b"not an mcap file at all\n"])
def test_bad_file_is_one_line_exit_2(tmp_path: Path, capsys, content: bytes) -> None:
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(content)
    assert main(["view", str(bad), "--save", str(tmp_path / "x.rrd")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "bad.mcap" in err
    assert not (tmp_path / "x.rrd").exists()


def test_bad_options_are_one_line(node_rec: Path, tmp_path: Path, capsys) -> None:
    assert main(["view", str(node_rec), "--save", str(tmp_path / "x.txt")]) == 2
    assert main(["view", str(node_rec), "--bed", "nope", "--save", str(tmp_path / "x.rrd")]) == 2
    assert main(["view", str(node_rec), "--target", "yZ", "--save", str(tmp_path / "x.rrd")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and ".rrd" in err[0] and "b1" in err[1] and "yZ" in err[2]


def test_no_display_suggests_save(node_rec: Path, monkeypatch, capsys) -> None:
    monkeypatch.setattr(sys, "platform", "linux")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert main(["view", str(node_rec)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--save" in err[0]


def test_sensor_series_follow_the_payload_rule() -> None:
    from node.contract import decode_samples
    from replay.views.view_data import series_of

    payloads = [b'{"t": 3.0, "v": 1.5}', b'{"t": 1.0, "v": null}', b'{"t": 2.0, "v": "x"}',
                b'{"t": true, "v": 1}', b'{"t": -1.0, "v": 1}', b'not json', b'{"t": 2, "v": 7}']
    s = series_of(payloads)
    t, _, ok = decode_samples(payloads)
    assert s.t.tolist() == sorted(t[ok].tolist()) == [1.0, 2.0, 3.0]
    assert np.isnan(s.v[0]) and s.v[1:].tolist() == [7.0, 1.5]
