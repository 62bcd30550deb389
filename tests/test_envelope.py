"""The model's envelope: where its training runs went, what the node says and does beyond it."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from conftest import small_campaign
from hypothesis import given, settings
from hypothesis import strategies as st

from node.contract.errors import OrdervibError
from node.models.bundle import load_bundle, save_bundle
from node.models.envelope import HELD, OUTSIDE, Envelope
from node.runtime.align import AlignedSample
from node.runtime.guard import CURVE
from node.runtime.pipeline import MonitorPipeline
from node.training.envelope import band_factors
from node.training.evaluation import evaluate, predict_segments
from node.training.runs import read_runs


@st.composite
def training_cloud(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray]:
    n = draw(st.integers(5, 60))
    m = draw(st.integers(1, 4))
    seed = draw(st.integers(0, 2**31 - 1))
    rng = np.random.default_rng(seed)
    scale = rng.uniform(0.1, 1000.0, m)
    X = rng.normal(size=(n, m)) * scale + rng.uniform(-5000, 5000, m)
    return X, np.arange(n) / 40.0


@settings(max_examples=60, deadline=None)
@given(training_cloud(), st.floats(1.01, 50.0))
def test_training_samples_lie_inside_and_beyond_the_ranges_is_outside(cloud, beyond):
    X, t = cloud
    env = Envelope.fit([f"u{i}" for i in range(X.shape[1])], X, t)
    d = env.distances(X, t)
    assert np.all(d <= OUTSIDE + 1e-9)  # the training samples span the region
    scalar = [env.distance(x.tolist(), s) for x, s in zip(X, t)]
    np.testing.assert_allclose(scalar, d, rtol=1e-9, atol=1e-12)  # the node's path = the batch's
    # one input beyond its range by `beyond` half-widths: outside, and clamping brings it back
    lo, hi = env.low[:-1], env.high[:-1]
    x = (lo + hi) / 2
    x[0] = hi[0] + beyond * max((hi[0] - lo[0]) / 2, 1e-6)
    assert env.distance(x.tolist(), float(t[-1]) / 2) > OUTSIDE
    held = np.array(env.clamp(x.tolist()))
    assert np.all(held >= lo) and np.all(held <= hi) and held[0] == hi[0]
    np.testing.assert_array_equal(env.clamp_rows(X), X)  # inside the ranges: unchanged
    assert env.clamp(held.tolist()) == held.tolist()


def test_the_time_since_the_switch_is_part_of_the_region():
    X = np.full((80, 1), 5000.0) + np.arange(80)[:, None]  # 2 s of training after the switch
    env = Envelope.fit(["nB"], X, np.arange(80) / 40.0)
    assert env.distance([5040.0], 1.0) <= OUTSIDE
    assert env.distance([5040.0], 10.0) > OUTSIDE  # the same inputs, long after: outside


def test_band_factors_pool_where_an_oc_saw_few_samples_outside():
    assert band_factors([(160.0, 40), (1.0, 1), (0.0, 50), None]) == pytest.approx(
        [2.0, (161.0 / 91) ** 0.5, 1.0, 1.0])
    assert band_factors([(1.0, 3)]) == [1.0]  # too few anywhere: the band as calibrated


@pytest.fixture(scope="module")
def campaign(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return small_campaign(tmp_path_factory.mktemp("envelope"), 7)


def _node(bundle, run, shift: float) -> list[dict]:
    """The node's monitor messages over ``run`` with ``shift`` added to tF."""
    pipe = MonitorPipeline(bundle)
    out = []
    for k in range(len(run.t)):
        vals = {c: float(run.data[k, j]) for j, c in enumerate(run.channels)}
        vals["tF"] += shift
        out.append(pipe.step(AlignedSample(float(run.t[k]), vals, k == 0))[0])
    return out


def _model(m: dict) -> str:
    """The name of the model in force of a monitor message (its OC's; in the start, the start's)."""
    return m["model"].split(":", 1)[1].split("@", 1)[0]


def test_the_node_says_where_it_extrapolates_holds_the_inputs_and_widens_the_band(campaign):
    bundle = load_bundle(campaign / "m")
    assert all(r.envelope is not None and r.envelope.inputs == tuple(r.inputs)
               for r in bundle.ocs if r.model is not None)
    run = read_runs(campaign / "test.mcap")[0]
    msgs = _node(bundle, run, 0.0)
    hot = _node(bundle, run, 400.0)  # tF far beyond anything the training runs held
    modelled = [m for m in msgs if m["predicted"] is not None]
    assert modelled and all(m["envelope"] is not None for m in modelled)
    assert all(m["envelope"] is None for m in msgs if m["predicted"] is None)
    takes_tf = {r.name for r in bundle.ocs if r.model is not None and "tF" in r.inputs}
    outside = [m for m in hot if m["predicted"] is not None and _model(m) in takes_tf]
    assert outside and all(m["envelope"] > OUTSIDE for m in outside)
    for m in outside:
        res = bundle.oc(_model(m))
        c = res.calibration
        held = f"{res.model.method.value}:{res.name}{HELD}"
        assert m["model"] in (held, held + CURVE)  # the curve guard may name itself after it
        assert m["band"] == pytest.approx(c.threshold * c.sigma * m["run_scale"] * res.envelope.band_factor)
    for m in modelled:  # inside, the model's own name and band
        if m["envelope"] <= OUTSIDE:
            c = bundle.oc(_model(m)).calibration
            assert HELD not in m["model"]
            assert m["band"] == pytest.approx(c.threshold * c.sigma * m["run_scale"])
    # beyond the training range of tF the prediction is the one at its edge: it no longer moves
    # with tF (a regression on tF would extrapolate)
    hotter = _node(bundle, run, 800.0)
    assert [m["predicted"] for m in hotter] == [m["predicted"] for m in hot]


def test_evaluation_counts_the_samples_outside_as_the_node_sees_them(campaign):
    bundle = load_bundle(campaign / "m")
    run = read_runs(campaign / "test.mcap")[0]
    hot_run = dataclasses.replace(run, data=run.data.copy())
    hot_run.data[:, run.channels.index("tF")] += 400.0
    evals, _ = evaluate(bundle.ocs, [hot_run], bundle.schedule, bundle.target, bundle.curve, bundle.config)
    takes_tf = {r.name for r in bundle.ocs if r.model is not None and "tF" in r.inputs}
    assert takes_tf and all(e.outside == e.samples > 0 for e in evals if e.name in takes_tf)
    preds = predict_segments(bundle.ocs, [hot_run], bundle.schedule, bundle.target, bundle.curve,
                             bundle.config)
    by_t = {m["t"]: m for m in _node(bundle, run, 400.0)}
    for p in preds:
        node = [by_t[float(t)] for t in p.t]
        np.testing.assert_allclose([m["envelope"] for m in node], p.envelope, rtol=1e-9)
        np.testing.assert_allclose([m["predicted"] for m in node], p.predicted, rtol=1e-9, atol=1e-12)


def test_a_malformed_envelope_is_one_line(campaign, tmp_path):
    bundle = load_bundle(campaign / "m")
    save_bundle(bundle, tmp_path / "ok")
    assert load_bundle(tmp_path / "ok").ocs[0].envelope.d_max == bundle.ocs[0].envelope.d_max
    manifest = json.loads((tmp_path / "ok" / "manifest.json").read_text())
    first = next(d for d in manifest["ocs"] if d.get("envelope"))
    for bad in ({"band_factor": 0.5}, {"d_max": "x"}, {"inputs": ["nope"]}):
        broken = json.loads(json.dumps(manifest))
        next(d for d in broken["ocs"] if d["name"] == first["name"])["envelope"].update(bad)
        (tmp_path / "bad").mkdir(exist_ok=True)
        (tmp_path / "bad" / "arrays.npz").write_bytes((tmp_path / "ok" / "arrays.npz").read_bytes())
        (tmp_path / "bad" / "manifest.json").write_text(json.dumps(broken))
        with pytest.raises(OrdervibError, match="malformed bundle") as info:
            load_bundle(tmp_path / "bad")
        assert "\n" not in str(info.value)
    old = json.loads(json.dumps(manifest))  # a bundle from before: no envelope, none in the node
    for d in old["ocs"]:
        d.pop("envelope", None)
    (tmp_path / "bad" / "manifest.json").write_text(json.dumps(old))
    assert all(r.envelope is None for r in load_bundle(tmp_path / "bad").ocs)
