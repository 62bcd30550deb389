"""The order's phase (issue 15): the vector rule, the vector curve, and the node's vector fields."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader

from node.cli import main
from node.contract.vector import order_vectors
from node.models.bundle import load_bundle
from node.models.curve import CurveModel
from node.models.ocmodel import Method, Trajectory
from node.runtime.alarms import StepCheck
from node.training.evaluation import predict_segments


def _rotating(k: np.ndarray, turn_at: int, angle_deg: float, rng: np.random.Generator) -> np.ndarray:
    """A 1x vector of constant amplitude 5 that turns by ``angle_deg`` at sample ``turn_at``, in noise."""
    phase = np.radians(30.0 + angle_deg * (k >= turn_at))
    return 5.0 * np.exp(-1j * phase) + 0.05 * (rng.standard_normal(k.size) + 1j * rng.standard_normal(k.size))


def test_a_turn_of_the_vector_is_seen_where_the_amplitude_does_not_move():
    rng = np.random.default_rng(2)
    k = np.arange(1200)
    z = _rotating(k, 600, 40.0, rng)  # |dz| = 2 x 5 sin(20 deg) = 3.4 mm/s, the amplitude unchanged
    amplitude, vector = StepCheck(threshold=8.0), StepCheck(threshold=8.0)
    flags_a = [(amplitude.step(abs(v), True), amplitude.flagged)[1] for v in z]
    flags_v = [(vector.step(v, True), vector.flagged)[1] for v in z]
    assert not any(flags_a)
    first = flags_v.index(True)
    assert 600 <= first <= 640 and all(flags_v[first:])


def test_the_anchored_check_sees_a_slow_turn_the_sliding_one_misses():
    rng = np.random.default_rng(4)
    k = np.arange(2400)
    turn = np.clip((k - 800) / 800.0, 0.0, 1.0)  # 40 deg over 20 s, like a stiffness loss ramping in
    z = 5.0 * np.exp(-1j * np.radians(30.0 + 40.0 * turn)) + 0.05 * (
        rng.standard_normal(k.size) + 1j * rng.standard_normal(k.size))
    sliding, anchored = StepCheck(threshold=8.0), StepCheck(threshold=8.0, anchored=True)
    s = [sliding.step(v, True) for v in z]
    a = [anchored.step(v, True) for v in z]
    assert not sliding.flagged and max(s) < 8.0
    assert anchored.flagged and max(a[:800]) < 4.0
    # the anchor is the plateau's first full window: a new plateau takes a new one
    anchored.step(0.0, False)
    assert not anchored.flagged and anchored.step(z[-1], True) == 0.0


def test_a_real_check_gives_the_same_numbers_for_real_and_complex_values():
    rng = np.random.default_rng(1)
    y = 3.0 + 0.1 * rng.standard_normal(900) + 1.0 * (np.arange(900) > 500)
    for anchored in (False, True):
        r, c = StepCheck(8.0, anchored=anchored), StepCheck(8.0, anchored=anchored)
        assert [r.step(v, True) for v in y.tolist()] == [c.step(complex(v, 0.0), True) for v in y.tolist()]


def test_the_vector_curve_follows_each_run_s_own_unbalance_exactly():
    """Runs whose 1x vector is the fleet's response times the run's complex unbalance factor:
    the vector curve, anchored on the second before the switch, predicts the amplitude exactly,
    which the amplitude alone cannot when the response's phase turns with speed."""
    rng = np.random.default_rng(7)
    speed = np.concatenate([np.full(60, 1010.0), np.arange(1010.0, 3000.0, 20.0)])  # bin centres
    response = (speed / 1000.0) * np.exp(-1j * speed / 700.0)  # turns with speed
    trajs = []
    for _ in range(4):
        u = rng.uniform(0.5, 2.0) * np.exp(1j * rng.uniform(0, 2 * np.pi))
        z = u * response
        trajs.append(Trajectory(np.abs(z), speed[:, None], start=60, z=z))
    m = CurveModel.fit(Method.CURVE, {"variant": "vector", "bin": 20.0, "anchor": 40}, trajs)
    np.testing.assert_allclose(m.weights, [1.0, 0.0], atol=1e-9)
    u_new = 1.7 * np.exp(0.4j)
    new = Trajectory(np.abs(u_new * response), speed[:, None], start=60, z=u_new * response)
    np.testing.assert_allclose(m.predict(new), new.seg_y, rtol=1e-9)
    rt = m.runtime()
    rt.start(new.z[:60], new.U[:60])
    rt.step([float(speed[-1])])
    np.testing.assert_allclose(rt.vector, new.z[-1], rtol=1e-9)
    # stored and loaded: real arrays only (npz without pickle), the same model
    arrays = m.arrays()
    assert all(not np.iscomplexobj(a) for a in arrays.values())
    again = CurveModel.from_arrays(Method.CURVE, m.params, arrays)
    np.testing.assert_array_equal(again.predict(new), m.predict(new))
    with pytest.raises(ValueError, match="phase"):
        CurveModel.fit(Method.CURVE, {"variant": "vector"}, [Trajectory(new.y, new.U, 60)])


def test_the_influence_curve_recovers_a_fixed_part_plus_each_run_s_unbalance_response():
    """Runs whose 1x vector is a run-independent part b(v) (say a bow) plus the rotor's response
    H(v) to the run's own unbalance u: the influence curve predicts a new run exactly from its
    vector at the switch, also an unbalance at an angle no training run had; the vector curve
    (one response scaled by the run) cannot."""
    rng = np.random.default_rng(11)
    speed = np.concatenate([np.full(60, 1010.0), np.arange(1010.0, 3000.0, 20.0)])  # bin centres
    h = (speed / 1000.0) * np.exp(-1j * speed / 700.0)  # the unbalance response turns with speed
    b = 0.8 * np.exp(1j * speed / 400.0)  # the fixed part turns otherwise

    def run(u: complex) -> Trajectory:
        z = b + u * h
        return Trajectory(np.abs(z), speed[:, None], start=60, z=z)

    trajs = [run(rng.uniform(0.5, 2.0) * np.exp(1j * rng.uniform(-0.6, 0.6))) for _ in range(5)]
    params = {"variant": "influence", "bin": 20.0, "anchor": 40, "ridge": 0.0}
    m = CurveModel.fit(Method.CURVE, params, trajs)
    for u_new in (1.7 * np.exp(0.4j), 1.2 * np.exp(2.5j)):  # inside and far outside the runs' angles
        new = run(u_new)
        np.testing.assert_allclose(m.predict(new), new.seg_y, rtol=1e-9)
        rt = m.runtime()
        rt.start(new.z[:60], new.U[:60])
        rt.step([float(speed[-1])])
        np.testing.assert_allclose(rt.vector, new.z[-1], rtol=1e-9)
    vec = CurveModel.fit(Method.CURVE, {"variant": "vector", "bin": 20.0, "anchor": 40}, trajs)
    assert np.max(np.abs(vec.predict(new) - new.seg_y)) > 0.1
    # stored and loaded: real arrays only, the same model
    arrays = m.arrays()
    assert all(not np.iscomplexobj(a) for a in arrays.values())
    again = CurveModel.from_arrays(Method.CURVE, m.params, arrays)
    np.testing.assert_array_equal(again.predict(new), m.predict(new))
    # without its vector at the switch, a run gets the runs' mean vector per speed
    rt = m.runtime()
    rt.start(np.zeros(0, complex), np.zeros((0, 1)))
    assert rt.anchor is None and rt.step([2990.0]) == pytest.approx(abs(np.mean([t.z[-1] for t in trajs])))


def test_order_vectors_are_the_lag_convention():
    z = order_vectors(np.array([2.0, 2.0, 1.0]), np.array([0.0, 90.0, np.nan]))
    np.testing.assert_allclose(z[:2], [2.0, -2.0j], atol=1e-12)
    assert np.isnan(z[2])


def _monitor(rec: Path) -> list[dict]:
    with open(rec, "rb") as f:
        topics = ["testbed/bed1/monitor/yB"]
        return [json.loads(m.data) for _, _, m in make_reader(f).iter_messages(topics=topics)]


def test_a_model_trained_with_phase_predicts_the_vector_in_the_node_as_in_training(
        phased: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    bundle = load_bundle(phased / "model")
    kinds = [r.kind for r in bundle.ocs if r.model is not None]
    assert "curve:vector" in kinds
    assert bundle.checks["vector_step_threshold"] > 0 and bundle.checks["vector_drift_threshold"] > 0
    out = tmp_path / "node.mcap"
    assert main(["replay", str(phased / "train.mcap"), "--model", str(phased / "model"), "--out", str(out),
                 "--quiet"]) == 0
    capsys.readouterr()
    msgs = _monitor(out)
    fields = {"measured_phase", "predicted_phase", "vector_residual", "vector_score"}
    assert all(fields <= set(m) for m in msgs)
    vec = [m for m in msgs if m["model"] and m["predicted_phase"] is not None]
    assert vec, "no sample predicted by a vector curve"
    for m in vec:
        assert -180.0 <= m["predicted_phase"] < 180.0
        if m["measured"] is not None and m["measured_phase"] is not None:
            zm = order_vectors(np.array([m["measured"]]), np.array([m["measured_phase"]]))[0]
            zp = order_vectors(np.array([m["predicted"]]), np.array([m["predicted_phase"]]))[0]
            assert m["vector_residual"] == pytest.approx(abs(zm - zp), rel=1e-6, abs=1e-9)
    node = {round(m["t"], 6): m["predicted"] for m in msgs}
    from node.training.fit import load_runs
    runs = load_runs([str(phased / "train.mcap")], quiet=True)
    preds = predict_segments(bundle.ocs, runs, bundle.schedule, "yB", bundle.curve, bundle.config)
    pairs = [(node.get(round(float(t), 6)), p) for s in preds for t, p in zip(s.t, s.predicted)]
    assert pairs and all(a is not None for a, _ in pairs)
    np.testing.assert_allclose([a for a, _ in pairs], [b for _, b in pairs], rtol=1e-9, atol=1e-9)


def test_no_phase_trains_an_amplitude_only_model_whose_messages_have_no_vector_fields(
        phased: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    out = tmp_path / "m"
    assert main(["train", str(phased / "train.mcap"), "--schedule", str(phased / "train.schedule.toml"),
                 "--out", str(out), "--method", "lasso", "--inputs", "nB", "--target", "yB", "--quiet",
                 "--workers", "1", "--no-phase"]) == 0
    bundle = load_bundle(out)
    assert "curve:vector" not in [r.kind for r in bundle.ocs]
    assert not any(k.startswith("vector") for k in bundle.checks)
    rec = tmp_path / "node.mcap"
    assert main(["replay", str(phased / "train.mcap"), "--model", str(out), "--out", str(rec),
                 "--quiet"]) == 0
    capsys.readouterr()
    assert not any(k.startswith(("measured_phase", "vector")) for m in _monitor(rec) for k in m)


def test_a_huge_finite_value_neither_raises_nor_stops_the_checks():
    """1e300 passes the payload rule (finite); squaring it with ** would raise OverflowError.
    The check goes on, and on the next plateau it finds a step as before."""
    from node.contract.vector import order_vector
    rng = np.random.default_rng(3)
    for huge in (1e300, complex(1e300, -1e300)):
        chk = StepCheck(threshold=8.0)
        for _ in range(400):
            chk.step(1.0 + 0.01 * rng.standard_normal(), True)
        assert isinstance(chk.step(huge, True), float)
        chk.step(1.0, False)  # the plateau ends
        level = 1.0 + 0.01 * rng.standard_normal(700) + 0.5 * (np.arange(700) >= 600)
        flags = [(chk.step(v, True), chk.flagged)[1] for v in level.tolist()]
        assert not any(flags[:600]) and flags.index(True) <= 640
    assert np.isnan(order_vector(1.0, float("inf")))


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.lists(st.tuples(st.integers(0, 5999), st.sampled_from(["nB", "yB", "yB_ph"]),
                          st.sampled_from([1e300, -1e300, 1e-300, 0.0, -0.0, float("nan"), 7e5, -400.0])),
                min_size=1, max_size=40))
def test_extreme_values_on_any_channel_never_stop_a_phase_pipeline(phased: Path, hits: list) -> None:
    """Finite extremes pass the payload rule: every sample still gets its monitor message."""
    from node.contract import Flag
    from node.runtime.align import AlignedSample
    from node.runtime.pipeline import MonitorPipeline
    from node.training.runs import read_runs
    bundle = load_bundle(phased / "model")
    run = read_runs(phased / "train.mcap")[1]
    pipe = MonitorPipeline(bundle)
    cols = {c: run.column(c) for c in pipe.sensor_channels}
    n = min(6000, len(run.t))
    bad = {(k, c): v for k, c, v in hits if k < n}
    for k in range(n):
        values = {c: bad.get((k, c), float(cols[c][k])) for c in cols}
        msg, _ = pipe.step(AlignedSample(float(run.t[k]), values, new_run=k == 0))
        assert msg["flag"] in set(Flag)
