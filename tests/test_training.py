"""Training the switching model: bundles, refusals, robustness to gaps, the commands."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from node.cli import main
from node.contract import SENSOR_CHANNELS
from node.contract.errors import OrdervibError
from node.contract.schedule import OperatingCondition, Schedule
from node.models.bundle import Bundle, load_bundle, save_bundle
from node.training.evaluation import predict_segments
from node.training.runs import Run
from node.training.train import train
from simulator.campaign import simulate_campaign

ROOT = Path(__file__).resolve().parents[1]
SMALL_GRID = {"levels": [1, 2], "rcond": [1e-8], "estimator": ["oe"]}


@pytest.fixture(scope="module")
def sim():
    camp = simulate_campaign(runs=3, seed=5, plateau_scale=0.25)
    runs = [Run(r.t, r.data, tuple(camp.channels), "bed1", None) for r in camp.runs]
    schedule = Schedule(tuple(OperatingCondition(oc.name, oc.speed) for oc in camp.ocs))
    return runs, schedule


def test_bundle_reload_gives_bit_identical_predictions(sim, tmp_path):
    runs, schedule = sim
    for method, grid in (("wdmd", SMALL_GRID), ("lasso", {"alpha": [0.01, 0.1]})):
        results = train(runs, schedule, method=method, grid=grid, workers=1)
        assert any(r.model is not None for r in results)
        save_bundle(Bundle(method, "yB", schedule, results), tmp_path / method)
        loaded = load_bundle(tmp_path / method)
        assert loaded.schedule == schedule and loaded.method == method
        before = predict_segments(results, runs, schedule, "yB")
        after = predict_segments(loaded.ocs, runs, schedule, "yB")
        assert len(before) == len(after) > 0
        for a, b in zip(before, after):
            np.testing.assert_array_equal(a.predicted, b.predicted)
        for r, q in zip(results, loaded.ocs):
            assert r.inputs == q.inputs and r.params == q.params
            if r.calibration:
                assert q.calibration.threshold == r.calibration.threshold


def test_corrupted_or_mismatched_bundle_is_refused(sim, tmp_path):
    runs, schedule = sim
    results = train(runs, schedule, method="lasso", grid={"alpha": [0.1]}, workers=1)
    path = save_bundle(Bundle("lasso", "yB", schedule, results), tmp_path / "m")
    data = bytearray((path / "arrays.npz").read_bytes())
    data[len(data) // 2] ^= 0xFF
    (path / "arrays.npz").write_bytes(bytes(data))
    with pytest.raises(OrdervibError, match="hash"):
        load_bundle(path)
    path = save_bundle(Bundle("lasso", "yB", schedule, results), tmp_path / "v")
    manifest = json.loads((path / "manifest.json").read_text())
    manifest["format_version"] = 99
    (path / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(OrdervibError, match="version"):
        load_bundle(path)
    (path / "manifest.json").write_text("{not json")
    with pytest.raises(OrdervibError, match="JSON"):
        load_bundle(path)
    with pytest.raises(OrdervibError, match="not found"):
        load_bundle(tmp_path / "nothing")
    for bad in ({"step_threshold": "high"}, {"flatline_samples": -3}, {"run_scale_prior_ocs": True}, []):
        path = save_bundle(Bundle("lasso", "yB", schedule, results), tmp_path / "c")
        manifest = json.loads((path / "manifest.json").read_text())
        manifest["checks"] = bad
        (path / "manifest.json").write_text(json.dumps(manifest))
        with pytest.raises(OrdervibError, match="malformed bundle"):
            load_bundle(path)
    # the arrays file holds no pickled objects: numpy refuses pickles on load
    np.load(tmp_path / "m" / "arrays.npz", allow_pickle=False).close()


def test_training_survives_dropouts_and_a_missing_optional_channel(sim):
    runs, schedule = sim
    rng = np.random.default_rng(0)
    damaged = []
    for i, r in enumerate(runs):
        data = r.data.copy()
        holes = rng.random(data.shape) < 0.05  # 5 % dropouts everywhere, target included
        data[holes] = np.nan
        channels = r.channels
        if i == 1:  # one run lacks tG entirely
            keep = [j for j, c in enumerate(channels) if c != "tG"]
            data, channels = data[:, keep], tuple(channels[j] for j in keep)
        damaged.append(Run(r.t, data, channels, r.bed, None))
    results = train(damaged, schedule, method="wdmd", grid=SMALL_GRID, workers=1)
    fitted = [r for r in results if r.model is not None]
    assert len(fitted) >= len(schedule.ocs) - 1
    for r in fitted:  # a characteristic curve (one input, the speed) or an average may win
        assert "tG" not in r.inputs
        members = r.params["members"] if r.model.method == "average" else [r.model.method]
        for m in members:  # an average's: curves and the grid's best
            ins = m["inputs"] if isinstance(m, dict) else r.inputs
            assert ins == ["nB"] if (m["method"] if isinstance(m, dict) else m) == "curve" else len(ins) == 4
        assert np.isfinite(r.cv_eps) and all(np.isfinite(a).all() for a in r.model.arrays().values())
    assert set(SENSOR_CHANNELS) >= set().union(*(r.inputs for r in fitted))


def test_order_phases_are_never_input_candidates():
    """The simulator's order phases (yA_ph, yB_ph, yC_ph) and any further *_ph channel are the
    vibration itself, not its cause: never inputs of an amplitude model."""
    from node.contract import PHASE_CHANNELS
    from node.training.train import candidate_channels

    camp = simulate_campaign(runs=2, seed=5, plateau_scale=0.05)
    channels = (*camp.published, "M3_ph")  # a bed's further phase channel, not named y*
    runs = []
    for r in camp.runs:
        assert r.phase is not None
        data = np.column_stack([r.data, r.phase, r.phase[:, 1]])
        runs.append(Run(r.t, data, channels, "bed1", None))
    assert camp.published == (*SENSOR_CHANNELS, *PHASE_CHANNELS)
    for target in ("yA", "yB", "yC"):
        got = candidate_channels(runs, target, "nB")
        assert got[0] == "nB" and not [c for c in got if c.endswith("_ph") or c.startswith("y")]
        assert set(got) == {c for c in SENSOR_CHANNELS if not c.startswith("y")}


def test_named_inputs_missing_from_recordings_is_one_line_error(sim):
    runs, schedule = sim
    with pytest.raises(OrdervibError, match="zZ"):
        train(runs, schedule, method="lasso", inputs=["nB", "zZ"], workers=1)


def test_train_and_evaluate_commands(tmp_path, capsys):
    rec = ROOT / "recordings" / "engine1_runs.mcap"
    sched = ROOT / "recordings" / "engine1_runs.schedule.toml"
    out = tmp_path / "model"
    assert main(["train", str(rec), "--schedule", str(sched), "--out", str(out), "--method", "lasso",
                 "--target", "yB", "--quiet", "--workers", "1"]) == 0
    text = capsys.readouterr().out
    assert "OC2a" in text and "CV eps_td" in text and (out / "manifest.json").exists()
    fault = ROOT / "recordings" / "engine1_fault.mcap"
    assert main(["evaluate", str(out), str(fault), "--quiet", "--png", str(tmp_path / "e.png")]) == 0
    text = capsys.readouterr().out
    assert "held-out eps_td" in text and "node alarms (ordervib replay)" in text and "per hour" in text
    assert (tmp_path / "e.png").stat().st_size > 10_000


@pytest.mark.parametrize("argv, message", [
    (["train", "nope.mcap", "--schedule", "s.toml", "--out", "m"], "schedule file not found"),
    (["evaluate", "no-model-here", "x.mcap"], "model bundle not found"),
    (["train", "x.mcap", "--schedule", "s.toml", "--out", "m", "--n-inputs", "0"], "n-inputs"),
    (["train", "x.mcap", "--schedule", "s.toml", "--out", "m", "--cv-undercoverage", "0.5"],
     "cv-undercoverage"),
    (["train", "x.mcap", "--schedule", "s.toml", "--out", "m", "--cv-undercoverage", "nan"],
     "cv-undercoverage"),
])
def test_command_errors_are_one_line(argv, message, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and "\n" not in err and "Traceback" not in err


def test_train_with_history_stores_the_cooling_and_the_node_replays_it(tmp_path, capsys):
    """--history: the bundle carries the estimated cooling; replay (the node) runs models on
    the history channels, and its predictions equal training's evaluation of the same runs."""
    from mcap.reader import make_reader
    rec = ROOT / "recordings" / "engine1_runs.mcap"
    sched = ROOT / "recordings" / "engine1_runs.schedule.toml"
    out = tmp_path / "model"
    assert main(["train", str(rec), "--schedule", str(sched), "--out", str(out), "--method", "lasso",
                 "--inputs", "nB,hist_energy,hist_thermal", "--no-curve-candidates", "--history",
                 "--target", "yB", "--quiet", "--workers", "1"]) == 0
    capsys.readouterr()
    bundle = load_bundle(out)
    assert {"hist_energy", "hist_thermal"} <= set(bundle.inputs)
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["runtime"]["history_cooling"] == bundle.config.history_cooling > 0
    node_out = tmp_path / "node.mcap"
    assert main(["replay", str(rec), "--model", str(out), "--out", str(node_out), "--quiet"]) == 0
    with open(node_out, "rb") as f:
        node = {round(json.loads(m.data)["t"], 6): json.loads(m.data)["predicted"]
                for _, ch, m in make_reader(f).iter_messages(topics=["testbed/bed1/monitor/yB"])}
    from node.training.fit import load_runs
    preds = predict_segments(bundle.ocs, load_runs([str(rec)], quiet=True), bundle.schedule, "yB",
                             bundle.curve, bundle.config)
    pairs = [(node.get(round(float(t), 6)), p) for s in preds for t, p in zip(s.t, s.predicted)]
    assert pairs and all(a is not None for a, _ in pairs)  # the node predicted every sample
    np.testing.assert_allclose([a for a, _ in pairs], [b for _, b in pairs], rtol=1e-9, atol=1e-9)


def test_fold_rankings_from_shared_segment_terms_equal_ranking_each_fold_afresh():
    """Leave-one-run-out CV ranks the inputs of every fold from per-segment MS-DPCCA terms
    computed once: each fold's scores equal rank_inputs over its own segments to the last bit."""
    from node.training.features import rank_inputs
    from node.training.ocdata import OCData
    from node.training.train import _ranking_terms, select_inputs

    rng = np.random.default_rng(4)
    d = OCData("OC1", "yB", ["nB", "tF", "tI", "hist_energy"], [], [], [], [], switch="nB",
               unranked=["hist_energy"])
    for r in range(6):
        K = int(rng.integers(300, 600))
        X = np.cumsum(rng.normal(size=(K, 4)), axis=0)
        X[:, 2] = 5.0 if r == 3 else X[:, 2]  # a channel constant in one segment
        d.runs.append(r)
        d.y.append(X[:, 0] * 0.3 + X[:, 1] * 0.1 + rng.normal(size=K))
        d.X.append(X)
        d.start.append(50)
        d.at.append(50)
    terms = _ranking_terms(d)
    for f in range(6):
        rows = [i for i in range(6) if i != f]
        segs = [np.column_stack([d.y[i], d.X[i][:, [0, 1, 2]]])[d.start[i]:] for i in rows]  # (as training)
        want = rank_inputs(segs, 0)[1:]
        got = select_inputs(d, rows, None, 2, terms)[1]
        order = np.argsort(-want)
        assert [c for c, _ in got] == [d.candidates[j] for j in order]  # never the unranked one
        np.testing.assert_array_equal([s for _, s in got], want[order])
