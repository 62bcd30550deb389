"""The run's own characteristic curve (``run_curve``): semantics, and node == training."""

from __future__ import annotations

import math

import numpy as np
import orjson
import pytest

from node.contract.schedule import OperatingCondition, Schedule
from node.models.bundle import Bundle
from node.models.ocmodel import InputScaling, RegressionModel
from node.models.result import Calibration, OCResult
from node.runtime.core import NodeCore
from node.runtime.runcurve import RUN_CURVE, RunCurve, add_run_curve
from node.training.runs import Run

FLEET = (np.array([0.0, 10000.0]), np.array([1.0, 1.0]))  # the fleet says 1.0 everywhere


def test_run_curve_uses_earlier_segments_only_and_the_fleet_elsewhere():
    rc = RunCurve(np.array([0.0, 10000.0]), np.array([0.0, 10.0]))  # fleet: 1 per 1000 rpm
    assert rc.step(4010.0, 7.0, False) == pytest.approx(4.01)  # not seen yet: the fleet
    assert rc.step(4020.0, 9.0, False) == pytest.approx(4.02)  # own segment: no
    assert rc.step(6000.0, 1.0, True) == 6.0  # a new segment at another speed: the fleet
    assert rc.step(4030.0, 5.0, True) == 8.0  # back at 4000-4050 rpm: the earlier mean (7 + 9) / 2
    assert rc.step(4030.0, 5.0, False) == 8.0  # the current segment's 5.0 does not count
    assert math.isnan(rc.step(math.nan, 5.0, False))
    assert rc.step(6010.0, math.nan, True) == 1.0  # the 6000 bin from the second segment
    rc.reset()  # a new run forgets everything
    assert rc.step(4030.0, 1.0, False) == pytest.approx(4.03)
    for s in (-5.0, 0.0, 2500.0, 9999.0, 10000.0, 12000.0):  # the fleet curve is np.interp's
        assert rc.fleet(s) == pytest.approx(float(np.interp(s, [0, 10000], [0, 10])), abs=1e-12)


def _profile() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """t (s), nB (rpm), yB (mm/s): 4000 rpm, up to 6000, back to 4000, with dropouts."""
    fs = 40.0
    knots_t = [0.0, 20.0, 30.0, 50.0, 60.0, 80.0]
    knots_v = [4000.0, 4000.0, 6000.0, 6000.0, 4000.0, 4000.0]
    t = np.arange(0.0, 80.0, 1.0 / fs)
    nb = np.interp(t, knots_t, knots_v)
    rng = np.random.default_rng(3)
    yb = 2.0 + nb / 2000.0 + rng.normal(0.0, 0.05, t.size) + np.where(t > 70.0, 1.5, 0.0)
    nb[[100, 101, 2500]] = np.nan
    yb[[50, 1200, 2900]] = np.nan
    return t, nb, yb


def test_the_node_computes_the_very_feature_training_saw():
    sched = Schedule((OperatingCondition("A", 4000.0), OperatingCondition("B", 6000.0)))
    # a Lasso model "yB = run_curve": the node's prediction is the feature itself
    model = RegressionModel({"alpha": 1.0}, InputScaling(np.array([0.0]), np.array([1.0])),
                            coef=np.array([1.0]), intercept=0.0)
    ocs = [OCResult(n, model, [RUN_CURVE], {}, 8, 0.1, 0.1, Calibration(1.0, 1e9)) for n in ("A", "B")]
    core = NodeCore(Bundle("lasso", "yB", sched, ocs, curve=FLEET))
    t, nb, yb = _profile()
    out = []
    for k in range(t.size):
        for ch, v in (("nB", nb[k]), ("yB", yb[k])):
            payload = {"t": float(1000.0 + t[k]), "v": None if np.isnan(v) else float(v)}
            out += core.handle(f"testbed/b/sensor/{ch}", orjson.dumps(payload))
    out += core.finish()
    mon = [m for key, m in out if key.endswith("/yB")]
    assert len(mon) == t.size
    # the derived input is never awaited from the test bed: no sample waits for it
    align = core.beds["b"].aligner.stats
    assert sum(align.missing.values()) == 0  # nulls arrive; run_curve is not "missing"
    run = Run(1000.0 + t, np.column_stack([nb, yb]), ("nB", "yB"), "b", None)
    offline = add_run_curve(run, sched, "yB", FLEET).column(RUN_CURVE)
    pred = np.array([np.nan if m["predicted"] is None else m["predicted"] for m in mon])
    has = np.isfinite(pred)
    assert has.sum() > 0.6 * t.size
    np.testing.assert_array_equal(pred[has], offline[has])  # to the last bit
    # the return to 4000 rpm predicts the first plateau's level, not the +1.5 of its own end
    back = (t > 72.0) & has
    assert np.all(np.abs(pred[back] - 4.0) < 0.05)


def test_a_bundle_taking_run_curve_without_a_fleet_curve_is_refused(tmp_path):
    from node.contract.errors import OrdervibError
    from node.models.bundle import load_bundle, save_bundle

    sched = Schedule((OperatingCondition("A", 4000.0),))
    model = RegressionModel({"alpha": 1.0}, InputScaling(np.array([0.0]), np.array([1.0])),
                            coef=np.array([1.0]), intercept=0.0)
    res = OCResult("A", model, [RUN_CURVE], {}, 8, 0.1, 0.1, Calibration(1.0, 5.0))
    save_bundle(Bundle("lasso", "yB", sched, [res], curve=FLEET), tmp_path / "ok")
    assert load_bundle(tmp_path / "ok").oc("A").inputs == [RUN_CURVE]
    save_bundle(Bundle("lasso", "yB", sched, [res]), tmp_path / "bad")
    with pytest.raises(OrdervibError, match="malformed bundle.*characteristic curve"):
        load_bundle(tmp_path / "bad")
