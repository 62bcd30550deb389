"""Imbalanced-rotor benchmark (section 5.4): the pieces that make its table trustworthy."""

from __future__ import annotations

import numpy as np
import pytest

from harness import beam as bm
from harness import rotor as R


@pytest.fixture(scope="module")
def run() -> R.Run:
    return R.simulate_run()


@pytest.fixture(scope="module")
def truth(run: R.Run) -> R.Truth:
    return R.Truth.of(run)


def test_profile_stays_inside_each_operating_condition(run: R.Run) -> None:
    for (oc, _), (a, b) in run.spans.items():
        lo, hi = R.PROFILE[oc]["range"]
        assert lo <= run.rpm[a:b].min() and run.rpm[a:b].max() <= hi
    assert run.rpm.size == max(b for _, b in run.spans.values())


def test_vkf_recovers_the_steady_order1_amplitude_at_a_plateau(run: R.Run, truth: R.Truth) -> None:
    # OC1 test (i) is a 1420 rpm plateau (after 1.5 s at 1420 rpm ending the training)
    a, _ = R.oc_span(run, "OC1", "test")
    rpm = run.rpm[a]
    assert np.allclose(run.rpm[a:a + 3000], rpm)
    f = rpm / 60.0
    H = bm.discrete_model(R.beam_spec(run.fs), [R.ROTOR_NODE], R.OUTPUT_NODES) \
        .frequency_response(np.array([f]))[0, :, 0]
    expected = np.abs(H) * R.MASS_ECC * (2 * np.pi * f) ** 2  # (3,) m
    mid = truth.amps[("OC1", "test")][1000:2500]  # away from the tracker's span edges
    assert np.max(np.abs(mid / expected - 1)) < 0.01


def test_noise_free_oc1_model_reproduces_the_order1_amplitude(run: R.Run, truth: R.Truth) -> None:
    train, test = R.oc_errors(run, truth, run.y, "OC1", R.make_model("oe"))
    assert train < 1e-4 and test < 1e-4  # measured 7.5e-6 / 7.0e-6; dissertation 6e-4 / 4.6e-3


def test_noise_makes_the_fit_worse_but_oe_stays_below_ls(run: R.Run, truth: R.Truth) -> None:
    clean = R.oc_errors(run, truth, run.y, "OC1", R.make_model("ls"))[1]
    y_meas = R.add_noise(run, 20, np.random.default_rng(0))
    ls = R.oc_errors(run, truth, y_meas, "OC1", R.make_model("ls"))[1]
    oe = R.oc_errors(run, truth, y_meas, "OC1", R.make_model("oe"))[1]
    assert ls > 10 * clean
    assert oe < ls / 3


def test_noise_is_scaled_to_each_oc_training_std(run: R.Run) -> None:
    y_meas = R.add_noise(run, 10, np.random.default_rng(1))
    for oc in R.PROFILE:
        a, b = run.spans[(oc, "train")]
        ratio = (y_meas[a:b] - run.y[a:b]).std(axis=0) / run.y[a:b].std(axis=0)
        assert np.allclose(ratio, 0.10, rtol=0.05)
