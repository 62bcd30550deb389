"""ParametricROM against scikit-learn's ``check_estimator``: every check it fails is named with
its reason, so that a check that starts failing, or a named one that starts passing, fails here;
and what those checks would have verified, checked on the data ParametricROM takes."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from conftest import check_estimator_statuses
from sklearn.base import clone

from node.sysid import WDMD, ParametricROM, PoleResidue, StateSpace

# Why these checks cannot pass: fit(samples, params) takes one list entry per parameter sample,
# each a (Y, U) pair (or a list of pairs) of time series, and the parameter values; scikit-learn's
# checks call fit(X, y) with one array X (rows = observations) and a target y. ParametricROM refuses
# such an X with a one-line message (sparse, complex, non-finite, empty and 1-D arrays with the
# messages the checks expect, which pass), so every check that needs a successful fit(X, y) fails.
# It has no predict, transform or score (``at(p)`` returns a model) and no n_features_in_ (its data
# are many time series, not one X).
_NO_XY = ("needs a successful fit(X, y); fit takes (Y, U) pairs per parameter sample and params, "
          "one array X is refused")
EXPECTED_FAILED_CHECKS = {
    "check_fit_score_takes_y": "fit's arguments are (samples, params), not (X, y); " + _NO_XY,
    "check_estimators_overwrite_params": _NO_XY + " (tested here on samples: "
                                         "test_fit_leaves_its_parameters_and_inputs_alone)",
    "check_dont_overwrite_parameters": _NO_XY + " (tested here: "
                                       "test_fit_leaves_its_parameters_and_inputs_alone)",
    "check_estimators_fit_returns_self": _NO_XY + " (tested here: "
                                         "test_fit_returns_self_and_is_deterministic)",
    "check_readonly_memmap_input": _NO_XY,
    "check_n_features_in_after_fitting": _NO_XY + "; no n_features_in_ (many time series, not one X)",
    "check_n_features_in": _NO_XY + "; no n_features_in_ (many time series, not one X)",
    "check_positive_only_tag_during_fit": _NO_XY,
    "check_estimators_dtypes": _NO_XY,
    "check_dtype_object": _NO_XY + " (an object array of numbers is refused too)",
    "check_pipeline_consistency": _NO_XY + "; no score, predict nor transform to chain",
    "check_estimators_nan_inf": "raises on NaN and inf in X as asked, but then fits a finite X: " + _NO_XY,
    "check_estimators_pickle": _NO_XY + " (tested here: test_a_fitted_rom_pickles_to_the_same_models)",
    "check_f_contiguous_array_estimator": _NO_XY,
    "check_methods_sample_order_invariance": _NO_XY + "; no predict nor transform",
    "check_methods_subset_invariance": _NO_XY + "; no predict nor transform",
    "check_dict_unchanged": _NO_XY + "; no predict nor transform",
    "check_fit_idempotent": _NO_XY + " (tested here: test_fit_returns_self_and_is_deterministic)",
    "check_fit_check_is_fitted": _NO_XY + " (NotFittedError before fit: check_estimators_unfitted passes)",
    "check_fit2d_predict1d": _NO_XY + "; no predict",
}
# Skipped unless SCIPY_ARRAY_API=1 is set in the environment.
MAY_SKIP = {"check_array_api_input"}


def test_scikit_learn_check_estimator_passes_but_its_named_exceptions() -> None:
    by_status = check_estimator_statuses(ParametricROM(WDMD(levels=2)), EXPECTED_FAILED_CHECKS, MAY_SKIP)
    assert {"check_estimator_cloneable", "check_estimator_repr", "check_no_attributes_set_in_init",
            "check_estimators_unfitted", "check_get_params_invariance", "check_set_params",
            "check_complex_data", "check_estimator_sparse_array", "check_estimator_sparse_matrix",
            "check_estimators_empty_data_messages", "check_fit1d", "check_fit2d_1sample",
            "check_fit2d_1feature"} <= by_status["passed"]


DT = 0.01


def _system(p: float) -> StateSpace:
    """Two oscillators seen through two outputs; the first one's w^2 grows with p."""
    w = 2 * np.pi * np.array([2.0 * np.sqrt(1 + p), 4.5])
    s = -0.02 * w + 1j * w
    z = np.exp(s * DT)
    Rs = np.array([[1.0, 0.3], [0.2, 1.0]]).T[:, :, None] * (0.5 / (1j * w))[:, None, None]
    Rz = Rs * ((z - 1) / s)[:, None, None]
    return PoleResidue(np.r_[z, z.conj()], np.r_[Rz, Rz.conj()], np.zeros((2, 1)), DT).to_statespace()


PS = [0.0, 0.4, 1.0]


def _data() -> list[tuple[np.ndarray, np.ndarray]]:
    u = np.random.default_rng(0).normal(size=(1500, 1))
    return [(_system(p).simulate(u), u) for p in PS]


def test_fit_returns_self_and_is_deterministic() -> None:
    data = _data()
    a = ParametricROM(WDMD(levels=2), n_pairs=2)
    assert a.fit(data, PS) is a
    b = clone(a).fit(data, PS)
    b.fit(data, PS)  # a refit: the same bits again
    for name in "ABCD":
        np.testing.assert_array_equal(getattr(a.at(0.6), name), getattr(b.at(0.6), name))
    assert a.validation_.rule == "loo" and repr(a).endswith(a.validation_.summary())


def test_fit_leaves_its_parameters_and_inputs_alone() -> None:
    data = _data()
    copies = [(y.copy(), u.copy()) for y, u in data]
    est = ParametricROM(WDMD(levels=2), n_pairs=2)
    before = est.get_params(deep=True)
    est.fit(data, PS)
    after = est.get_params(deep=True)
    assert before.keys() == after.keys()
    for k, v in before.items():
        if k != "base_estimator":
            assert after[k] == v, k
    assert not hasattr(est.base_estimator, "model_")  # the base estimator is cloned, not fitted
    for (y0, u0), (y, u) in zip(copies, data):
        np.testing.assert_array_equal(y0, y)
        np.testing.assert_array_equal(u0, u)


def test_a_fitted_rom_pickles_to_the_same_models() -> None:
    rom = ParametricROM(WDMD(levels=2), n_pairs=2).fit(_data(), PS)
    back = pickle.loads(pickle.dumps(rom))
    for p in (0.2, 0.6):
        np.testing.assert_array_equal(rom.at(p).A, back.at(p).A)
    assert repr(back) == repr(rom)


def test_one_array_is_refused_with_what_fit_takes() -> None:
    with pytest.raises(ValueError, match="one \\(Y, U\\) pair .* per parameter sample"):
        ParametricROM(WDMD(levels=2)).fit(np.zeros((10, 3)), np.arange(10.0))
