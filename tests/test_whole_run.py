"""Every sample from light-off to standstill: the start is the first OC's transition (with a
model of its own until it leaves the speed it held), the rundown a segment of its own; a sample
without a prediction is a miss in the evaluation."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from node.contract import RUNDOWN
from node.models.bundle import load_bundle
from node.runtime.align import AlignedSample
from node.runtime.ocdetect import OCDetector
from node.runtime.pipeline import MonitorPipeline
from node.training.evaluation import SegmentPrediction, score_segments
from node.training.runs import read_runs


def _messages(bundle, run) -> tuple[list[dict], list[dict]]:
    pipe = MonitorPipeline(bundle)
    msgs, switches = [], []
    for k in range(len(run.t)):
        vals = {c: float(run.data[k, j]) for j, c in enumerate(run.channels)}
        msg, sw = pipe.step(AlignedSample(float(run.t[k]), vals, k == 0))
        msgs.append(msg)
        if sw is not None:
            switches.append(sw)
    return msgs, switches


def test_a_prediction_from_light_off_to_standstill(phased: Path):
    bundle = load_bundle(phased / "model")
    sched = bundle.schedule
    assert {r.name for r in bundle.ocs} == set(sched.models)  # every OC, the rundown, the start
    run = read_runs(phased / "train.mcap")[0]
    msgs, switches = _messages(bundle, run)
    speed = run.column(sched.switch)
    on = np.flatnonzero(speed >= OCDetector(sched).off_level)
    inside = msgs[on[0] + 10:on[-1] + 1]  # (light-off: the speed above the off level for 0.25 s)
    assert all(m["oc"] is not None for m in inside)
    assert sum(m["predicted"] is not None for m in inside) >= 0.99 * len(inside)
    names = [s["oc"] for s in switches]
    assert names[0] == sched.names[0] and switches[0]["phase"] == "transition"
    assert RUNDOWN in names and names[-1] is None and switches[-1]["previous"] == RUNDOWN
    assert any(m["model"] and m["model"].endswith(f":{sched.names[0]}:start") for m in inside)
    assert all(m["oc"] == sched.names[0] for m in inside if m["model"] and m["model"].endswith(":start"))
    rundown = [m for m in inside if m["oc"] == RUNDOWN]
    assert rundown and all(m["predicted"] is not None and m["band"] is not None for m in rundown)
    # no message of a model that has none: a model trained before the rundown and the start
    old = dataclasses.replace(bundle, ocs=[r for r in bundle.ocs if r.name in sched.names])
    msgs_old, switches_old = _messages(old, run)
    assert [s["oc"] for s in switches_old] == names
    assert all(m["flag"] == "no-model" for m in msgs_old if m["oc"] == RUNDOWN)


def test_a_sample_without_a_prediction_is_a_miss(phased: Path):
    sched = load_bundle(phased / "model").schedule
    y = np.array([1.0, 2.0, 2.0, 1.0])
    preds = [SegmentPrediction(0, sched.rundown, np.arange(4.0), y, np.array([1.0, 2.0, np.nan, np.nan]))]
    row = score_segments([], sched, preds)[sched.rundown]
    assert row.name == RUNDOWN and row.predicted == 2 and row.coverage == 0.5
    assert np.isclose(row.eps, np.sqrt(5.0 / 10.0))  # the misses' error: their measured values
