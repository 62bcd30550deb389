"""The settle anchor (issue 30): what an OC model missed as the visit settled, partly kept."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from conftest import node_messages
from hypothesis import given, settings
from hypothesis import strategies as st

import node.models.settle as settle_mod
import node.runtime.pipeline as pipeline_mod
import node.training.plateau_fit as fit_mod
from node.contract import OrdervibError
from node.models.bundle import load_bundle, save_bundle
from node.models.settle import SettleAnchor
from node.training.evaluation import predict_segments
from node.training.ocdata import OCData
from node.training.plateau_fit import choose_settle, fit_settle
from node.training.runs import read_runs
from node.training.train import CURVE_CANDIDATES, train_oc

AT, WINDOW = settle_mod.AT, settle_mod.WINDOW


def _visits(rng: np.random.Generator, n: int, keep: float, k: int = 1200
            ) -> list[tuple[np.ndarray, np.ndarray]]:
    """n visits of k samples predicted at 2.0: each misses a level of its own over the window
    before AT, of which ``keep`` stays after it (small sensor noise)."""
    out = []
    for _ in range(n):
        miss = rng.normal(0.0, 0.5)
        y = np.full(k, 2.0 + miss)
        y[AT:] = 2.0 + keep * miss
        out.append((y + rng.normal(0.0, 0.01, k), np.full(k, 2.0)))
    return out


@settings(max_examples=25, deadline=None)
@given(st.floats(0.0, 1.0), st.integers(0, 2**31 - 1))
def test_the_gain_is_the_share_of_the_miss_that_stays(keep, seed):
    a = fit_settle(_visits(np.random.default_rng(seed), 12, keep))
    assert a is not None and abs(a.gain - keep) < 0.02


def test_the_gain_stays_within_zero_and_one():
    rng = np.random.default_rng(2)
    assert fit_settle(_visits(rng, 8, 1.8)).gain == 1.0  # more than was seen: clipped
    assert fit_settle(_visits(rng, 8, -0.7)).gain == 0.0
    assert fit_settle([(np.full(AT, 1.0), np.full(AT, 0.0))]) is None  # no visit reaches AT


def test_the_cross_validation_keeps_an_anchor_that_helps_and_drops_one_that_does_not():
    """Where a run's miss stays the anchor is kept and its held-out error falls after AT;
    where it does not, it is not kept and the pairs are as they were."""
    rng = np.random.default_rng(1)
    folds = [[i] for i in range(8)]
    pairs = _visits(rng, 8, 1.0)
    anchor, moved = choose_settle(folds, pairs)
    assert anchor is not None and anchor.gain > 0.95
    after = [np.mean((y[AT:] - p[AT:]) ** 2) for y, p in moved]
    assert np.mean(after) < 0.01 * np.mean([np.mean((y[AT:] - p[AT:]) ** 2) for y, p in pairs])
    pairs = _visits(rng, 8, 0.0)
    assert choose_settle(folds, pairs) == (None, pairs)


def test_a_window_mostly_unknown_moves_nothing():
    y, p = np.full(AT + 100, 3.0), np.full(AT + 100, 2.0)
    y[AT - WINDOW:AT - settle_mod.MIN_FINITE + 1] = np.nan  # one finite residual too few
    assert SettleAnchor(1.0).moved(y, p) is p
    y[AT - settle_mod.MIN_FINITE] = 3.0
    assert SettleAnchor(1.0).moved(y, p)[AT] == 3.0


@pytest.fixture
def short_visits(monkeypatch: pytest.MonkeyPatch) -> None:
    """The test campaigns' plateaus last seconds: the anchor at 4 s, over the second before."""
    for mod, names in ((settle_mod, ("AT", "WINDOW", "MIN_FINITE")), (fit_mod, ("AT", "WINDOW")),
                       (pipeline_mod, ("SETTLE_AT", "SETTLE_WINDOW"))):
        for name in names:
            monkeypatch.setattr(mod, name, {"AT": 160, "SETTLE_AT": 160, "MIN_FINITE": 20}.get(name, 40))


def test_the_node_and_the_evaluation_settle_alike(phased: Path, short_visits: None, tmp_path: Path):
    """A bundle with settle anchors: the node's predictions over two runs equal the evaluation's
    (to rounding, as every model's step and batch paths), the anchor moved them from 4 s after
    each switch on, and it survives the bundle's round trip. The target has gaps (the node sees
    them as NaN, the model's inputs hold the last value)."""
    base = load_bundle(phased / "model")
    runs = read_runs(phased / "train.mcap")[:2]
    data = runs[0].data.copy()
    data[::23, runs[0].channels.index(base.target)] = np.nan
    runs[0] = dataclasses.replace(runs[0], data=data)
    ocs = [dataclasses.replace(r, settle=SettleAnchor(0.7)) if r.model is not None else r for r in base.ocs]
    save_bundle(dataclasses.replace(base, ocs=ocs), tmp_path / "m")
    loaded = load_bundle(tmp_path / "m")
    assert [r.settle for r in loaded.ocs] == [r.settle for r in ocs]
    assert all(r.kind.endswith("+settle") for r in loaded.ocs if r.model is not None)
    msgs, plain = node_messages(loaded, runs), node_messages(base, runs)
    preds = predict_segments(loaded.ocs, runs, loaded.schedule, loaded.target, loaded.curve, loaded.config)
    by_t = {m["t"]: m for m in msgs}
    plain_t = {m["t"]: m for m in plain}
    moved = 0
    for p in preds:
        node = np.array([by_t[float(t)]["predicted"] for t in p.t], float)
        np.testing.assert_allclose(node, p.predicted, rtol=1e-9, atol=1e-12)
        before = np.array([plain_t[float(t)]["predicted"] for t in p.t[:160]], float)
        np.testing.assert_array_equal(node[:160], before)  # nothing moves before the anchor
        moved += int(np.sum(node[160:] != np.array([plain_t[float(t)]["predicted"] for t in p.t[160:]])))
    assert moved > 1000


def test_a_malformed_settle_anchor_is_one_line_naming_the_bundle(phased: Path, tmp_path: Path):
    base = load_bundle(phased / "model")
    ocs = [dataclasses.replace(r, settle=SettleAnchor(0.5)) for r in base.ocs]
    save_bundle(dataclasses.replace(base, ocs=ocs), tmp_path / "m")
    manifest = json.loads((tmp_path / "m" / "manifest.json").read_text())
    for bad in ({"gain": 1.5}, {"gain": -0.1}, {"gain": True}, {"gain": "1"}, {"gain": 0.5, "x": 1}, [0.5]):
        manifest["ocs"][1]["settle"] = bad
        (tmp_path / "m" / "manifest.json").write_text(json.dumps(manifest))
        with pytest.raises(OrdervibError, match="malformed bundle") as exc:
            load_bundle(tmp_path / "m")
        assert str(tmp_path / "m") in str(exc.value) and "\n" not in str(exc.value)
    manifest["ocs"][1]["settle"] = {"gain": 0.25}
    (tmp_path / "m" / "manifest.json").write_text(json.dumps(manifest))
    assert load_bundle(tmp_path / "m").ocs[1].settle == SettleAnchor(0.25)


def _offset_runs(settle: bool) -> OCData:
    """Six runs of one OC: the level a function of speed, plus an offset of each run's own that
    comes 8 s after the switch, past any anchor at the switch, and stays."""
    rng = np.random.default_rng(4)
    d = OCData("OC1", "yB", ["nB"], [], [], [], [], switch="nB", curves=[dict(c) for c in CURVE_CANDIDATES],
               settle=settle)
    for r in range(6):
        speed = np.r_[np.full(100, 2000.0), np.linspace(2000.0, 3500.0, 200), np.full(1000, 3500.0)]
        y = 1.0 + speed / 1000.0 + rng.normal(0.0, 0.01, speed.size)
        y[100 + 320:] += rng.normal(0.0, 0.6)
        d.runs.append(r)
        d.y.append(y)
        d.X.append(speed[:, None])
        d.start.append(100)
        d.at.append(1000)
    return d


def test_the_band_keeps_the_scale_of_the_residuals_before_the_anchor():
    """The anchor is learnt where a run's miss stays; the residual rule's sigma is the CV
    residuals' before the move (the transition before AT_S keeps its band), the CV eps after."""
    plain = train_oc(_offset_runs(False), "lasso", {"alpha": [1e-3]}, ["nB"], 1)
    moved = train_oc(_offset_runs(True), "lasso", {"alpha": [1e-3]}, ["nB"], 1)
    assert plain.settle is None and moved.settle is not None and moved.settle.gain > 0.9
    assert moved.cv_eps < 0.7 * plain.cv_eps  # (the miss between 8 and 15 s stays)
    assert moved.calibration is not None and plain.calibration is not None
    assert moved.calibration.sigma == plain.calibration.sigma
