"""The characteristic-curve OC model: exact recovery, its stepper, the CV's choice, bundles."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from node.contract.schedule import OperatingCondition, Schedule
from node.models.bundle import Bundle, load_bundle, save_bundle
from node.models.curve import CurveModel, Variant
from node.models.kinds import fit_oc_model, model_from_arrays
from node.models.ocmodel import RUN_CURVE, Method, StateSpaceModel, Trajectory
from node.models.result import OCResult
from node.training.ocdata import OCData
from node.training.train import CURVE_CANDIDATES, CURVE_MARGIN, FEW_RUNS, curve_candidates, train_oc

FLEET = {"variant": "fleet", "bin": 25.0, "window": 40, "deadband": 20.0}


def _profile(rng: np.random.Generator, lo: float, hi: float, n_hist: int = 200) -> np.ndarray:
    """A speed history at ``lo``, a ramp to ``hi`` at a random rate, a plateau, a ramp back."""
    rate = rng.uniform(2.0, 4.0)  # rpm per sample
    up = np.arange(lo, hi, rate)
    return np.concatenate([np.full(n_hist, lo), up, np.full(300, hi), up[::-1]]) + rng.normal(0, 2.0, 1)


def _law(speed: np.ndarray, code: np.ndarray) -> np.ndarray:
    """A speed-amplitude law, another one on the way down, another on the plateau."""
    up = 1.0 + np.sin(speed / 300.0)
    return np.choose(code, [0.5 + 0.0 * speed, up, 2.0 * up])


def _codes(speed: np.ndarray, window: int = 40, deadband: float = 20.0) -> np.ndarray:
    from node.models.curve import direction_codes
    return direction_codes(np.zeros(0), speed, window, deadband)


def test_recovers_a_speed_amplitude_law_rising_and_falling_apart():
    """Bins of the law's own speeds: a bin per sample speed, its means are the law's values."""
    speed = np.concatenate([np.full(100, 1000.0), np.arange(1000.0, 3000.0, 25.0),
                            np.full(100, 3000.0), np.arange(3000.0, 1000.0, -25.0)]) + 12.5
    code = _codes(speed)
    y = _law(speed, code)
    traj = Trajectory(y, speed[:, None], start=0)
    m = CurveModel.fit(Method.CURVE, FLEET, [traj])
    pred = m.predict(traj)
    np.testing.assert_allclose(pred, y, rtol=0, atol=1e-12)  # rising and falling apart
    assert set(np.unique(code)) == {0, 1, 2}
    one = CurveModel.fit(Method.CURVE, {**FLEET, "window": 0}, [traj])  # one curve: the mean
    assert np.max(np.abs(one.predict(traj) - y)) > 0.5


def test_stepper_equals_batch_predict_bit_for_bit():
    rng = np.random.default_rng(3)
    trajs = []
    for _ in range(4):
        speed = _profile(rng, 2000.0, 4000.0) + rng.normal(0, 3.0, 1)
        speed = speed + rng.normal(0, 4.0, speed.size)
        y = _law(speed, _codes(speed)) + rng.normal(0, 0.05, speed.size)
        z = y * np.exp(-1j * (speed / 1000.0 + rng.uniform(0, 6.3)))  # the phase turns with speed
        trajs.append(Trajectory(y, speed[:, None], start=150, z=z))
    lookups = [c for c in CURVE_CANDIDATES if c["variant"] != "run"]
    assert {"anchored", "vector", "influence"} <= {c["variant"] for c in lookups}
    for params in lookups:
        m = CurveModel.fit(Method.CURVE, params, trajs[:3])
        for t in trajs:
            rt = m.runtime()
            past = t.z if Variant(params["variant"]).on_vector else t.y
            rt.start(past[:t.start], t.U[:t.start])
            node = [rt.step([u]) for u in t.seg_U[:, 0].tolist()]  # as the pipeline calls it
            np.testing.assert_array_equal(np.array(node), m.predict(t))
    run = fit_oc_model("curve", {"variant": "run"}, trajs)
    rt = run.runtime()
    rt.start(np.zeros(0), np.zeros((0, 1)))
    np.testing.assert_array_equal([rt.step([u]) for u in trajs[0].seg_U[:, 0].tolist()],
                                  run.predict(trajs[0]))


def _ocdata(y_of, rng: np.random.Generator, n_runs: int = 5) -> OCData:
    d = OCData("OC1", "yB", ["nB", "u1", RUN_CURVE], [], [], [], [], switch="nB",
               curves=[dict(c) for c in CURVE_CANDIDATES])
    for r in range(n_runs):
        speed = _profile(rng, 2000.0, 3500.0, n_hist=100)
        speed = speed + rng.normal(0, 2.0, speed.size)
        u1 = np.cumsum(rng.normal(0, 1.0, speed.size)) * 0.05
        y = y_of(speed, u1, r)
        X = np.column_stack([speed, u1, np.full(speed.size, y.mean())])
        d.runs.append(r)
        d.y.append(y)
        d.X.append(X)
        d.start.append(100)
        d.at.append(1000)
    return d


def test_training_picks_the_curve_for_a_function_of_speed_and_a_dmd_for_dynamics():
    rng = np.random.default_rng(7)
    static = _ocdata(lambda s, u, r: _law(s, _codes(s)) + rng.normal(0, 0.02, s.size), rng)
    res = train_oc(static, "delay-dmd", {"delays": [1, 2], "rcond": [1e-8]}, None, 2)
    assert isinstance(res.model, CurveModel) and res.params["variant"] in ("fleet", "anchored")
    assert res.inputs == ["nB"] and res.calibration is not None
    # each run's level scaled by its own factor (its imbalance): the curve anchored at the switch
    factors = rng.uniform(0.5, 2.0, 5)
    scaled = _ocdata(lambda s, u, r: factors[r] * _law(s, _codes(s)) + rng.normal(0, 0.02, s.size), rng)
    res = train_oc(scaled, "delay-dmd", {"delays": [1, 2], "rcond": [1e-8]}, None, 2, prune=False)
    assert isinstance(res.model, CurveModel) and res.params["variant"] == "anchored"
    fleet_scores = [s for p, s in res.cv_scores if p.get("variant") == "fleet"]
    assert res.cv_eps < 0.5 * min(fleet_scores)

    def dynamic(s, u, r):
        y = np.zeros(s.size)
        for k in range(1, s.size):
            y[k] = 0.95 * y[k - 1] + 0.5 * u[k - 1]
        return y
    dyn = _ocdata(dynamic, rng, n_runs=FEW_RUNS)
    res = train_oc(dyn, "delay-dmd", {"delays": [1, 2], "rcond": [1e-8]}, ["u1"], 2, prune=False)
    assert isinstance(res.model, StateSpaceModel)
    # with fewer runs the same dynamics are a member of the curves' average, never alone
    few = dataclasses.replace(dyn, runs=dyn.runs[:-1], y=dyn.y[:-1], X=dyn.X[:-1], start=dyn.start[:-1],
                              at=dyn.at[:-1])
    res_few = train_oc(few, "delay-dmd", {"delays": [1, 2], "rcond": [1e-8]}, ["u1"], 2, prune=False)
    assert res_few.model.method == "average" and "delay-dmd" in res_few.kind
    curve_scores = [s for p, s in res.cv_scores if p.get("method") == "curve"]
    assert curve_scores and min(curve_scores) > res.cv_eps
    # without curve candidates the grid's numbers are those of the plain CV
    dyn.curves = []
    plain = train_oc(dyn, "delay-dmd", {"delays": [1, 2], "rcond": [1e-8]}, ["u1"], 2)
    assert plain.cv_eps == res.cv_eps and plain.params == res.params


def _same_result(a: OCResult, b: OCResult) -> bool:
    """The same choice, inputs, errors, calibration and model arrays (bit for bit)."""
    if (a.kind, a.params, a.inputs, a.cv_eps, a.train_eps, a.calibration) != \
            (b.kind, b.params, b.inputs, b.cv_eps, b.train_eps, b.calibration):
        return False
    x, y = a.model.arrays(), b.model.arrays()
    return sorted(x) == sorted(y) and all(np.array_equal(x[k], y[k]) for k in x)


@pytest.mark.parametrize("law", ["static", "scaled", "dynamic", "mixed"])
def test_pruned_cv_chooses_and_fits_as_the_full_cv(law: str) -> None:
    """Stopping a candidate's CV once it cannot be chosen changes nothing chosen or fitted; the
    pruned candidates' scores are inf, the others' those of the full CV."""
    rng = np.random.default_rng(11)
    factors = rng.uniform(0.5, 2.0, FEW_RUNS)

    def dynamic(s, u, r):
        y = np.zeros(s.size)
        for k in range(1, s.size):
            y[k] = 0.95 * y[k - 1] + 0.5 * u[k - 1]
        return factors[r] * y if law == "mixed" else y

    laws = {"static": lambda s, u, r: _law(s, _codes(s)) + rng.normal(0, 0.02, s.size),
            "scaled": lambda s, u, r: factors[r] * _law(s, _codes(s)) + rng.normal(0, 0.02, s.size),
            "dynamic": dynamic,
            "mixed": lambda s, u, r: dynamic(s, u, r) + _law(s, _codes(s)) + rng.normal(0, 0.05, s.size)}
    d = _ocdata(laws[law], rng, n_runs=FEW_RUNS)
    grid = {"delays": [1, 2, 4], "rcond": [1e-8]}
    full = train_oc(d, "delay-dmd", grid, ["u1"], 2, prune=False)
    pruned = train_oc(d, "delay-dmd", grid, ["u1"], 2)
    assert _same_result(full, pruned), (full.kind, pruned.kind)
    assert isinstance(full.model, StateSpaceModel) == (law == "dynamic")  # both paths covered
    if law == "mixed":  # the Delay-DMD, best of the pool but not by the margin: a member
        assert full.model.method == "average" and "delay-dmd" in full.kind
    assert [p for p, _ in full.cv_scores] == [p for p, _ in pruned.cv_scores]
    for (_, s), (_, t) in zip(full.cv_scores, pruned.cv_scores):
        assert t == s or (t == np.inf and s >= (1 - CURVE_MARGIN) * min(v for _, v in pruned.cv_scores))
    if law != "dynamic":  # there the curves lose, each to the one before it at most
        assert sum(t == np.inf for _, t in pruned.cv_scores) > 0


@pytest.mark.parametrize("variant", ["fleet", "run", "anchored"])
def test_bundle_with_a_curve_model_saves_and_loads(tmp_path, variant):
    rng = np.random.default_rng(1)
    speed = _profile(rng, 2000.0, 3000.0)
    y = _law(speed, _codes(speed))
    col = y + 0.1 if variant == "run" else speed
    traj = Trajectory(y, col[:, None], start=100)
    params = {"fleet": FLEET, "run": {"variant": "run"},
              "anchored": {**FLEET, "variant": "anchored", "anchor": 40}}[variant]
    m = fit_oc_model("curve", params, [traj])
    again = model_from_arrays("curve", params, m.arrays())
    np.testing.assert_array_equal(again.predict(traj), m.predict(traj))
    from node.models.result import Calibration, OCResult
    schedule = Schedule((OperatingCondition("OC1", 3000.0),))
    res = OCResult("OC1", m, [RUN_CURVE if variant == "run" else "nB"], dict(params), 2, 0.1, 0.2,
                   Calibration(0.3, 4.0))
    curve = (np.array([2000.0, 3000.0]), np.array([1.0, 2.0]))
    save_bundle(Bundle("wdmd", "yB", schedule, [res], curve=curve), tmp_path / "m")
    loaded = load_bundle(tmp_path / "m")
    q = loaded.ocs[0]
    assert isinstance(q.model, CurveModel) and q.model.method is Method.CURVE
    assert q.params == res.params and q.inputs == res.inputs
    np.testing.assert_array_equal(q.model.predict(traj), m.predict(traj))


def test_a_direction_with_few_samples_in_a_bin_takes_the_bins_mean():
    # bin [1000, 1025): 20 steady samples at 1.0 and one falling sample at 9.0
    speed = np.concatenate([np.full(20, 1010.0), [1200.0, 1010.0]])
    y = np.concatenate([np.full(20, 1.0), [5.0, 9.0]])
    traj = Trajectory(y, speed[:, None], start=0)
    params = {"variant": "fleet", "bin": 25.0, "window": 1, "deadband": 20.0}
    alone = CurveModel.fit(Method.CURVE, params, [traj])
    pooled = CurveModel.fit(Method.CURVE, {**params, "min_count": 2}, [traj])
    falling = 2  # the row of a falling speed
    assert alone.means[falling, 0] == 9.0  # one sample decides the falling curve there
    assert pooled.means[falling, 0] == pytest.approx(29.0 / 21.0)  # the bin's mean instead


@pytest.mark.parametrize("vector", [False, True])
def test_the_anchor_s_vectorised_lookups_are_the_scalar_lookups_to_the_last_bit(vector):
    """The anchor's curve level at the switch (mean over its window of the steady curve at each
    past speed) from the vectorised lookups equals the per-sample scalar lookups exactly."""
    from node.models.curve import STEADY, _mean

    rng = np.random.default_rng(11)
    for _ in range(50):
        B = int(rng.integers(1, 40))
        means = rng.normal(size=(3, B)) + (1j * rng.normal(size=(3, B)) if vector else 0.0)
        m = CurveModel({"variant": "vector" if vector else "anchored", "window": 0, "anchor": 40},
                       np.sort(rng.uniform(1000.0, 9000.0, B)), means)
        rt = m.runtime()
        x = rng.uniform(500.0, 9500.0, 400)  # beyond both ends too
        scalar = _mean([rt._lookup(v, STEADY) for v in x.tolist()])
        c = rt._lookups(x, STEADY)
        vectorised = _mean(c.tolist() if vector else c.real.tolist())
        assert vectorised == scalar and type(vectorised) is type(scalar)


def _bowed_runs(rng: np.random.Generator, n_runs: int, alpha: float, tau_s: float, noise: float
                ) -> list[Trajectory]:
    """Runs at a steady 3000 rpm after a start: the fleet's 1x vector plus the run's own
    deviation (of one size, the runs' phases spread evenly), of which the share ``alpha``
    stays and the rest (a bow) fades with ``tau_s`` from the switch on; the deviation at the
    switch is in the past the anchor sees."""
    k_hist, k_seg = 80, 2400  # 2 s of past, 60 s in the OC
    speed = np.full(k_hist + k_seg, 3000.0)
    base = 1.0 + 0.5j
    out = []
    turn = rng.uniform(0, 2 * np.pi)
    for r in range(n_runs):  # deviations of every phase, their mean 0: the fleet curve is the base
        dev = 0.6 * np.exp(1j * (turn + 2 * np.pi * r / n_runs))
        k = np.arange(k_hist + k_seg) - k_hist
        share = np.where(k < 0, 1.0, alpha + (1 - alpha) * np.exp(-np.maximum(k, 0) / (tau_s * 40.0)))
        z = base + dev * share + noise * (rng.standard_normal(k.size) + 1j * rng.standard_normal(k.size))
        out.append(Trajectory(np.abs(z), speed[:, None], k_hist, z))
    return out


@pytest.mark.parametrize("variant", ["vector", "influence"])
def test_a_fading_deviation_at_the_switch_is_learned_and_followed(variant: str):
    """A bowed start (issue 30): the run's deviation at the switch fades, a quarter of it stays.
    The anchored vector curve learns the share that stays and the fade time from the runs, and a
    new run is followed as it fades (the held anchor is wrong by the faded part); the node's
    stepper gives the batch prediction bit for bit."""
    rng = np.random.default_rng(11)
    params = {"variant": variant, "bin": 25.0, "window": 0, "anchor": 40, "fade": True}
    trajs = _bowed_runs(rng, 6, 0.25, 60.0, 0.005)
    m = CurveModel.fit(Method.CURVE, params, trajs)
    alpha, beta, ratio = m.decay
    assert alpha / (alpha + beta) == pytest.approx(0.25, rel=1e-12)  # influence: times a scale
    assert ratio == pytest.approx(np.exp(-1 / (60.0 * 40.0)), rel=1e-12)
    held = CurveModel.fit(Method.CURVE, params, trajs)
    held = CurveModel(held.params, held.centres, held.means, held.weights, held.gains, held.anchor_mean)
    new = _bowed_runs(rng, 3, 0.25, 60.0, 0.005)
    for t in new:
        truth = np.abs(t.z[t.start:])
        rms, rms_held = (np.sqrt(np.mean((x.predict(t) - truth) ** 2)) for x in (m, held))
        assert rms < 0.02 and rms_held > 4 * rms
        rt = m.runtime()
        rt.start(t.z[:t.start], t.U[:t.start])
        node = [rt.step([u]) for u in t.seg_U[:, 0].tolist()]
        np.testing.assert_array_equal(np.array(node), m.predict(t))
    again = model_from_arrays("curve", m.params, m.arrays())
    np.testing.assert_array_equal(again.decay, m.decay)
    np.testing.assert_array_equal(again.predict(new[0]), m.predict(new[0]))


def test_noise_alone_keeps_the_anchor_held():
    """Runs whose deviation stays (no bow): the fade's two more parameters do not pay for
    themselves, the anchor is held as before."""
    rng = np.random.default_rng(5)
    trajs = _bowed_runs(rng, 6, 1.0, 60.0, 0.02)
    for variant in ("anchored", "vector", "influence"):
        m = CurveModel.fit(Method.CURVE, {"variant": variant, "bin": 25.0, "window": 0, "anchor": 40,
                                          "fade": True}, trajs)
        assert tuple(m.decay) == (1.0, 0.0, 1.0), variant


def test_a_bundle_decay_out_of_range_is_refused():
    params = {"variant": "vector", "bin": 25.0, "window": 0, "anchor": 40, "fade": True}
    m = CurveModel.fit(Method.CURVE, params, _bowed_runs(np.random.default_rng(2), 3, 0.25, 60.0, 0.005))
    arrays = dict(m.arrays())
    for bad in ([1.0, 0.0, 1.5], [np.nan, 0.0, 0.9], [1.0, 0.0, 0.0]):
        arrays["decay"] = np.array(bad)
        with pytest.raises(ValueError, match="decay"):
            model_from_arrays("curve", m.params, arrays)


def test_without_fade_the_anchor_is_held():
    """Params without ``"fade": true`` (the held candidates, old bundles, ``--no-fade``'s): the
    bowed runs' anchor is held; ``train --no-fade`` leaves the fading candidates out."""
    trajs = _bowed_runs(np.random.default_rng(11), 6, 0.25, 60.0, 0.005)
    for variant in ("anchored", "vector", "influence"):
        params = {"variant": variant, "bin": 25.0, "window": 0, "anchor": 40}
        assert tuple(CurveModel.fit(Method.CURVE, {**params, "fade": True}, trajs).decay) != (1.0, 0.0, 1.0)
        assert tuple(CurveModel.fit(Method.CURVE, params, trajs).decay) == (1.0, 0.0, 1.0), variant
    held = curve_candidates(False)
    assert not any(c.get("fade") for c in held) and len(held) < len(curve_candidates(True))
