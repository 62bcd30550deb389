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
from node.contract import ORDER_CHANNELS, PHASE_CHANNELS, SENSOR_CHANNELS
from node.training.runs import read_runs
from simulator.campaign import simulate_campaign

KEY = re.compile(r"^testbed/([^/]+)/sensor/([^/]+)$")
# Shorter plateaus keep the suite fast; the layout does not depend on them.
FAST = ["--plateau-scale", "0.05", "--quiet"]
PUBLISHED = (*SENSOR_CHANNELS, *PHASE_CHANNELS)  # what simulate writes by default


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
            f"testbed/bed1/sensor/{c}" for c in PUBLISHED
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
        assert m and m.group(1) == "bed1" and m.group(2) in PUBLISHED
        assert schema.encoding == "jsonschema"
        assert json.loads(schema.data)["type"] == "object"
        assert channel.message_encoding == "json"
    assert {KEY.match(c.topic).group(2) for _, c in channels.values()} == set(PUBLISHED)
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
        assert run.data.shape == (len(run.t), len(PUBLISHED))
        assert run.channels == PUBLISHED and run.bed == "bed1"
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


# --- --schedule and --noise-scale ---------------------------------------------------------

OTHER = """
switch = "nB"
tolerance = 0.03

[[oc]]
name = "low"
speed = 4300.0
plateau = 60
rate = 80

[[oc]]
name = "res1"
speed = 8200.0
plateau = 90.5

[[oc]]
name = "back"
speed = 6100.0
rate = 140

[[oc]]
name = "res2"
speed = 9450.0
plateau = 75
rate = 60

[[oc]]
name = "idle-ish"
speed = 3000.0
"""


def _sched(tmp_path: Path, text: str = OTHER, name: str = "s.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_custom_schedule_is_run(tmp_path: Path) -> None:
    from node.contract.schedule import load_schedule
    from simulator.schedule import load_sim_schedule

    path = _sched(tmp_path)
    out = tmp_path / "o.mcap"
    argv = ["simulate", "--runs", "2", "--seed", "4", "--schedule", str(path), "--out", str(out),
            "--channels", "nB,yB", "--plateau-scale", "0.1", "--quiet"]
    assert main(argv) == 0
    truth = json.loads(out.with_suffix(".truth.json").read_text())
    want = [("low", 4300.0, 60.0, 80.0), ("res1", 8200.0, 90.5, 90.0), ("back", 6100.0, 40.0, 140.0),
            ("res2", 9450.0, 75.0, 60.0), ("idle-ish", 3000.0, 40.0, 90.0)]
    sched = truth["schedule"]
    assert sched["source"] == str(path) and sched["tolerance"] == 0.03
    assert [(o["name"], o["speed"], o["plateau_s"], o["rate_rpm_s"]) for o in sched["oc"]] == want
    assert truth["noise_scale"] == 1.0
    # the sidecar is that schedule: the node reads the same OCs from both files
    assert load_schedule(out.with_suffix(".schedule.toml")) == load_schedule(path)
    # ... and the simulator's: the same OCs with their timing (the same digest)
    assert load_sim_schedule(out.with_suffix(".schedule.toml")).digest() == sched["sha256"]
    runs = read_runs(out, ["nB"])
    prev = 2600.0
    for run, tr in zip(runs, truth["runs"], strict=True):
        assert [(o["name"], o["speed"]) for o in tr["ocs"]] == [w[:2] for w in want]
        for oc, (_, speed, plateau, rate) in zip(tr["ocs"], want, strict=True):
            steady = oc["end"] - oc["steady_start"]
            assert 0.8 * 0.1 * plateau - 1e-9 <= steady <= 1.25 * 0.1 * plateau + 1e-9
            ramp = oc["steady_start"] - oc["transition_start"]
            assert ramp == pytest.approx(max(abs(speed - prev) / (rate * 1.7), 1.0), rel=1.0)
            assert abs(speed - prev) / (rate * 1.7) - 1e-9 <= ramp
            assert ramp <= max(abs(speed - prev) / (rate * 0.6), 1.0) + 1e-9
            prev = speed
            # the spool has settled by the plateau's last second: nB at the schedule's speed
            last = (run.t >= oc["end"] - 1.0) & (run.t < oc["end"])
            assert np.nanmedian(run.column("nB")[last]) == pytest.approx(speed, rel=0.005)
        prev = 2600.0


def test_fault_onset_in_the_middle_ocs() -> None:
    from simulator.schedule import DEFAULT_OCS, OC, SimSchedule, fault_candidates, make_profile

    prof = make_profile(np.random.default_rng(0), DEFAULT_OCS)
    assert [s.name for s in fault_candidates(prof.segments)] == ["OC6", "OC7", "OC8", "OC9", "OC10"]
    eight = tuple(OC(f"S{i}", 3000.0 + 800 * i, 30.0, 90.0) for i in range(8))
    prof8 = make_profile(np.random.default_rng(0), eight)
    assert [s.name for s in fault_candidates(prof8.segments)] == ["S3", "S4", "S5"]
    one = make_profile(np.random.default_rng(0), eight[:1])
    assert [s.name for s in fault_candidates(one.segments)] == ["S0"]
    sched = SimSchedule(eight, source="eight")
    for seed in range(4):
        run = simulate_campaign(1, seed, fault="drift", plateau_scale=0.1, schedule=sched).runs[0]
        f = run.truth["fault"]
        assert f["oc"] in ("S3", "S4", "S5")
        oc = next(o for o in run.truth["ocs"] if o["name"] == f["oc"])
        assert oc["steady_start"] < f["onset"] < oc["end"]


def test_twins_hold_with_a_schedule_and_noise_scale(tmp_path: Path) -> None:
    from simulator.schedule import load_sim_schedule

    sched = load_sim_schedule(_sched(tmp_path))
    kw = dict(plateau_scale=0.1, schedule=sched, noise_scale=2.0)
    healthy = simulate_campaign(2, 8, **kw)
    j = SENSOR_CHANNELS.index("yB")
    for kind in ("imbalance", "stiffness", "drift"):
        faulty = simulate_campaign(2, 8, fault=kind, **kw)
        np.testing.assert_array_equal(healthy.runs[0].data, faulty.runs[0].data)
        a, b = healthy.runs[1], faulty.runs[1]
        before = b.t < b.truth["fault"]["onset"]
        np.testing.assert_array_equal(a.data[before], b.data[before])
        assert not np.array_equal(a.data[~before, j], b.data[~before, j], equal_nan=True)


def test_noise_scale_2_doubles_the_noise() -> None:
    from simulator.campaign import _measure, _noise_spec

    k = 200_000
    typical = {"n": 5000.0, "y": 5.0, "t": 300.0, "p": 200.0, "M1": 1.0, "M2": 50.0}
    clean = {c: np.full(k, typical.get(c) or typical[c[0]]) for c in SENSOR_CHANNELS}
    measured = {}
    for scale in (1.0, 2.0):
        m = _measure(np.random.default_rng(5), clean, SENSOR_CHANNELS, scale)
        measured[scale] = m
    # same draws: the same dropouts, and the noise itself doubled (up to the rounding)
    np.testing.assert_array_equal(np.isnan(measured[1.0]), np.isnan(measured[2.0]))
    for j, c in enumerate(SENSOR_CHANNELS):
        absolute, relative, decimals = _noise_spec(c)
        sigma = absolute + relative * clean[c][0]
        q2 = (10.0 ** -decimals) ** 2 / 12.0  # rounding adds a uniform error's variance
        for scale in (1.0, 2.0):
            e = measured[scale][:, j] - clean[c]
            e = e[~np.isnan(e)]
            assert np.std(e) == pytest.approx(np.sqrt((scale * sigma) ** 2 + q2), rel=0.03), c
    # through the CLI: the truth records the scale, and the run is the default run's clean
    # signal plus twice its noise (the same draws): difference = the default noise, sigma 0.4 C
    one = simulate_campaign(1, 2, plateau_scale=0.1).runs[0]
    two = simulate_campaign(1, 2, plateau_scale=0.1, noise_scale=2.0).runs[0]
    j = SENSOR_CHANNELS.index("tB")
    d = (two.data[:, j] - one.data[:, j])
    assert np.nanstd(d) == pytest.approx(np.sqrt(0.4**2 + 2 * 0.1**2 / 12), rel=0.05)


def test_noise_scale_in_truth(tmp_path: Path) -> None:
    out = tmp_path / "n.mcap"
    assert main(["simulate", "--runs", "1", "--seed", "2", "--noise-scale", "2.5", "--out", str(out),
                 "--channels", "nB", *FAST]) == 0
    truth = json.loads(out.with_suffix(".truth.json").read_text())
    assert truth["noise_scale"] == 2.5 and truth["schedule"]["source"] == "built-in"


# sha256 of simulate_campaign's numbers (t, data, run truth): the defaults of --schedule and
# --noise-scale must keep every number. Taken again when the rotor became the modal unbalance
# response of one imbalance vector with the tracker's lag only (session 17: new physics, so new
# numbers; the speeds, temperatures and every draw are as before).
GOLDEN = {
    ("drift", None): "b0c30fb85f4fdcb8701b203d6e543db461d85ecb7d6bfae4a4ef827ea6b59460",
    ("imbalance", 3): "dc61826fa98f4dbcb1c8738ddb86c0423949caf18268643fdf50b3b249c17710",
}


def _digest(campaign) -> str:
    import hashlib

    h = hashlib.sha256()
    for r in campaign.runs:
        h.update(r.t.tobytes())
        h.update(r.data.tobytes())
        h.update(json.dumps(r.truth, sort_keys=True).encode())
    return h.hexdigest()


def test_default_output_unchanged(tmp_path: Path) -> None:
    from simulator.schedule import DEFAULT_OCS, load_sim_schedule, schedule_toml

    for (fault, fault_seed), want in GOLDEN.items():
        c = simulate_campaign(2, 7, fault=fault, fault_seed=fault_seed, plateau_scale=0.05)
        assert _digest(c) == want
    # the built-in OCs written as a file (with their timing) are the very same simulation
    text = "switch = \"nB\"\ntolerance = 0.02\n" + "".join(
        f'[[oc]]\nname = "{o.name}"\nspeed = {o.speed}\nplateau = {o.plateau}\nrate = {o.rate}\n'
        for o in DEFAULT_OCS)
    as_file = load_sim_schedule(_sched(tmp_path, text, "builtin.toml"))
    c = simulate_campaign(2, 7, fault="drift", plateau_scale=0.05, schedule=as_file, noise_scale=1.0)
    assert _digest(c) == GOLDEN[("drift", None)]
    # the sidecar of the default run, as it always was
    assert schedule_toml() == (
        "# Pass-off schedule of the ordervib simulator (docs/contract.md section 4).\n"
        'switch = "nB"\ntolerance = 0.02\n\n'
        + "".join(f'[[oc]]\nname = "{o.name}"\nspeed = {o.speed:.1f}\n\n' for o in DEFAULT_OCS)
    )[:-1]


BAD_SCHEDULES = {
    "switch": OTHER.replace('switch = "nB"', 'switch = "nA"'),
    "fast": OTHER.replace("speed = 9450.0", "speed = 10450.0"),
    "slow": OTHER.replace("speed = 3000.0", "speed = 2000.0"),
    "plateau": OTHER.replace("plateau = 60", 'plateau = "long"'),
    "rate": OTHER.replace("rate = 80", "rate = 0"),
    "dup": OTHER.replace('name = "back"', 'name = "low"'),
    "no-oc": 'switch = "nB"\n',
    "no-speed": '[[oc]]\nname = "a"\n',
    "toml": "[[oc]\n",
}


@pytest.mark.parametrize("case", [*BAD_SCHEDULES, "missing"])
def test_bad_schedule_one_line_exit_2(
    case: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "missing.toml" if case == "missing" else _sched(tmp_path, BAD_SCHEDULES[case])
    out = tmp_path / "x.mcap"
    code = main(["simulate", "--runs", "1", "--schedule", str(path), "--out", str(out), *FAST])
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert str(path) in err
    expect = {"switch": "switch is 'nA'", "fast": "outside the simulated engine's range",
              "slow": "outside the simulated engine's range", "missing": "not found",
              "rate": "rate 0"}
    if case in expect:
        assert expect[case] in err
    assert not out.exists()


@pytest.mark.parametrize("x", ["0", "-1", "nan", "inf"])
def test_bad_noise_scale(x: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "x.mcap"
    assert main(["simulate", "--runs", "1", f"--noise-scale={x}", "--out", str(out), *FAST]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--noise-scale" in err
    assert not out.exists()


def test_bench_faults_compares_twinson_common_samples() -> None:
    """bench faults: a fault file's run may keep one rundown sample more than the normal file's
    (read_runs trims off samples against each file's top speed); the twins are compared on the
    samples both hold, and runs that are not twins are left for fault_effect to refuse."""
    from harness.fault_effect import on_common_samples
    from node.training.runs import Run

    t = 1000.0 + 0.025 * np.arange(400)
    data = np.arange(800.0).reshape(400, 2)
    full = Run(t, data, ("nB", "yB"), "b", None)
    short = Run(t[:-1], data[:-1], ("nB", "yB"), "b", None)
    a, b = on_common_samples(full, short)
    np.testing.assert_array_equal(a.t, b.t)
    np.testing.assert_array_equal(a.data, short.data)
    other = Run(t + 0.0125, data, ("nB", "yB"), "b", None)
    a, b = on_common_samples(full, other)
    assert a is full and b is other


# --- order phases (yA_ph, yB_ph, yC_ph) ------------------------------------------------------


def test_phase_channels_are_wrapped_degrees_and_noisier_at_small_amplitude(rec3: Path) -> None:
    from simulator.campaign import PHASE_MIN_AMPLITUDE

    truth = json.loads(rec3.with_suffix(".truth.json").read_text())
    assert truth["channels"] == list(PUBLISHED)
    assert truth["phase"]["min_amplitude_mm_s"] == PHASE_MIN_AMPLITUDE
    assert truth["phase"]["unit"] == "degrees"
    for run in read_runs(rec3):
        for amp_ch, ph_ch in zip(ORDER_CHANNELS, PHASE_CHANNELS, strict=True):
            a, p = run.column(amp_ch), run.column(ph_ch)
            ok = np.isfinite(p)
            # most of a run has a phase: about half for yA on these short-plateau runs, whose
            # LP shaft idles far below its first critical (1x under the unit's 0.1 mm/s)
            assert ok.mean() > (0.45 if amp_ch == "yA" else 0.5)
            assert np.all((p[ok] >= -180.0) & (p[ok] < 180.0))
            np.testing.assert_array_equal(p[ok], np.round(p[ok], 1))  # 0.1 degree resolution
            # the engine at rest (amplitude rounded to 0.00): no phase
            rest = a == 0.0
            assert rest.sum() > 20 and np.isnan(p[rest]).mean() > 0.95
            # sample-to-sample scatter of the phase shrinks as the amplitude grows
            d = np.abs(np.mod(np.diff(p) + 180.0, 360.0) - 180.0)
            low, high = (np.nanmedian(d[(a[1:] >= lo) & (a[1:] < hi)])
                         for lo, hi in ((0.15, 0.4), (1.0, 3.0)))
            assert low > 2.0 * high


def test_measured_phase_noise_threshold_and_wrap() -> None:
    from simulator.campaign import PHASE_MIN_AMPLITUDE, _measure_phase, phase_sigma

    k = 40_000
    levels = np.array([0.02, 0.099, 0.15, 0.5, 2.0, 10.0])  # clean amplitudes, mm/s
    amp = np.repeat(levels, k // len(levels))
    clean = {}
    for name, ph in zip(ORDER_CHANNELS, PHASE_CHANNELS, strict=True):
        clean[name] = amp
        clean[ph] = np.full(len(amp), 179.0)  # next to the wrap: noise crosses it
    for scale in (1.0, 2.0):
        m = _measure_phase(np.random.default_rng(1), clean, scale)
        assert m.shape == (len(amp), len(PHASE_CHANNELS))
        below = amp < PHASE_MIN_AMPLITUDE
        assert np.isnan(m[below]).all()  # no phase below the threshold
        assert np.isfinite(m[~below]).mean() > 0.98  # elsewhere only the dropouts
        ok = np.isfinite(m)
        assert np.all((m[ok] >= -180.0) & (m[ok] < 180.0)) and (m[ok] < 0).any()
        err = np.mod(m - 179.0 + 180.0, 360.0) - 180.0
        stds = []
        for level in levels[levels >= PHASE_MIN_AMPLITUDE]:
            e = err[amp == level]
            e = e[np.isfinite(e)]
            want = float(phase_sigma(np.array(level), scale))
            assert abs(np.mean(e)) < 0.1 * want + 0.05
            assert np.std(e) == pytest.approx(np.sqrt(want**2 + 0.1**2 / 12), rel=0.06), level
            stds.append(np.std(e))
        assert stds == sorted(stds, reverse=True) and stds[0] > 5 * stds[-1]
    assert phase_sigma(np.array([0.0, 0.1, 1e-3]), 10.0).max() <= 45.0  # capped


def test_tracked_phase_is_the_phase_lag_through_a_resonance() -> None:
    """One mode at a steady speed: the tracked phase is the lag of the analytic response,
    -angle(U) + atan2(2 zeta w W, w^2 - W^2), which grows by 180 degrees through the
    resonance; the tracked amplitude is the modulus of the same tracked vector."""
    from simulator import rotor

    mode = rotor.Mode(rpm=6000.0, zeta=0.05, phi=1.0, kappa=0.0)
    shaft = rotor.Shaft(speed="nB", out="yB", modes=(mode,), residual=0.0)
    u = 1e-3 * np.exp(1j * np.radians(40.0))
    k = 1200  # 30 s: settled
    got = []
    for rpm in (3000.0, 5700.0, 6000.0, 6300.0, 9000.0):
        total = rotor.order(shaft, np.full(k, rpm), np.full(k, rotor.T_REF),
                            np.full(k, u), np.zeros(k, dtype=complex))
        vector = rotor.tracked(total)
        big, w = rotor.rad_s(rpm), rotor.rad_s(mode.rpm)
        want = -40.0 + np.degrees(np.arctan2(2 * mode.zeta * w * big, w**2 - big**2))
        phase = rotor.tracked_phase(vector)
        assert phase[-1] == pytest.approx(want, abs=1e-6)
        amp = abs(u) * big**3 / abs(w**2 - big**2 + 2j * mode.zeta * w * big)
        assert rotor.tracked_amplitude(vector)[-1] == pytest.approx(amp, rel=1e-9)
        got.append(phase[-1])
    assert got == sorted(got) and got[2] == pytest.approx(50.0) and got[-1] - got[0] > 165.0


def _first_run_clean(seed: int, plateau_scale: float) -> dict[str, np.ndarray]:
    """The clean signals of run 0 of ``simulate_campaign(1, seed)``, drawn as it draws them."""
    from simulator.campaign import simulate_run
    from simulator.engine import build_engine

    engine_ss, _fault_ss, run_ss = np.random.SeedSequence(seed).spawn(3)
    engine = build_engine(np.random.default_rng(engine_ss), np.random.default_rng(engine_ss.spawn(1)[0]))
    rng = np.random.default_rng(run_ss)
    rng.uniform()  # the shutdown time, unused for the first run
    return simulate_run(engine, rng, np.inf, {}, plateau_scale=plateau_scale)[0]


def test_phase_follows_the_true_complex_phase_at_high_amplitude() -> None:
    from simulator.campaign import PHASE_MIN_AMPLITUDE, phase_sigma

    run = simulate_campaign(1, 4, plateau_scale=0.25).runs[0]
    clean = _first_run_clean(4, 0.25)
    assert run.phase is not None
    for j, (name, ph) in enumerate(zip(ORDER_CHANNELS, PHASE_CHANNELS, strict=True)):
        measured = run.data[:, SENSOR_CHANNELS.index(name)]
        ok = np.isfinite(measured)  # the replica is the campaign's run: same amplitude
        assert np.max(np.abs(measured[ok] - clean[name][ok])) < 0.5 + 0.15 * clean[name].max()
        amp, p = clean[name], run.phase[:, j]
        np.testing.assert_array_equal(np.isnan(p[amp < PHASE_MIN_AMPLITUDE]), True)
        err = np.mod(p - clean[ph] + 180.0, 360.0) - 180.0
        high = (amp > 2.0) & np.isfinite(p)
        assert high.sum() > 500, name
        z = err[high] / phase_sigma(amp[high])
        assert np.max(np.abs(err[high])) < 10.0 and np.max(np.abs(z)) < 6.0
        assert np.std(z) == pytest.approx(1.0, abs=0.15) and abs(np.mean(z)) < 0.15
        # the true phase moves (resonances): the channel follows it, not a constant
        assert np.ptp(clean[ph][high]) > 30.0 or name != "yB"


def test_no_phase_leaves_every_other_channel_as_it_was(tmp_path: Path) -> None:
    with_phase = simulate_campaign(2, 6, plateau_scale=0.05, fault="imbalance")
    without = simulate_campaign(2, 6, plateau_scale=0.05, fault="imbalance", phase=False)
    assert without.published == SENSOR_CHANNELS and with_phase.published == PUBLISHED
    for a, b in zip(with_phase.runs, without.runs, strict=True):
        np.testing.assert_array_equal(a.t, b.t)
        np.testing.assert_array_equal(a.data, b.data)
        assert a.truth == b.truth and b.phase is None and a.phase is not None
    # the fault twin holds for the phases too; an imbalance step moves yB's phase
    twin = simulate_campaign(2, 6, plateau_scale=0.05).runs[1]
    faulty = with_phase.runs[1]
    before = faulty.t < faulty.truth["fault"]["onset"]
    np.testing.assert_array_equal(twin.phase[before], faulty.phase[before])
    j = PHASE_CHANNELS.index("yB_ph")
    assert not np.array_equal(twin.phase[~before, j], faulty.phase[~before, j], equal_nan=True)
    # the files: every non-phase message (payload, times, order) identical, no phase topics
    paths = {}
    for name, extra in (("with", []), ("without", ["--no-phase"])):
        paths[name] = tmp_path / f"{name}.mcap"
        argv = ["simulate", "--runs", "2", "--seed", "6", "--out", str(paths[name]), *extra]
        assert main([*argv, *FAST]) == 0
    messages = {}
    for name, path in paths.items():
        with open(path, "rb") as f:
            messages[name] = [(c.topic, m.log_time, m.publish_time, m.data)
                              for _, c, m in NonSeekingReader(f).iter_messages()]
    phase_topics = {f"testbed/bed1/sensor/{c}" for c in PHASE_CHANNELS}
    assert not {m[0] for m in messages["without"]} & phase_topics
    assert {m[0] for m in messages["with"]} >= phase_topics
    assert [m for m in messages["with"] if m[0] not in phase_topics] == messages["without"]
    truth = json.loads(paths["without"].with_suffix(".truth.json").read_text())
    assert truth["channels"] == list(SENSOR_CHANNELS) and truth["phase"] is None


def test_channels_picks_phases_too(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "p.mcap"
    assert main(["simulate", "--runs", "1", "--seed", "2", "--channels", "yB_ph,nB,yB",
                 "--out", str(out), *FAST]) == 0
    (run,) = read_runs(out)
    assert run.channels == ("nB", "yB", "yB_ph")
    both = np.isfinite(run.column("yB")) & np.isfinite(run.column("yB_ph"))
    assert both.sum() > 100
    truth = json.loads(out.with_suffix(".truth.json").read_text())
    assert truth["channels"] == ["yB_ph", "nB", "yB"] and truth["phase"] is not None
    # the amplitude channels are the very ones of a run without the phase
    plain = tmp_path / "q.mcap"
    assert main(["simulate", "--runs", "1", "--seed", "2", "--channels", "nB,yB",
                 "--out", str(plain), *FAST]) == 0
    (other,) = read_runs(plain)
    np.testing.assert_array_equal(other.data, run.data[:, :2])
    bad = tmp_path / "x.mcap"
    code = main(["simulate", "--runs", "1", "--no-phase", "--channels", "nB,yB_ph",
                 "--out", str(bad), *FAST])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "--no-phase" in err
    assert not bad.exists()
