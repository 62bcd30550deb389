"""The parametric OC model (``prom``): a history-dependent OC recovered, picked by the CV, its
stepper equal to its batch prediction, bundles round-trip."""

from __future__ import annotations

import numpy as np
import orjson
import pytest

from node.contract import FS
from node.models.kinds import model_from_arrays
from node.models.ocmodel import Trajectory
from node.models.prom import ParametricOCModel
from node.training.ocdata import OCData
from node.training.runs import Run
from node.training.train import CURVE_CANDIDATES, PROM_CANDIDATES, train_oc

HIST = 100  # samples of past before each OC


def _run(rng: np.random.Generator, p: float, n: int = 1200) -> tuple[np.ndarray, np.ndarray]:
    """Speed steps around 3000 rpm; the order follows them with a time constant set by the
    history parameter p in [0, 1]: y[k+1] = a y[k] + (1 - a) g (speed[k] - 3000) / 1000,
    a = 0.90 + 0.08 p, g = 1 (a warm engine answers slowly)."""
    speed = 3000.0 + np.repeat(rng.uniform(-300.0, 300.0, n // 60 + 1), 60)[:n]
    a = 0.90 + 0.08 * p
    y = np.zeros(n)
    for k in range(n - 1):
        y[k + 1] = a * y[k] + (1.0 - a) * (speed[k] - 3000.0) / 1000.0
    return speed, y + 1.0 + rng.normal(0.0, 1e-3, n)


def _ocdata(rng: np.random.Generator, ps: list[float]) -> OCData:
    d = OCData("OC1", "yB", ["nB", "hist_thermal"], [], [], [], [], switch="nB",
               curves=[dict(c) for c in CURVE_CANDIDATES if c["variant"] != "run"],
               proms=[dict(c) for c in PROM_CANDIDATES], unranked=["hist_thermal"])
    for r, p in enumerate(ps):
        speed, y = _run(rng, p)
        d.runs.append(r)
        d.y.append(y)
        d.X.append(np.column_stack([speed, np.full(speed.size, p)]))
        d.start.append(HIST)
        d.at.append(HIST)
    return d


def test_the_cv_picks_the_parametric_model_for_history_dependent_dynamics():
    rng = np.random.default_rng(5)
    ps = [0.0, 0.2, 0.4, 0.6, 0.8, 1.0]
    d = _ocdata(rng, ps)
    res = train_oc(d, "delay-dmd", {"delays": [1, 2], "rcond": [1e-8]}, None, 1, prune=False)
    assert isinstance(res.model, ParametricOCModel), res.model
    pruned = train_oc(d, "delay-dmd", {"delays": [1, 2], "rcond": [1e-8]}, None, 1)
    assert (pruned.params, pruned.cv_eps, pruned.calibration) == (res.params, res.cv_eps, res.calibration)
    assert np.inf in [s for _, s in pruned.cv_scores]
    assert res.inputs == ["nB", "hist_thermal"] and res.params["param"] == "hist_thermal"
    grid = min(s for p, s in res.cv_scores if "method" not in p)
    curve = min(s for p, s in res.cv_scores if p.get("method") == "curve")
    assert res.cv_eps < 0.5 * grid and res.cv_eps < 0.5 * curve  # beyond the curve margin
    # the history parameter only reaches the parametric model: MS-DPCCA never ranked it
    assert [c for c, _ in res.ranking] == ["nB"]
    # a run at a parameter between the samples: the interpolated time constant
    m = res.model
    pole = float(m.at(0.5).poles().real.max())
    assert pole == pytest.approx(0.94, abs=2e-3)


def test_stepper_equals_batch_and_a_bundle_restores_the_model():
    rng = np.random.default_rng(6)
    d = _ocdata(rng, [0.0, 0.3, 0.7, 1.0])
    trajs = [Trajectory(y, X, s) for y, X, s in zip(d.y, d.X, d.start)]
    for params in ({**PROM_CANDIDATES[0], "weights": "linear"}, {**PROM_CANDIDATES[0], "weights": "regress"}):
        m = ParametricOCModel.fit(ParametricOCModel.method, params, trajs[:3])
        again = model_from_arrays("prom", params, m.arrays())
        speed, y = _run(rng, 0.5)
        t = Trajectory(y, np.column_stack([speed, np.full(speed.size, 0.5)]), HIST)
        batch = m.predict(t)
        for model in (m, again):
            rt = model.runtime()
            rt.start(t.y[:t.start], t.U[:t.start])
            node = np.array([rt.step(u) for u in t.seg_U])  # as the pipeline calls it
            np.testing.assert_allclose(node, batch, rtol=1e-10, atol=1e-12)
        np.testing.assert_array_equal(again.predict(t), batch)
        assert float(np.sqrt(np.mean((batch - y[HIST:]) ** 2))) < 0.01  # the dynamics at p = 0.5


def test_unknown_parameter_takes_equal_weights_and_repeated_values_do_not_interpolate():
    rng = np.random.default_rng(8)
    d = _ocdata(rng, [0.0, 0.5, 1.0])
    trajs = [Trajectory(y, X, s) for y, X, s in zip(d.y, d.X, d.start)]
    m = ParametricOCModel.fit(ParametricOCModel.method, dict(PROM_CANDIDATES[0]), trajs)
    mean = m.rom.at_weights(np.full(3, 1 / 3)).model_
    np.testing.assert_array_equal(m.at(float("nan")).A, mean.A)
    rt = m.runtime()
    rt.start(np.zeros(0), np.zeros((0, 2)))  # no past: from rest, equal weights
    assert np.isfinite(rt.step(np.array([3000.0, np.nan])))
    same = [Trajectory(t.y, np.column_stack([t.U[:, 0], np.zeros(len(t.y))]), t.start) for t in trajs]
    with pytest.raises(ValueError, match="repeated"):
        ParametricOCModel.fit(ParametricOCModel.method, {**PROM_CANDIDATES[0], "weights": "linear"}, same)


def _engine_run(t0: float, seed: int, warmth: float) -> Run:
    """Off, light-off, 4000 rpm, 6000 rpm with speed steps, 4000 rpm, off; the order's time
    constant at 6000 rpm grows with ``warmth``; slow temperatures for the thermal state."""
    t = np.arange(0.0, 120.0, 1 / FS)
    nb = np.interp(t, [0, 5, 8, 25, 35, 85, 95, 112, 116],
                   [100, 100, 4000, 4000, 6000, 6000, 4000, 4000, 100])
    rng = np.random.default_rng(seed)
    steps = np.repeat(rng.uniform(-80.0, 80.0, t.size // 80 + 1), 80)[:t.size]
    nb = nb + np.where((t > 40) & (t < 82), steps, 0.0) + rng.normal(0.0, 2.0, t.size)
    a = 0.90 + 0.08 * warmth
    y = np.zeros(t.size)
    for k in range(t.size - 1):
        y[k + 1] = a * y[k] + (1.0 - a) * nb[k] / 1000.0
    y = y + rng.normal(0.0, 1e-3, t.size)
    slow = np.column_stack([50.0 + 100.0 * warmth + t / 10, 80.0 + t / 20, 20.0 + 0 * t])
    return Run(t0 + t, np.column_stack([nb, y, slow]), ("nB", "yB", "tF", "tI", "tH"), "b", None)


def test_the_node_runs_a_parametric_model_as_training_predicts_it(tmp_path):
    """A bundle with a parametric OC model on the engine history: the node's predictions over
    the OC are the model's own prediction from the training arrays (history at the switch,
    seeding, interpolation), after a save and load."""
    from node.contract.schedule import OperatingCondition, Schedule
    from node.models.bundle import Bundle, load_bundle, save_bundle
    from node.models.config import RuntimeConfig
    from node.models.result import Calibration, OCResult
    from node.runtime.core import NodeCore
    from node.training.dataset import with_history
    from node.training.train import oc_datasets

    sched = Schedule((OperatingCondition("A", 4000.0), OperatingCondition("B", 6000.0)))
    config = RuntimeConfig(history_cooling=5.0e4)
    runs = [_engine_run(1.0e6 + 900.0 * i, i, w) for i, w in enumerate([0.0, 0.3, 0.7, 1.0, 0.1])]
    derived = with_history(runs, sched, config)
    d = oc_datasets(derived, sched, "yB", ["nB", "hist_thermal"], history_s=config.history_s)[1]
    trajs = [Trajectory(y, X, s) for y, X, s in zip(d.y, d.X, d.start)]
    params = {**PROM_CANDIDATES[0], "weights": "regress", "param": "hist_thermal"}
    library = [t for t, r in zip(trajs, d.runs) if r < 4]  # (the speed steps make B several segments)
    model = ParametricOCModel.fit(ParametricOCModel.method, params, library)
    oc = OCResult("B", model, ["nB", "hist_thermal"], params, 4, 0.1, 0.1, Calibration(1.0, 1e9))
    save_bundle(Bundle("wdmd", "yB", sched, [oc], config=config), tmp_path / "m")
    core = NodeCore(load_bundle(tmp_path / "m"))
    got = []
    for run in runs:
        for k in range(len(run.t)):
            for j, ch in enumerate(run.channels):
                payload = {"t": float(run.t[k]), "v": float(run.data[k, j])}
                got += [m for key, m in core.handle(f"testbed/b/sensor/{ch}", orjson.dumps(payload))
                        if key.endswith("/yB")]
    got += [m for key, m in core.finish() if key.endswith("/yB")]
    pred = np.array([np.nan if m["predicted"] is None else m["predicted"] for m in got])
    offsets = np.cumsum([0] + [len(r.t) for r in runs])
    for i, t in enumerate(trajs):  # every run, the one the library left out too
        at = offsets[d.runs[i]] + d.at[i]
        node = pred[at:at + len(t.seg_y)]
        np.testing.assert_allclose(node, model.predict(t), rtol=1e-9, atol=1e-12)
    assert len(trajs) > len(library) > 4
    for t in trajs[len(library):]:  # the run left out: its warmth tells its dynamics
        unknown = Trajectory(t.y, np.column_stack([t.U[:, 0], np.full(len(t.y), np.nan)]), t.start)
        rms, rms_mean = (float(np.sqrt(np.mean((model.predict(x) - t.seg_y) ** 2))) for x in (t, unknown))
        assert rms < 0.5 * rms_mean


def test_two_parameters_pick_the_model_by_both():
    """The time constant set by two history parameters: a = 0.90 + 0.05 p1 + 0.03 p2; the
    least-squares plane through six runs recovers it between them; the stepper follows."""
    rng = np.random.default_rng(9)
    grid = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0), (0.5, 0.0), (0.0, 0.5)]
    trajs = []
    for p1, p2 in grid:
        speed = 3000.0 + np.repeat(rng.uniform(-300.0, 300.0, 21), 60)[:1200]
        a = 0.90 + 0.05 * p1 + 0.03 * p2
        y = np.zeros(speed.size)
        for k in range(speed.size - 1):
            y[k + 1] = a * y[k] + (1.0 - a) * (speed[k] - 3000.0) / 1000.0
        X = np.column_stack([speed, np.full(speed.size, p1), np.full(speed.size, p2)])
        trajs.append(Trajectory(y + rng.normal(0.0, 1e-4, y.size), X, HIST))
    params = {**PROM_CANDIDATES[0], "param": "hist_thermal,hist_energy", "weights": "regress"}
    m = ParametricOCModel.fit(ParametricOCModel.method, params, trajs)
    assert m.rom.params_.shape == (6, 2)
    assert float(m.at([0.5, 0.5]).poles().real.max()) == pytest.approx(0.94, abs=3e-3)
    assert float(m.at([1.0, 0.0]).poles().real.max()) == pytest.approx(0.95, abs=3e-3)
    t = trajs[3]
    rt = model_from_arrays("prom", params, m.arrays()).runtime()
    rt.start(t.y[:t.start], t.U[:t.start])
    np.testing.assert_allclose([rt.step(u) for u in t.seg_U], m.predict(t), rtol=1e-10, atol=1e-12)


def test_the_cv_s_free_run_is_the_state_space_s_own_to_the_last_bit():
    from node.models.prom import _free_run
    from node.sysid import StateSpace

    rng = np.random.default_rng(0)
    for A in (np.diag([0.5, 0.97, 0.2]), np.array([[0.9, 0.1, 0.0], [-0.1, 0.9, 0.0], [0.0, 0.0, 0.5]])):
        ss = StateSpace(A, rng.normal(size=(3, 2)), rng.normal(size=(1, 3)), rng.normal(size=(1, 2)), 0.025)
        U, x0 = rng.normal(size=(2000, 2)), rng.normal(size=3)
        np.testing.assert_array_equal(_free_run(ss, U, x0), ss.simulate(U, x0)[:, 0])
