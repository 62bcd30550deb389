"""The curve guard: within an OC visit, the characteristic curve where the model erred more so far."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from conftest import small_campaign
from hypothesis import given, settings
from hypothesis import strategies as st

from node.models.baseline import CharacteristicCurve, FleetCurve
from node.models.bundle import load_bundle, save_bundle
from node.models.config import RuntimeConfig, SettingError
from node.runtime.align import AlignedSample
from node.runtime.guard import CURVE, CurveGuard, guard_segment
from node.runtime.pipeline import MonitorPipeline
from node.sysid.metrics import pooled_eps
from node.training.evaluation import evaluate, predict_segments
from node.training.runs import read_runs

FLAT = FleetCurve(np.array([0.0, 1e4]), np.array([2.0, 2.0]))  # 2.0 at every speed


def test_the_curve_takes_over_after_the_wait_and_hands_back_with_hysteresis():
    g = CurveGuard(FLAT, wait=40, margin=0.1)
    # the model errs 1.0 a sample, the curve 0: the model until 40 samples were compared
    out = [g.step(2.0, 3.0, 5000.0) for _ in range(60)]
    assert [o[1] for o in out] == [False] * 40 + [True] * 20
    assert [o[0] for o in out] == [3.0] * 40 + [2.0] * 20
    # the measured value moves to the model's level: its error so far (60) falls below the
    # curve's over 1.1 only once the curve erred 66 (the hysteresis)
    back = [g.step(3.0, 3.0, 5000.0)[1] for _ in range(100)]
    k = back.index(False)
    assert 60 < k <= 67 and not any(back[k:])
    g.reset()
    assert g.step(2.0, 3.0, 5000.0) == (3.0, False) and not g.using_curve


def test_unknown_values_count_nothing_and_a_missing_prediction_passes_through():
    g = CurveGuard(FLAT, wait=2, margin=0.0)
    nan = float("nan")
    for _ in range(5):
        assert g.step(nan, 3.0, 5000.0) == (3.0, False)  # a dropout: nothing compared
        assert g.step(2.0, 3.0, nan) == (3.0, False)  # no switch speed: no curve, nothing compared
    p, on = g.step(2.0, nan, 5000.0)
    assert p != p and not on  # no model prediction: nothing to guard
    assert g.step(2.0, 3.0, 5000.0) == (3.0, False)  # the first sample compared
    assert g.step(2.0, 3.0, 5000.0) == (3.0, False)
    assert g.step(2.0, 3.0, 5000.0) == (2.0, True)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(1, 200), st.floats(0.0, 2.0))
def test_the_guard_is_causal_and_only_ever_gives_the_model_or_the_curve(seed, wait, margin):
    rng = np.random.default_rng(seed)
    k = 300
    y = rng.normal(5.0, 1.0, k)
    model = y + rng.normal(rng.uniform(-2, 2), rng.uniform(0.1, 2), k)
    speed = rng.uniform(3000.0, 6000.0, k)
    curve = FleetCurve(np.array([3000.0, 6000.0]), np.array([4.0, 6.0]))
    g = CurveGuard(curve, wait, margin)
    out, used = guard_segment(g, y, model, speed)
    c = np.array([curve.at(s) for s in speed])
    np.testing.assert_array_equal(out, np.where(used, c, model))
    assert not used[:wait].any()
    # causal: changing the future leaves the past alone
    j = int(rng.integers(1, k))
    y2 = y.copy()
    y2[j:] += 100.0
    out2, used2 = guard_segment(g, y2, model, speed)
    np.testing.assert_array_equal(out2[:j + 1], out[:j + 1])
    np.testing.assert_array_equal(used2[:j + 1], used[:j + 1])


def test_settings_are_bounded_and_old_bundles_keep_it_off():
    assert RuntimeConfig().guard_wait_s == 5.0
    with pytest.raises(SettingError, match="guard_margin"):
        RuntimeConfig(guard_margin=-1.0)
    with pytest.raises(SettingError, match="guard_wait_s"):
        RuntimeConfig(guard_wait_s=float("inf"))
    with pytest.raises(ValueError):
        CurveGuard(FLAT, wait=0, margin=0.1)


@pytest.fixture(scope="module")
def campaign(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return small_campaign(tmp_path_factory.mktemp("guard"), 11)


def _node(bundle, run) -> list[dict]:
    pipe = MonitorPipeline(bundle)
    out = []
    for k in range(len(run.t)):
        vals = {c: float(run.data[k, j]) for j, c in enumerate(run.channels)}
        out.append(pipe.step(AlignedSample(float(run.t[k]), vals, k == 0))[0])
    return out


def test_the_node_and_the_evaluation_guard_alike_where_the_curve_knows_better(campaign, tmp_path):
    bundle = load_bundle(campaign / "m")
    assert bundle.config.guard_wait_s > 0  # a new bundle: the guard on
    run = read_runs(campaign / "test.mcap")[0]
    # a curve that knows this very run (fitted on it): better than the model nearly everywhere
    sw, tg = bundle.schedule.switch, bundle.target
    own = CharacteristicCurve().fit(run.column(sw), run.column(tg))
    sharp = dataclasses.replace(bundle, curve=(own.centres_, own.means_))
    off = dataclasses.replace(sharp, config=dataclasses.replace(sharp.config, guard_wait_s=0.0))
    msgs, plain = _node(sharp, run), _node(off, run)
    guarded = [m for m in msgs if m["model"] and m["model"].endswith(CURVE)]
    assert len(guarded) > 200  # of 5,881 predicted here
    assert not any(m["model"] and m["model"].endswith(CURVE) for m in plain)
    # the run scale (how unusual the run is, from the earlier OCs) measures the models' own
    # residuals, as training calibrated it: the same with the guard as without
    assert [m["run_scale"] for m in msgs] == [m["run_scale"] for m in plain]
    assert len({m["run_scale"] for m in msgs if m["run_scale"] is not None}) > 1
    fleet = FleetCurve(own.centres_, own.means_)
    speeds = {float(t): float(x) for t, x in zip(run.t, run.column(sw))}
    for m in guarded:
        assert m["predicted"] == fleet.at(speeds[m["t"]])
    # the batch evaluation guards the very same samples (the models' own batch and step paths
    # agree to rounding, as elsewhere)
    preds = predict_segments(sharp.ocs, [run], sharp.schedule, tg, sharp.curve, sharp.config)
    by_t = {m["t"]: m for m in msgs}
    for p in preds:
        node = [by_t[float(t)] for t in p.t]
        np.testing.assert_allclose([m["predicted"] for m in node], p.predicted, rtol=1e-9, atol=1e-12)
        assert [bool(m["model"].endswith(CURVE)) for m in node] == p.guarded.tolist()
    evals, _ = evaluate(sharp.ocs, [run], sharp.schedule, tg, sharp.curve, sharp.config)
    assert sum(e.guarded for e in evals) == len(guarded)
    # and the guard helps here: the pooled error of the guarded predictions is the smaller
    pairs = [(np.array([m["measured"] for m in ms]), np.array([m["predicted"] for m in ms]))
             for ms in ([m for m in msgs if m["predicted"] is not None and m["measured"] is not None],
                        [m for m in plain if m["predicted"] is not None and m["measured"] is not None])]
    assert pooled_eps([pairs[0]]) < pooled_eps([pairs[1]])
    # a bundle saved before the guard (no guard settings): loaded with the guard off
    save_bundle(bundle, tmp_path / "m")
    manifest = json.loads((tmp_path / "m" / "manifest.json").read_text())
    for key in ("guard_wait_s", "guard_margin"):
        manifest["runtime"].pop(key)
    (tmp_path / "m" / "manifest.json").write_text(json.dumps(manifest))
    assert load_bundle(tmp_path / "m").config.guard_wait_s == 0.0


def test_a_prediction_that_measures_nothing_is_never_guarded(campaign):
    """``predict`` feeds the node its own chained prediction as the target: the guard would
    compare the model with itself, so ``predict_runs`` runs the node ``unguarded``."""
    import inspect

    from node.runtime.guard import unguarded
    from node.training import prediction

    bundle = load_bundle(campaign / "m")
    model = unguarded(bundle)
    assert bundle.config.guard_wait_s > 0
    assert [b.config.guard_wait_s for b in model.bundles] == [0.0]
    assert model.bundles[0].ocs is bundle.ocs and model.bundles[0].curve is bundle.curve
    assert "NodeCore(unguarded(m)" in inspect.getsource(prediction.predict_runs)
