"""The anchored vector check's threshold per OC: set in training, in force in the node, checked on load."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import pytest

from node.contract import FS, Phase
from node.contract.errors import OrdervibError
from node.contract.vector import order_vectors
from node.models.bundle import Bundle, load_bundle, save_bundle
from node.runtime.alarms import StepCheck
from node.runtime.align import AlignedSample
from node.runtime.ocdetect import OCDetector
from node.runtime.pipeline import MonitorPipeline
from node.training.calibrate import DRIFT_OC_FACTOR, DRIFT_OC_MIN_PLATEAUS
from node.training.runs import Run, read_runs


def _plateau_peaks_by_hand(run: Run, bundle: Bundle) -> list[tuple[str, float]]:
    """(OC, largest anchored statistic) of each steady plateau long enough for the check, each
    plateau stepped through a fresh check of its own."""
    oc, phase = OCDetector(bundle.schedule, bundle.config, FS).label(run.column("nB"))
    z = order_vectors(run.column("yB"), run.column("yB_ph"))
    steady = phase == Phase.STEADY.code
    out = []
    k = 0
    while k < len(z):
        if not steady[k]:
            k += 1
            continue
        end = k
        while end < len(z) and steady[end]:
            end += 1
        chk = StepCheck(math.inf, bundle.config, FS, anchored=True)
        stats = [chk.step(v, True) for v in z[k:end].tolist()]
        if end - k >= chk.n_settle + chk.n_short + chk.n_long:
            out.append((bundle.schedule.names[oc[k]], max(stats)))
        k = end
    return out


def test_each_ocs_threshold_is_the_factor_times_its_largest_training_plateau(phased: Path) -> None:
    bundle = load_bundle(phased / "model")
    by_oc: dict[str, list[float]] = {}
    for run in read_runs(phased / "train.mcap"):
        for name, peak in _plateau_peaks_by_hand(run, bundle):
            by_oc.setdefault(name, []).append(peak)
    expected = {n: DRIFT_OC_FACTOR * max(v) for n, v in by_oc.items() if len(v) >= DRIFT_OC_MIN_PLATEAUS}
    got = bundle.checks["vector_drift_thresholds"]
    assert len(expected) >= 6, "too few OCs with enough plateaus to test"
    assert got.keys() == expected.keys()
    for name, thr in expected.items():
        assert got[name] == pytest.approx(thr, rel=1e-12)
    assert len(set(got.values())) > 1  # not one number for all


def _scores(bundle: Bundle, run: Run) -> list[tuple[str | None, float | None, str | None]]:
    pipe = MonitorPipeline(bundle)
    cols = {c: run.column(c) for c in pipe.sensor_channels}
    out = []
    for k in range(len(run.t)):
        msg, _ = pipe.step(AlignedSample(float(run.t[k]), {c: float(v[k]) for c, v in cols.items()},
                                         new_run=k == 0))
        out.append((msg["oc"], msg["vector_score"], msg["reason"]))
    return out


def test_the_node_holds_the_ocs_own_threshold(phased: Path) -> None:
    """With the sliding check off, vector_score is the anchored statistic over the threshold in
    force: doubling one OC's threshold halves its scores there and nowhere else; an OC without
    its own threshold takes the pooled one, and 0 turns the check off in that OC."""
    bundle = load_bundle(phased / "model")
    run = read_runs(phased / "train.mcap")[1]
    pooled = float(bundle.checks["vector_drift_threshold"])
    names = bundle.schedule.names
    base = {**bundle.checks, "vector_step_threshold": 0,
            "vector_drift_thresholds": dict.fromkeys(names, pooled)}
    a = _scores(dataclasses.replace(bundle, checks=base), run)
    # no per-OC thresholds (a bundle of earlier code): the pooled one everywhere, the same scores
    old = {k: v for k, v in base.items() if k != "vector_drift_thresholds"}
    assert _scores(dataclasses.replace(bundle, checks=old), run) == a
    oc = "OC7"
    scores = [s for o, s, _ in a if o == oc and s]
    assert scores and max(scores) > 0.0
    b = _scores(dataclasses.replace(bundle, checks={**base, "vector_drift_thresholds": {
        **base["vector_drift_thresholds"], oc: 2.0 * pooled}}), run)
    for (o1, s1, _), (o2, s2, _) in zip(a, b):
        assert o1 == o2
        if o1 == oc and s1 is not None:
            assert s2 == pytest.approx(s1 / 2.0, rel=1e-12)
        else:
            assert s2 == s1
    c = _scores(dataclasses.replace(bundle, checks={**base, "vector_drift_thresholds": {
        **base["vector_drift_thresholds"], oc: 0.0}}), run)
    assert all(s == 0.0 and r != "vector" for o, s, r in c if o == oc and s is not None)


@pytest.mark.parametrize("bad", [[1.0], {"OC3": -1.0}, {"OC3": "2"}, {"OC3": True}, {"OC3": float("nan")}])
def test_a_malformed_per_oc_threshold_is_refused_on_load(phased: Path, tmp_path: Path, bad: object) -> None:
    bundle = load_bundle(phased / "model")
    out = save_bundle(dataclasses.replace(bundle, checks={**bundle.checks, "vector_drift_thresholds": bad}),
                      tmp_path / "m")
    with pytest.raises(OrdervibError, match="vector_drift_thresholds"):
        load_bundle(out)
    checks = {**bundle.checks, "vector_drift_thresholds": {"OC3": 4}}
    good = save_bundle(dataclasses.replace(bundle, checks=checks), tmp_path / "ok")
    assert load_bundle(good).checks["vector_drift_thresholds"] == {"OC3": 4}
