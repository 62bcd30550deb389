"""The average of an OC's best curves (issue 13): its stepper, its CV, the choice, the bundle,
and the node running it as training predicted it."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from node.cli import main
from node.contract.schedule import OperatingCondition, Schedule
from node.models.average import AverageModel, average_params, member_label
from node.models.bundle import Bundle, load_bundle, save_bundle
from node.models.kinds import fit_oc_model, model_from_arrays
from node.models.ocmodel import RUN_CURVE, Method, Trajectory
from node.models.result import Calibration, OCResult
from node.runtime.guard import CURVE
from node.sysid.metrics import pooled_eps
from node.training.evaluation import predict_segments
from node.training.ocdata import OCData
from node.training.train import (
    CURVE_AVERAGE,
    CURVE_CANDIDATES,
    cross_validate_candidate,
    curve_model_inputs,
    run_folds,
    train_oc,
)
from node.training.train import (
    oc_trajectories as _trajs_of,
)

VECTOR = {"variant": "vector", "bin": 25.0, "window": 0, "anchor": 40}
INFLUENCE = {"variant": "influence", "bin": 25.0, "anchor": 40}
FLEET = {"variant": "fleet", "bin": 25.0, "window": 40, "deadband": 20.0}
RUN = {"variant": "run"}


def _run(rng: np.random.Generator, n_hist: int = 150, gaps: bool = True,
         noise: float = 0.03) -> tuple[np.ndarray, ...]:
    """A speed profile (history, ramp up, plateau, ramp down), the run's own unbalance turning
    its 1x vector, noise (on each part of the vector), and NaN gaps in speed, amplitude and
    phase: speed, y, z, run_curve (K,)."""
    rate = rng.uniform(2.0, 4.0)
    up = np.arange(2000.0, 3500.0, rate)
    speed = np.concatenate([np.full(n_hist, 2000.0), up, np.full(200, 3500.0), up[::-1]])
    speed = speed + rng.normal(0, 3.0, speed.size)
    u = rng.uniform(0.5, 2.0) * np.exp(1j * rng.uniform(-1.0, 1.0))  # the run's unbalance
    z = (0.6 + u * speed / 2000.0) * np.exp(-1j * speed / 900.0)
    z = z + noise * (rng.standard_normal(speed.size) + 1j * rng.standard_normal(speed.size))
    y = np.abs(z)
    curve = y + rng.normal(0, 0.1, y.size)  # a stand-in for the derived run_curve input
    if gaps:
        for a in (speed, y, curve):
            a[rng.choice(a.size, 15, replace=False)] = np.nan
        z = z.copy()
        z[rng.choice(z.size, 15, replace=False)] = complex(np.nan, np.nan)
    return speed, y, z, curve


def _trajs(rng: np.random.Generator, n: int, gaps: bool = True, noise: float = 0.03) -> list[Trajectory]:
    out = []
    for _ in range(n):
        speed, y, z, curve = _run(rng, gaps=gaps, noise=noise)
        out.append(Trajectory(y, np.column_stack([speed, curve]), start=150, z=z))
    return out


MIXED = average_params([("curve", FLEET, ["nB"]), ("curve", VECTOR, ["nB"]), ("curve", RUN, [RUN_CURVE]),
                        ("curve", INFLUENCE, ["nB"])])


def test_the_stepper_gives_predict_s_numbers_bit_for_bit_with_members_of_every_kind():
    """Amplitude and vector members, on the speed and on run_curve, through NaN gaps: the node's
    stepper and training's predict agree to the last bit; the predicted vector has the
    predicted amplitude and the direction of the vector members' mean vector."""
    rng = np.random.default_rng(5)
    trajs = _trajs(rng, 6)
    m = fit_oc_model("average", MIXED, trajs[:4])
    assert isinstance(m, AverageModel) and m.on_vector and MIXED["inputs"] == ["nB", RUN_CURVE]
    for t in trajs:
        rt = m.runtime()
        rt.start(t.y[:t.start], t.U[:t.start], t.z[:t.start])
        node, vecs = [], []
        for u in t.seg_U.tolist():  # as the pipeline calls it
            node.append(rt.step(u))
            vecs.append(rt.vector)
        np.testing.assert_array_equal(np.array(node), m.predict(t))
        members = [mm.predict(Trajectory(t.y, t.U[:, c], t.start, t.z))
                   for mm, c in zip(m.members, m.columns)]
        np.testing.assert_allclose(m.predict(t), np.mean(members, axis=0), rtol=1e-12)
        ok = np.isfinite(node) & np.isfinite(np.array(vecs))
        assert ok.sum() > 0.8 * len(node)
        np.testing.assert_allclose(np.abs(np.array(vecs)[ok]), np.array(node)[ok], rtol=1e-12)
    # without the measured vectors the vector members start without their anchor, as in
    # training on a trajectory without phase
    rt = m.runtime()
    t = trajs[4]
    rt.start(t.y[:t.start], t.U[:t.start])
    np.testing.assert_array_equal([rt.step(u) for u in t.seg_U.tolist()],
                                  m.predict(dataclasses.replace(t, z=None)))


def _ocdata(rng: np.random.Generator, n_runs: int = 6, noise: float = 0.03) -> OCData:
    d = OCData("OC1", "yB", ["nB", RUN_CURVE], [], [], [], [], switch="nB",
               curves=[dict(c) for c in CURVE_CANDIDATES])
    for r, t in enumerate(_trajs(rng, n_runs, gaps=False, noise=noise)):
        d.runs.append(r)
        d.y.append(t.y)
        d.X.append(t.U)
        d.z.append(t.z)
        d.start.append(t.start)
        d.at.append(1000)
    return d


@pytest.mark.parametrize("noise", [0.03, 0.1])
def test_an_average_s_cv_is_its_members_cv_averaged_and_chosen_only_when_lower(noise: float):
    """The CV pairs training averages from the members' are those of fitting the average afresh
    in every fold; the OC's model is the best curve alone or the average of the k best of the
    pool (the 3 best curves and the grid's best model), whichever has the lowest CV eps, and is then
    fitted on every run. With little noise the influence curve alone wins (the data are its
    law); with more, its anchor's noise and the others' errors partly cancel in an average."""
    d = _ocdata(np.random.default_rng(3), noise=noise)
    folds = sorted(set(d.runs))
    scored = []
    for c in d.curves:
        ins = curve_model_inputs(d, c)
        if ins is not None:
            score, pairs = cross_validate_candidate(d, folds, Method.CURVE, c, dict.fromkeys(folds, ins))
            scored.append((score, "curve", c, pairs, ins))
    grid = [{"alpha": 1.0}, {"alpha": 0.01}]
    lasso = [(*cross_validate_candidate(d, folds, "lasso", g, dict.fromkeys(folds, ["nB"])), g) for g in grid]
    score, pairs, g = min(lasso, key=lambda x: x[0])
    pool = sorted(sorted(scored, key=lambda s: s[0])[:CURVE_AVERAGE] + [(score, "lasso", g, pairs, ["nB"])],
                  key=lambda s: s[0])
    options = [next(p for p in pool if p[1] == "curve")]  # a grid model is a member, never alone
    for k in (2, 3):  # the members' CV predictions averaged, against the average's CV afresh
        params = average_params([(m, p, ins) for _, m, p, _, ins in pool[:k]])
        mean = [(y, sum(pool[i][3][n][1] for i in range(k)) / k) for n, (y, _) in enumerate(pool[0][3])]
        options.append((pooled_eps(mean), "average", params, mean, params["inputs"]))
        if all(m == "curve" for _, m, _, _, _ in pool[:k]):
            again, fresh = cross_validate_candidate(d, folds, Method.AVERAGE, params,
                                           dict.fromkeys(folds, params["inputs"]), parts=False)
            assert again == options[-1][0]
            for (y, p), (y2, p2) in zip(mean, fresh, strict=True):
                np.testing.assert_array_equal(y, y2)
                np.testing.assert_array_equal(p, p2)
    expected = min(options, key=lambda o: o[0])  # the first of equals: the smaller k
    res = train_oc(d, "lasso", {"alpha": [a["alpha"] for a in grid]}, ["nB"], 1)
    assert (res.cv_eps, res.params, res.inputs) == (expected[0], expected[2], expected[4])
    assert res.model is not None and res.model.method is Method(expected[1])
    if expected[1] == "average":
        model = fit_oc_model("average", expected[2], _trajs_of(d, list(range(len(d.runs))), expected[4]))
        for key, value in model.arrays().items():
            np.testing.assert_array_equal(res.model.arrays()[key], value)
        assert res.kind == "average:" + member_label(expected[2])
    assert (res.model.method is Method.AVERAGE) == (noise > 0.05)  # both branches taken
    # the pruned CV chooses and fits the same
    full = train_oc(d, "lasso", {"alpha": [a["alpha"] for a in grid]}, ["nB"], 1, prune=False)
    assert (full.params, full.cv_eps, full.calibration) == (res.params, res.cv_eps, res.calibration)


def test_beyond_max_folds_the_cv_holds_out_blocks_of_runs_and_pruning_keeps_the_choice():
    """12 runs in 4 folds of 3 consecutive runs: a candidate's CV is the fits on the other
    blocks, predicting each block; the pruned CV chooses, scores and calibrates as the full."""
    d = _ocdata(np.random.default_rng(8), n_runs=12, noise=0.1)
    d.folds = run_folds(12, 4)
    assert d.fold_ids() == [0, 3, 6, 9]
    score, pairs = cross_validate_candidate(d, d.fold_ids(), Method.CURVE, FLEET,
                                            dict.fromkeys(d.fold_ids(), ["nB"]))
    again = []
    for f in d.fold_ids():
        fit_rows = [i for i in range(12) if not f <= d.runs[i] < f + 3]
        m = fit_oc_model("curve", FLEET, _trajs_of(d, fit_rows, ["nB"]))
        again += [(t.seg_y, m.predict(t)) for t in _trajs_of(d, [f, f + 1, f + 2], ["nB"])]
    assert len(pairs) == 12 and score == pooled_eps(again)
    grid = {"alpha": [1.0, 0.01]}
    res = train_oc(d, "lasso", grid, ["nB"], 1)
    full = train_oc(d, "lasso", grid, ["nB"], 1, prune=False)
    assert (full.params, full.cv_eps, full.calibration) == (res.params, res.cv_eps, res.calibration)
    assert res.n_runs == 12 and len(res.calibration.peaks) == 12


def test_a_bundle_stores_and_loads_an_average_as_json_and_arrays(tmp_path: Path):
    rng = np.random.default_rng(9)
    trajs = _trajs(rng, 4)
    m = fit_oc_model("average", MIXED, trajs[:3])
    res = OCResult("OC1", m, list(MIXED["inputs"]), MIXED, 3, 0.1, 0.2, Calibration(0.3, 4.0))
    curve = (np.array([2000.0, 3500.0]), np.array([1.0, 2.0]))
    save_bundle(Bundle("wdmd", "yB", Schedule((OperatingCondition("OC1", 3500.0),)), [res], curve=curve),
                tmp_path / "m")
    manifest = json.loads((tmp_path / "m" / "manifest.json").read_text())
    assert manifest["ocs"][0]["model"]["method"] == "average"
    q = load_bundle(tmp_path / "m").ocs[0]
    assert isinstance(q.model, AverageModel) and q.params == MIXED
    assert q.kind == "average:fleet+vector+run+influence"
    np.testing.assert_array_equal(q.model.predict(trajs[3]), m.predict(trajs[3]))
    # a member's arrays missing or an input the average lacks: refused, not half-loaded
    arrays = {k: v for k, v in m.arrays().items() if not k.startswith("m1/")}
    with pytest.raises(KeyError):
        model_from_arrays("average", MIXED, arrays)
    with pytest.raises(ValueError, match="input"):
        fit_oc_model("average", {**MIXED, "inputs": ["nB"]}, trajs)


@pytest.mark.parametrize("dynamic", [False, True])
def test_the_node_runs_an_average_of_amplitude_and_vector_models_as_training_predicts_it(
        phased: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], dynamic: bool):
    """Every OC's model made an average of its fleet and vector curves, and a Delay-DMD (fitted
    on the training runs): replay's monitor messages carry training's predictions, to the last
    bit for the curves alone (a state-space stepper folds the input scaling into its matrix:
    rounding apart), and the predicted phase is the vector member's."""
    from node.training.fit import load_runs
    from node.training.train import oc_datasets

    bundle = load_bundle(phased / "model")
    runs = load_runs([str(phased / "train.mcap")], quiet=True)
    members = [("curve", FLEET, ["nB"]), ("curve", VECTOR, ["nB"])]
    params = average_params(members + ([("delay-dmd", {"delays": 2}, ["nB"])] if dynamic else []))
    datas = oc_datasets(runs, bundle.schedule, "yB", ["nB"], history_s=bundle.config.history_s)
    ocs = []
    for r, d in zip(bundle.ocs, datas):
        if r.model is None:
            ocs.append(r)
            continue
        model = fit_oc_model("average", params, [Trajectory(y, X, s, z) for y, X, s, z in
                                                 zip(d.y, d.X, d.start, d.z)])
        ocs.append(dataclasses.replace(r, model=model, params=params, inputs=["nB"]))
    mine = dataclasses.replace(bundle, ocs=ocs)
    save_bundle(mine, tmp_path / "m")
    out = tmp_path / "node.mcap"
    assert main(["replay", str(phased / "train.mcap"), "--model", str(tmp_path / "m"), "--out", str(out),
                 "--quiet"]) == 0
    capsys.readouterr()
    with open(out, "rb") as f:
        topics = ["testbed/bed1/monitor/yB"]
        msgs = [json.loads(m.data) for _, _, m in make_reader(f).iter_messages(topics=topics)]
    assert all(m["model"] is None or m["model"].startswith("average:") for m in msgs)
    node = {round(m["t"], 6): m for m in msgs}
    preds = predict_segments(ocs, runs, bundle.schedule, "yB", bundle.curve, bundle.config)
    pairs = [(node[round(float(t), 6)]["predicted"], p) for s in preds for t, p in zip(s.t, s.predicted)]
    assert len(pairs) > 1000
    a = np.array([math.nan if x is None else x for x, _ in pairs])
    if dynamic:
        assert np.isfinite(a).mean() > 0.95
        np.testing.assert_allclose(a, np.array([p for _, p in pairs]), rtol=1e-9, atol=1e-9)
    else:
        np.testing.assert_array_equal(a, np.array([p for _, p in pairs]))
    # the vector member's phase where the model predicts; none where the curve guard took over
    # (the characteristic curve has no phase): the start from light-off, often
    phases = [m["predicted_phase"] for m in msgs if m["model"] and not m["model"].endswith(CURVE)]
    assert sum(p is not None for p in phases) > 0.9 * len(phases)
    assert all(m["predicted_phase"] is None for m in msgs if m["model"] and m["model"].endswith(CURVE))
