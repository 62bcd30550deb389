"""ordervib simulate: contract conformance, determinism, ground truth, bad options."""

from __future__ import annotations

import json
import re
from collections import defaultdict
from pathlib import Path

import numpy as np
import orjson
import pytest
from mcap.reader import NonSeekingReader, make_reader

from node.cli import main
from node.recording import SENSOR_CHANNELS, read_runs
from simulator.campaign import simulate_campaign

KEY = re.compile(r"^testbed/([^/]+)/sensor/([^/]+)$")
# Shorter plateaus keep the suite fast; the layout does not depend on them.
FAST = ["--plateau-scale", "0.05", "--quiet"]


@pytest.fixture(scope="module")
def rec3(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("sim") / "x.mcap"
    assert main(["simulate", "--runs", "3", "--seed", "7", "--out", str(out), *FAST]) == 0
    return out


def test_file_opens_with_the_plain_mcap_reader(rec3: Path) -> None:
    with open(rec3, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics.message_count > 0
        assert {c.topic for c in summary.channels.values()} == {
            f"testbed/bed1/sensor/{c}" for c in SENSOR_CHANNELS
        }
        first = next(iter(reader.iter_messages()))
        assert first[1].message_encoding == "json"


def test_every_message_follows_the_contract(rec3: Path) -> None:
    rows: list[tuple[int, int, int, bytes]] = []
    channels = {}
    with open(rec3, "rb") as f:
        reader = NonSeekingReader(f)  # the plain library, in file order
        for schema, channel, msg in reader.iter_messages(log_time_order=False):
            if channel.id not in channels:
                channels[channel.id] = (schema, channel)
            rows.append((channel.id, msg.log_time, msg.publish_time, msg.data))
    for schema, channel in channels.values():
        m = KEY.match(channel.topic)
        assert m and m.group(1) == "bed1" and m.group(2) in SENSOR_CHANNELS
        assert schema.encoding == "jsonschema"
        assert json.loads(schema.data)["type"] == "object"
        assert channel.message_encoding == "json"
    assert {KEY.match(c.topic).group(2) for _, c in channels.values()} == set(SENSOR_CHANNELS)
    payloads = orjson.loads(b"[" + b",".join(r[3] for r in rows) + b"]")
    times: dict[int, list[float]] = defaultdict(list)
    for (cid, log_time, publish_time, _), payload in zip(rows, payloads, strict=True):
        assert payload.keys() == {"t", "v"}
        t, v = payload["t"], payload["v"]
        assert type(t) is float and (v is None or type(v) is float)
        assert log_time == round(t * 1e9)
        assert 0 < publish_time - log_time < 20_000_000  # received soon after
        times[cid].append(t)
    for t in times.values():
        dt = np.diff(np.sort(t))
        gaps = dt[dt >= 60.0]
        assert len(gaps) == 2  # three runs, separated by shutdowns
        steps = dt[dt < 60.0]
        assert np.all(np.abs(steps - 0.025) < 0.004)  # 40 Hz with < 2 ms jitter
        assert abs(np.median(steps) - 0.025) < 1e-4


def test_sidecars_describe_the_runs(rec3: Path) -> None:
    truth = json.loads(rec3.with_suffix(".truth.json").read_text())
    schedule = rec3.with_suffix(".schedule.toml").read_text()
    assert 'switch = "nB"' in schedule and schedule.count("[[oc]]") == 12
    assert len(truth["runs"]) == 3
    assert truth["runs"][0]["shutdown_before_s"] is None
    for r in truth["runs"]:
        assert [oc["name"] for oc in r["ocs"]][:2] == ["OC2a", "OC3"]
        for oc in r["ocs"]:
            assert oc["transition_start"] <= oc["steady_start"] < oc["end"]
    for a, b in zip(truth["runs"][:-1], truth["runs"][1:], strict=False):
        assert b["shutdown_before_s"] >= 60.0
        assert b["engine_start"] - a["engine_stop"] == pytest.approx(b["shutdown_before_s"])


def test_read_runs_matches_truth(rec3: Path) -> None:
    truth = json.loads(rec3.with_suffix(".truth.json").read_text())["runs"]
    runs = read_runs(rec3)
    assert len(runs) == 3
    for run, tr in zip(runs, truth, strict=True):
        assert run.data.shape == (len(run.t), len(SENSOR_CHANNELS))
        assert run.channels == SENSOR_CHANNELS and run.bed == "bed1"
        assert run.t[0] == pytest.approx(tr["engine_start"], abs=0.03)
        if tr["shutdown_before_s"] is None:
            assert run.shutdown_before is None
        else:
            assert run.shutdown_before == pytest.approx(tr["shutdown_before_s"], abs=0.1)
        assert np.isnan(run.data).any()  # dropouts arrive as NaN
        assert np.nanmax(run.column("nB")) == pytest.approx(9800.0, rel=0.01)


def test_same_seed_same_bytes_other_seed_differs(tmp_path: Path) -> None:
    paths = []
    for name, seed in (("a", "5"), ("b", "5"), ("c", "6")):
        out = tmp_path / f"{name}.mcap"
        argv = ["simulate", "--runs", "2", "--seed", seed, "--out", str(out), "--channels", "nB,yB"]
        assert main([*argv, *FAST]) == 0
        paths.append(out)
    a, b, c = (p.read_bytes() for p in paths)
    assert a == b and a != c
    for suffix in (".truth.json", ".schedule.toml"):
        assert paths[0].with_suffix(suffix).read_bytes() == paths[1].with_suffix(suffix).read_bytes()


def test_runs_prefix_is_stable_and_faults_hit_the_last_run() -> None:
    short = simulate_campaign(2, 11, plateau_scale=0.05)
    longer = simulate_campaign(3, 11, fault="stiffness", plateau_scale=0.05)
    for a, b in zip(short.runs, longer.runs[:2], strict=True):
        np.testing.assert_array_equal(a.data, b.data)
    fault = longer.runs[-1].truth["fault"]
    assert fault["kind"] == "stiffness"
    assert longer.runs[-1].t[0] < fault["onset"] < longer.runs[-1].t[-1]


@pytest.mark.parametrize("kind", ["stuck-sensor", "drift", "imbalance"])
def test_fault_changes_yb_after_onset_only(kind: str) -> None:
    healthy = simulate_campaign(1, 3, plateau_scale=0.05).runs[0]
    faulty = simulate_campaign(1, 3, fault=kind, plateau_scale=0.05).runs[0]
    j = SENSOR_CHANNELS.index("yB")
    before = faulty.t < faulty.truth["fault"]["onset"]
    np.testing.assert_array_equal(healthy.data[before, j], faulty.data[before, j])
    after = ~before
    assert not np.allclose(healthy.data[after, j], faulty.data[after, j], equal_nan=True)
    if kind == "stuck-sensor":
        assert np.unique(faulty.data[after, j]).size == 1


def test_fault_size_scales_the_drift() -> None:
    j = SENSOR_CHANNELS.index("yB")
    healthy = simulate_campaign(1, 3, plateau_scale=0.05).runs[0]
    one, two = (simulate_campaign(1, 3, fault="drift", plateau_scale=0.05, fault_size=x).runs[0]
                for x in (1.0, 2.0))
    assert one.truth["fault"]["size"] == 1.0 and two.truth["fault"]["size"] == 2.0
    assert one.truth["fault"]["onset"] == two.truth["fault"]["onset"]
    after = one.t >= one.truth["fault"]["onset"]
    assert after.sum() > 100
    added1 = one.data[after, j] - healthy.data[after, j]
    added2 = two.data[after, j] - healthy.data[after, j]
    ok = ~np.isnan(added1)
    assert ok.sum() > 100
    assert added1[ok][-1] > 0.1  # the drift has grown well past the rounding by the end
    # the drifted value is rounded to 2 decimals: |round(2d) - 2 round(d)| <= 0.01
    np.testing.assert_allclose(added2[ok], 2.0 * added1[ok], rtol=0, atol=0.011)


@pytest.mark.parametrize("size", [0.0, -1.0])
def test_fault_size_must_be_positive(size: float) -> None:
    with pytest.raises(ValueError, match="fault_size"):
        simulate_campaign(1, 3, fault="drift", plateau_scale=0.05, fault_size=size)


def test_hot_restart_has_more_bow_than_cold() -> None:
    runs = simulate_campaign(6, 2, plateau_scale=0.05).runs
    gaps = [r.truth["shutdown_before_s"] for r in runs[1:]]
    bows = [r.truth["bow_start_mm"]["yB"] for r in runs[1:]]
    assert runs[0].truth["bow_start_mm"]["yB"] == 0.0
    # Shortest shutdown among the restarts (>= 10 min) bows more than the longest.
    assert bows[int(np.argmin(gaps))] > bows[int(np.argmax(gaps))]


@pytest.mark.parametrize(
    "argv",
    [
        ["--runs", "0"],
        ["--runs", "two"],
        ["--seed", "-1"],
        ["--fault", "meteor"],
        ["--bed", "a/b"],
        ["--skip", "3"],
        ["--plateau-scale", "0"],
        ["--channels", "nB,zZ"],
        ["--fault", "drift", "--fault-size", "0"],
        ["--fault-size", "2"],
    ],
)
def test_bad_options_one_line_exit_2(
    argv: list[str], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "x.mcap"
    try:
        code = main(["simulate", "--out", str(out), *argv])
    except SystemExit as exc:  # argparse errors exit through the parser
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert not out.exists()


def test_missing_output_directory(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["simulate", "--out", str(tmp_path / "no" / "x.mcap"), "--quiet"])
    assert code == 2
    assert "does not exist" in capsys.readouterr().err
