"""The chirp rate (``node.runtime.chirp``), a derived input: exact on a ramp, causal, offered to
training by ``--chirp-rate``, derived alike by the node and by training's batch path."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import SMALL_CHANNELS
from hypothesis import given, settings
from hypothesis import strategies as st

from node.cli import main
from node.models.bundle import load_bundle
from node.runtime.align import AlignedSample
from node.runtime.chirp import CHIRP_RATE, ChirpRate, chirp_rate_column
from node.runtime.pipeline import MonitorPipeline
from node.training.evaluation import predict_segments
from node.training.runs import read_runs


def test_a_ramps_rate_from_its_second_sample_and_dropouts_held():
    speed = 1000.0 + 50.0 * np.arange(200) / 40.0  # 50 rpm/s
    speed[100:105] = np.nan
    rate = chirp_rate_column(speed)
    assert np.isnan(rate[0])  # one speed: no rate yet; from the second, over those known
    ok = np.r_[np.arange(1, 100), np.arange(146, 200)]  # away from the held dropout
    np.testing.assert_allclose(rate[ok], 50.0, rtol=1e-12)
    assert np.isfinite(rate[100:146]).all()  # the held speed: a rate all the same


@settings(max_examples=40, deadline=None)
@given(st.lists(st.one_of(st.floats(0, 20000), st.just(math.nan)), min_size=1, max_size=150),
       st.integers(0, 149))
def test_causal_and_reset(values, cut):
    """The rate at a sample never depends on later speeds; a reset forgets the run before."""
    full = chirp_rate_column(np.array(values))
    head = chirp_rate_column(np.array(values[:cut]))
    np.testing.assert_array_equal(full[:cut], head)
    c = ChirpRate()
    for v in values:
        c.step(v)
    c.reset()
    assert [c.step(v) for v in values[:cut]] == pytest.approx(head.tolist(), nan_ok=True)


def test_trained_with_it_the_node_and_the_batch_path_agree(tmp_path):
    d = tmp_path
    assert main(["simulate", "--runs", "2", "--seed", "14", "--out", str(d / "train.mcap"),
                 *SMALL_CHANNELS]) == 0
    assert main(["simulate", "--runs", "3", "--skip", "2", "--seed", "14", "--out", str(d / "test.mcap"),
                 *SMALL_CHANNELS]) == 0
    assert main(["train", str(d / "train.mcap"), "--schedule", str(d / "train.schedule.toml"), "--out",
                 str(d / "m"), "--method", "lasso", "--inputs", f"nB,{CHIRP_RATE}", "--chirp-rate",
                 "--quiet", "--workers", "1", "--no-curve-candidates"]) == 0
    bundle = load_bundle(d / "m")
    assert CHIRP_RATE in bundle.inputs
    pipe = MonitorPipeline(bundle)
    assert CHIRP_RATE not in pipe.sensor_channels  # derived by the node, never awaited from the bed
    run = read_runs(d / "test.mcap")[0]
    msgs = []
    for k in range(len(run.t)):
        vals = {c: float(run.data[k, j]) for j, c in enumerate(run.channels)}
        msgs.append(pipe.step(AlignedSample(float(run.t[k]), vals, k == 0))[0])
    by_t = {m["t"]: m for m in msgs}
    preds = predict_segments(bundle.ocs, [run], bundle.schedule, bundle.target, bundle.curve,
                             bundle.config)
    used = [p for p in preds if CHIRP_RATE in bundle.ocs[p.oc].inputs]
    assert used
    for p in used:
        node = np.array([by_t[float(t)]["predicted"] for t in p.t], dtype=float)
        np.testing.assert_allclose(node, p.predicted, rtol=1e-9, atol=1e-12)


def test_without_the_option_it_is_not_offered(tmp_path):
    d = tmp_path
    assert main(["simulate", "--runs", "2", "--seed", "15", "--out", str(d / "train.mcap"),
                 *SMALL_CHANNELS]) == 0
    code = main(["train", str(d / "train.mcap"), "--schedule", str(d / "train.schedule.toml"), "--out",
                 str(d / "m"), "--method", "lasso", "--inputs", f"nB,{CHIRP_RATE}", "--quiet",
                 "--workers", "1"])
    assert code == 2 and not (d / "m").exists()  # one line: the input is missing
