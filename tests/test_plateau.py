"""The plateau shift (issue 30): what a run's earlier plateaus add to an OC model's plateau."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from conftest import node_messages
from hypothesis import given, settings
from hypothesis import strategies as st

import node.runtime.plateaus as plateaus
from node.contract import OrdervibError
from node.models.bundle import load_bundle, save_bundle
from node.models.plateau import PlateauShift
from node.runtime.plateaus import RunPlateaus, plateau_visits
from node.training.evaluation import predict_segments
from node.training.plateau_fit import choose_shift, fit_shift, run_levels, visit_tables
from node.training.runs import read_runs

finite = st.floats(-3.0, 3.0, allow_nan=False)


@settings(max_examples=30, deadline=None)
@given(st.lists(finite, min_size=6, max_size=6), st.integers(0, 2**31 - 1))
def test_a_plateau_that_is_an_affine_law_of_the_earlier_ones_is_recovered(law, seed):
    """Plateaus made exactly of the level before the switch and two earlier plateaus (complex
    weights): the fitted regression gives them back, up to its small ridge."""
    rng = np.random.default_rng(seed)
    a = complex(law[0], law[1])
    b, c, d = complex(law[2], law[3]), complex(law[4], 0.5), complex(law[5], -1.0)
    rows = []
    for _ in range(12):
        pre, p0, p1 = (complex(*rng.normal(size=2)) for _ in range(3))
        rows.append((pre, [p0, p1], a * pre + b * p0 + c * p1 + d))
    s = fit_shift(rows, vector=True)
    assert s is not None and s.earlier == (0, 1)
    scale = max(1.0, abs(a), abs(b), abs(c), abs(d))
    np.testing.assert_allclose(np.array(s.coef), [a, b, c, d], atol=0.03 * scale)


def test_run_plateaus_step_as_the_visits_say_and_forget_a_run():
    """The node's stepper and the training's visit table agree on every visit's level before the
    switch and the plateaus then; a new run forgets them."""
    rng = np.random.default_rng(3)
    labels = np.repeat([0, 1, -1, 2, 1], [900, 1000, 50, 700, 800])
    levels = rng.normal(size=labels.size) + 1j * rng.normal(size=labels.size)
    levels[100:130] = np.nan
    table = plateau_visits(levels, labels, 3)
    rp, prev = RunPlateaus(3), None
    for k, (oc, v) in enumerate(zip(labels.tolist(), levels.tolist())):
        oc = oc if oc >= 0 else None
        if k == 0 or oc != prev:
            rp.switch(oc)
            if oc is not None:
                pre, before, _ = table[k]
                assert (np.isnan(rp.pre) and np.isnan(pre)) or rp.pre == pre
                assert np.array_equal(np.array(rp.levels), np.array(before), equal_nan=True)
            prev = oc
        rp.step(v)
    assert set(table) == {0, 900, 1950, 2650}
    assert np.isfinite(table[2650][1][1])  # the first visit of OC 1 is known at its second
    assert np.isnan(table[1950][1][2]) and np.isnan(table[0][2]) is np.False_
    rp.reset()
    assert all(np.isnan(v) for v in rp.levels)


def test_the_cross_validation_keeps_a_shift_that_helps_and_drops_one_that_does_not():
    """A model that predicts every run's plateau at the runs' mean: where the plateau follows
    the run's first plateau the shift is kept and its held-out pairs improve; where it is noise,
    it is not kept."""
    rng = np.random.default_rng(1)
    n = 8
    first = rng.normal(2.0, 0.5, n)
    for follows in (True, False):
        own = 3.0 + (1.5 * (first - 2.0) if follows else rng.normal(0.0, 0.5, n))
        visits = [(complex(3.0), [complex(f)], complex(o)) for f, o in zip(first, own)]
        pairs = [(np.full(800, o) + rng.normal(0, 0.01, 800), np.full(800, own.mean())) for o in own]
        folds = [[i] for i in range(n)]
        fitted = [[j for j in range(n) if j != i] for i in range(n)]
        shift, moved = choose_shift(visits, folds, fitted, pairs, vector=False)
        if follows:
            assert shift is not None and shift.earlier == (0,)
            after = slice(400, None)  # the shift faded in (RAMP_S)
            err = [np.mean((y[after] - p[after]) ** 2) for y, p in moved]
            assert np.mean(err) < 0.05 * np.mean([np.mean((y - p) ** 2) for y, p in pairs])
        else:
            assert shift is None and moved == pairs


def test_a_shift_is_clipped_at_its_limit_and_unknown_plateaus_give_none():
    s = PlateauShift((2,), (0.0, 1.0, 0.0), (0.0, 0.0), vector=False, limit=0.5)
    assert s.shift(0.0, [0.0, 0.0, 4.0]) == 0.5 and s.shift(0.0, [0.0, 0.0, -4.0]) == -0.5
    assert s.shift(0.0, [0.0]) == 0.0  # the schedule's OC 2 never held in this run
    with pytest.raises(ValueError, match="finite"):
        PlateauShift((0,), (float("nan"), 1.0, 0.0), (0.0, 0.0), False, 1.0)


@pytest.fixture
def short_settle(monkeypatch: pytest.MonkeyPatch) -> None:
    """The test campaigns' plateaus last seconds: settle 1 s, 1 s of samples."""
    monkeypatch.setattr(plateaus, "SETTLE_S", 1.0)
    monkeypatch.setattr(plateaus, "MIN_SAMPLES", 40)


def _with_shifts(bundle, vector: bool, earlier: int = 0):
    """Every OC but the first given a shift on the run's plateau of OC ``earlier`` (a hand-made law;
    the rundown and the start, which training never gives one, none)."""
    law = PlateauShift((earlier,), (0.2, 0.5, 0.1), (0.3, 0.2), vector, 5.0)
    ocs = [dataclasses.replace(r, plateau=law) if r.model is not None and r.name in bundle.schedule.names[1:]
           else r for r in bundle.ocs]
    return dataclasses.replace(bundle, ocs=ocs)


@pytest.mark.parametrize("vector", [False, True])
def test_the_node_and_the_evaluation_shift_alike(phased: Path, short_settle: None, tmp_path: Path, vector):
    """A bundle with plateau shifts: the node's predictions over two runs equal the evaluation's
    (to rounding, as every model's step and batch paths), the shift moved them, and it survives
    the bundle's round trip."""
    base = load_bundle(phased / "model")
    runs = read_runs(phased / "train.mcap")[:2]
    shifted = _with_shifts(base, vector)
    save_bundle(shifted, tmp_path / "m")
    loaded = load_bundle(tmp_path / "m")
    assert [r.plateau for r in loaded.ocs] == [r.plateau for r in shifted.ocs]
    msgs, plain = node_messages(loaded, runs), node_messages(base, runs)
    preds = predict_segments(loaded.ocs, runs, loaded.schedule, loaded.target, loaded.curve, loaded.config)
    by_t = {m["t"]: m for m in msgs}
    moved = 0
    for p in preds:
        node = np.array([by_t[float(t)]["predicted"] for t in p.t], float)
        np.testing.assert_allclose(node, p.predicted, rtol=1e-9, atol=1e-12)
    for m, q in zip(msgs, plain):
        if m["predicted"] is not None and q["predicted"] is not None and m["predicted"] != q["predicted"]:
            moved += 1
    assert moved > 1000
    # a new run forgets the last one's plateaus: a shift on the last OC's plateau moves nothing
    # (each run holds it only at its end)
    last = node_messages(_with_shifts(base, vector, len(base.schedule.names) - 1), runs)
    assert [m["predicted"] for m in last] == [m["predicted"] for m in plain]
    levels = run_levels(runs[0], loaded.target, vector)
    assert levels.dtype == complex and (np.iscomplex(levels).any() == vector)
    assert visit_tables(runs, [np.zeros(len(r.t), int) for r in runs], loaded.target, 12, vector)


def test_a_malformed_plateau_shift_is_one_line_naming_the_bundle(phased: Path, tmp_path: Path):
    save_bundle(_with_shifts(load_bundle(phased / "model"), False), tmp_path / "m")
    manifest = json.loads((tmp_path / "m" / "manifest.json").read_text())
    good = {"earlier": [0], "coef": [[0, 0]] * 3, "coef_pre": [[0, 0]] * 2, "vector": False, "limit": 1}
    for bad in ({**good, "earlier": [99]}, {**good, "vector": 1}, {**good, "coef": [[1e400, 0]] * 3},
                {**good, "coef": [[0, 0]] * 2}, "shift"):
        manifest["ocs"][1]["plateau"] = bad
        (tmp_path / "m" / "manifest.json").write_text(json.dumps(manifest))
        with pytest.raises(OrdervibError, match="malformed bundle") as exc:
            load_bundle(tmp_path / "m")
        assert str(tmp_path / "m") in str(exc.value) and "\n" not in str(exc.value)
