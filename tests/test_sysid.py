"""Identification core: known systems recovered exactly, wavelet properties, error paths."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import sparse

from node.sysid import (
    IODMD,
    WDMD,
    CausalMODWT,
    DelayDMD,
    ParametricROM,
    StateSpace,
    causal_modwt,
    eps_td,
    mac,
    modwt_mra,
)


def random_system(rng, n, m, p, rho=0.95, proper=False) -> StateSpace:
    A = rng.standard_normal((n, n))
    A *= rho / np.max(np.abs(np.linalg.eigvals(A)))
    D = rng.standard_normal((p, m)) if proper else np.zeros((p, m))
    return StateSpace(A, rng.standard_normal((n, m)), rng.standard_normal((p, n)), D)


def lightly_damped_system(rng, p=1) -> StateSpace:
    """Autonomous 4-state system, poles 0.97 exp(+-0.3i) and 0.95 exp(+-1.1i), random basis."""
    blocks = [r * np.array([[np.cos(w), -np.sin(w)], [np.sin(w), np.cos(w)]])
              for r, w in ((0.97, 0.3), (0.95, 1.1))]
    T = rng.standard_normal((4, 4))
    A = T @ np.block([[blocks[0], np.zeros((2, 2))], [np.zeros((2, 2)), blocks[1]]]) @ np.linalg.inv(T)
    return StateSpace(A, np.zeros((4, 1)), rng.standard_normal((p, 4)), np.zeros((p, 1)))


def match_poles(found: np.ndarray, true: np.ndarray) -> float:
    """Largest distance from each true pole to the nearest found pole."""
    return float(max(np.min(np.abs(found - t)) for t in true))


@pytest.mark.parametrize("estimator", ["ls", "oe"])
def test_iodmd_recovers_full_state_system(estimator):
    rng = np.random.default_rng(0)
    sys = random_system(rng, 5, 2, 3, proper=True)
    U = rng.standard_normal((400, 2))
    Y, X = sys.simulate(U, return_states=True)
    m = IODMD(estimator=estimator).fit(Y, U, X=X[:-1])
    np.testing.assert_allclose(m.A, sys.A, atol=1e-9)
    assert match_poles(np.linalg.eigvals(m.A), sys.poles()) < 1e-8
    U2 = rng.standard_normal((300, 2))
    Y2, X2 = sys.simulate(U2, x0=X[-1], return_states=True)
    assert eps_td(Y2, m.simulate(U2, x0=X[-1])) < 1e-8


@pytest.mark.parametrize("estimator", ["ls", "oe"])
def test_delay_dmd_with_input_delays_recovers_siso_system(estimator):
    rng = np.random.default_rng(1)
    sys = random_system(rng, 4, 1, 1)
    U = rng.standard_normal((600, 1))
    Y = sys.simulate(U)
    m = DelayDMD(delays=4, input_delays=4, warmup=4, estimator=estimator).fit(Y, U)
    assert match_poles(m.model_.poles(), sys.poles()) < 1e-8
    Yhat = m.simulate(U[300:], history=(Y[:300], U[:300]))
    assert eps_td(Y[300:], Yhat) < 1e-8


def test_delay_dmd_output_delays_recover_autonomous_system():
    rng = np.random.default_rng(2)
    sys = random_system(rng, 4, 1, 2, rho=0.99)
    Y = sys.simulate(np.zeros((500, 1)), x0=rng.standard_normal(4))
    m = DelayDMD(delays=3, warmup=2).fit(Y)
    assert match_poles(m.model_.poles(), sys.poles()) < 1e-8
    assert eps_td(Y[250:], m.simulate(np.zeros((250, 0)), history=Y[:250])) < 1e-8


@pytest.mark.parametrize("wavelet", ["haar", "db2"])
def test_wdmd_recovers_partially_observed_autonomous_system(wavelet):
    rng = np.random.default_rng(3)
    sys = lightly_damped_system(rng)
    Y = sys.simulate(np.zeros((800, 1)), x0=rng.standard_normal(4))
    m = WDMD(levels=3, wavelet=wavelet, warmup=30).fit(Y)
    assert m.A.shape == (4, 4)
    assert match_poles(m.model_.poles(), sys.poles()) < 1e-8
    assert eps_td(Y[400:], m.simulate(np.zeros((400, 0)), history=Y[:400])) < 1e-8


@pytest.mark.parametrize("estimator", ["ls", "oe"])
def test_wdmd_recovers_driven_system_seen_through_all_states(estimator):
    # With p = n and J = 1 the pseudo-state [W1, V1] is [y[k], y[k-1]]: an exact realisation.
    rng = np.random.default_rng(4)
    sys = random_system(rng, 3, 1, 3)
    U = rng.standard_normal((500, 1))
    Y = sys.simulate(U)
    m = WDMD(levels=1, estimator=estimator).fit(Y, U)
    assert match_poles(m.model_.poles(), sys.poles()) < 1e-8
    assert eps_td(Y[300:], m.simulate(U[300:], history=(Y[:300], U[:300]))) < 1e-8


def test_history_without_inputs_is_accepted():
    rng = np.random.default_rng(5)
    sys = random_system(rng, 3, 1, 3)
    U = np.ones((300, 1))
    Y = sys.simulate(U)
    m = WDMD(levels=1).fit(Y, U)
    # constant input: the unknown last history input equals U2[0]
    assert eps_td(Y[200:], m.simulate(U[200:], history=Y[:200])) < 1e-8
    rest = m.simulate(U[200:], history=None)
    assert rest.shape == (100, 3)


def test_multi_trajectory_fit_never_pairs_across_trajectories():
    rng = np.random.default_rng(6)
    sys = random_system(rng, 3, 1, 3)
    runs = []
    for _ in range(3):
        U = rng.standard_normal((150, 1))
        runs.append((sys.simulate(U, x0=10 * rng.standard_normal(3)), U))
    Ys, Us = [r[0] for r in runs], [r[1] for r in runs]
    ok = IODMD(estimator="ls")
    states = []
    for Y, _ in runs:  # recover the states exactly (C is invertible here)
        states.append(np.linalg.solve(sys.C, Y.T).T)
    ok.fit(Ys, Us, X=states)
    np.testing.assert_allclose(ok.A, sys.A, atol=1e-9)
    # the same data glued into one trajectory does pair across the seams and is wrong
    glued = IODMD(estimator="ls").fit(np.vstack(Ys), np.vstack(Us), X=np.vstack(states))
    assert np.max(np.abs(glued.A - sys.A)) > 1e-3


def test_mra_components_sum_to_signal_for_any_length():
    rng = np.random.default_rng(7)
    Y = rng.standard_normal((1001, 2))
    for wavelet in ("haar", "db4", "sym4"):
        comps = modwt_mra(Y, 5, wavelet)
        assert comps.shape == (1001, 2, 6)
        np.testing.assert_allclose(comps.sum(axis=2), Y, atol=1e-12)


def test_mra_matches_pywavelets_where_pywavelets_applies():
    import pywt
    y = np.random.default_rng(8).standard_normal(512)
    ref = pywt.mra(y, "haar", level=4, transform="swt")  # [S_4, D_4, D_3, D_2, D_1]
    ours = modwt_mra(y, 4, "haar")[:, 0, :]
    for i, comp in enumerate(ref):
        np.testing.assert_allclose(ours[:, 4 - i], comp, atol=1e-12)


def test_haar_causal_coefficients_sum_to_signal():
    Y = np.random.default_rng(9).standard_normal((300, 3))
    np.testing.assert_allclose(causal_modwt(Y, 6).sum(axis=2), Y, atol=1e-12)


def test_causal_coefficients_ignore_the_future():
    rng = np.random.default_rng(10)
    y = rng.standard_normal((400, 1))
    z = causal_modwt(y, 5, "db2")
    k = 250
    y2 = y.copy()
    y2[k + 1:] = rng.standard_normal((400 - k - 1, 1))
    z2 = causal_modwt(y2, 5, "db2")
    np.testing.assert_array_equal(z[: k + 1], z2[: k + 1])
    assert np.max(np.abs(z[k + 1:] - z2[k + 1:])) > 0
    # and the dissertation's MRA does look ahead
    m, m2 = modwt_mra(y, 5), modwt_mra(y2, 5)
    assert np.max(np.abs(m[:k + 1] - m2[:k + 1])) > 1e-3


def test_causal_filter_bank_step_equals_batch_bit_for_bit():
    Y = np.random.default_rng(11).standard_normal((200, 2))
    batch = causal_modwt(Y, 4, "db3")
    bank = CausalMODWT(4, "db3", 2)
    stepped = np.stack([bank.step(y) for y in Y])
    np.testing.assert_array_equal(batch, stepped)


def test_pole_residue_round_trip_frequency_response():
    rng = np.random.default_rng(12)
    sys = random_system(rng, 8, 2, 3, proper=True)
    f = np.linspace(0.0, 0.5, 301)
    H = sys.frequency_response(f)
    pr = sys.to_pole_residue()
    np.testing.assert_allclose(pr.frequency_response(f), H, rtol=0, atol=1e-10 * np.abs(H).max())
    back = pr.to_statespace()
    assert np.isrealobj(back.A) and back.n_states == 8
    np.testing.assert_allclose(back.frequency_response(f), H, rtol=0, atol=1e-10 * np.abs(H).max())
    assert match_poles(back.poles(), sys.poles()) < 1e-10


def test_stability_and_mac():
    sys = StateSpace(np.diag([0.5, 1.01]), np.ones((2, 1)), np.eye(2), np.zeros((2, 1)))
    assert not sys.is_stable()
    assert StateSpace(np.diag([0.5, 0.9]), np.ones((2, 1)), np.eye(2), np.zeros((2, 1))).is_stable()
    phi = np.random.default_rng(13).standard_normal((6, 3))
    M = mac(phi, phi * np.array([2.0, -1.0, 3j]))
    np.testing.assert_allclose(np.diag(M), 1.0)


@pytest.mark.parametrize(
    ("make", "args", "message"),
    [
        (lambda: WDMD(), (np.zeros((10, 2, 2)), np.zeros((10, 1))), "time-major"),
        (lambda: WDMD(), (np.zeros((10, 2)), np.zeros((9, 1))), "samples"),
        (lambda: WDMD(), (np.full((10, 1), np.nan), np.zeros((10, 1))), "NaN"),
        (lambda: WDMD(), (np.zeros((2, 1)), np.zeros((2, 1))), "at least"),
        (lambda: WDMD(levels=0), (np.zeros((10, 1)), np.zeros((10, 1))), "levels"),
        (lambda: WDMD(wavelet="nope"), (np.zeros((10, 1)), np.zeros((10, 1))), "wavelet"),
        (lambda: WDMD(rcond=-1), (np.zeros((10, 1)), np.zeros((10, 1))), "rcond"),
        (lambda: DelayDMD(delays=0), (np.zeros((10, 1)), np.zeros((10, 1))), "delays"),
        (lambda: WDMD(estimator="magic"), (np.zeros((10, 1)), np.zeros((10, 1))), "estimator"),
        (lambda: IODMD(), (np.zeros((10, 1)), np.zeros((10, 1)), np.zeros((9, 2))), "X has 9"),
        (lambda: WDMD(), (np.zeros(10), np.zeros((10, 1))), "2-D"),
        (lambda: WDMD(), (np.zeros((10, 0)), np.zeros((10, 1))), "0 feature"),
        (lambda: DelayDMD(), (np.ones((10, 1)) + 1j, np.zeros((10, 1))), "Complex data not supported"),
        (lambda: DelayDMD(), (np.ones((10, 1)), np.ones((10, 1)) * 1j), "Complex data not supported in U"),
        (lambda: IODMD(), (sparse.csr_array(np.eye(10)), np.zeros((10, 1))), "sparse input is not"),
        (lambda: IODMD(), (np.zeros((10, 1)), np.zeros((10, 1)), sparse.csr_array(np.eye(10))),
         "X is a sparse"),
    ],
)
def test_bad_input_raises_value_error_saying_what(make, args, message):
    with pytest.raises(ValueError, match=message):
        make().fit(*args)


def test_simulate_checks_its_inputs():
    rng = np.random.default_rng(14)
    m = WDMD(levels=2).fit(rng.standard_normal((100, 2)), rng.standard_normal((100, 1)))
    with pytest.raises(ValueError, match="column"):
        m.simulate(np.zeros((10, 3)))
    with pytest.raises(ValueError, match="NaN"):
        m.simulate(np.full((10, 1), np.nan))
    with pytest.raises(ValueError, match="history"):
        m.simulate(np.zeros((10, 1)), history=np.zeros((5, 7)))
    with pytest.raises(ValueError, match="not fitted"):
        WDMD().simulate(np.zeros((10, 1)))


def test_output_error_refit_paths_agree_and_beat_least_squares_under_noise():
    from node.sysid import refine
    rng = np.random.default_rng(15)
    sys = random_system(rng, 4, 2, 2, rho=0.9)
    U = rng.standard_normal((800, 2))
    Y = sys.simulate(U)
    Yn = Y + 0.05 * Y.std(0) * rng.standard_normal(Y.shape)
    x0 = np.zeros(4)
    modal = refine._normal_equations_modal(sys.A, sys.C, [Yn], [U], [x0])
    markov = refine._normal_equations_markov(sys.A, sys.C, [Yn], [U], [x0])
    np.testing.assert_allclose(modal[0], markov[0], rtol=1e-8, atol=1e-8 * np.abs(markov[0]).max())
    np.testing.assert_allclose(modal[1], markov[1], rtol=1e-8, atol=1e-8 * np.abs(markov[1]).max())
    # with the same (A, C), OE's (B, D) minimise the free-run error on the training data
    ls = WDMD(levels=2, estimator="ls").fit(Yn, U)
    oe = WDMD(levels=2, estimator="oe").fit(Yn, U)
    assert oe.refined_
    np.testing.assert_allclose(oe.A, ls.A)
    assert eps_td(Yn, oe.simulate(U)) < 0.9 * eps_td(Yn, ls.simulate(U))


def test_seeding_observer_averages_measurement_noise():
    rng = np.random.default_rng(16)
    sys = lightly_damped_system(rng, p=2)
    Y = sys.simulate(np.zeros((600, 1)), x0=rng.standard_normal(4))
    Yn = Y + 0.05 * Y.std(0) * rng.standard_normal(Y.shape)
    m = DelayDMD(delays=2, estimator="ls").fit(Y)  # exact model from clean data
    lifted = DelayDMD(delays=2, estimator="ls", seed_window=0).fit(Y)
    err_window = eps_td(Y[400:], m.simulate(np.zeros((200, 0)), history=Yn[:400]))
    err_lift = eps_td(Y[400:], lifted.simulate(np.zeros((200, 0)), history=Yn[:400]))
    assert err_window < 0.5 * err_lift


@pytest.mark.parametrize("make", [lambda: WDMD(levels=3, rcond=1e-8), lambda: DelayDMD(delays=4),
                                  lambda: IODMD(rcond=1e-9),
                                  lambda: ParametricROM(WDMD(levels=2), n_pairs=1)])
def test_the_identification_classes_are_scikit_learn_estimators(make) -> None:
    """Contract section 6: get_params / set_params, clone, a readable repr, NotFittedError before
    fit (check_is_fitted agrees), and the applicable estimator checks of scikit-learn."""
    from sklearn.base import clone
    from sklearn.exceptions import NotFittedError
    from sklearn.utils import estimator_checks as ec
    from sklearn.utils.validation import check_is_fitted

    est = make()
    name = type(est).__name__
    params = est.get_params(deep=False)
    twin = clone(est)
    assert twin is not est and twin.get_params(deep=False).keys() == params.keys()
    assert repr(est).startswith(f"{name}(")
    first = sorted(params)[0]
    assert est.set_params(**{first: params[first]}) is est
    with pytest.raises(NotFittedError):
        check_is_fitted(est)
    if not isinstance(est, ParametricROM):
        with pytest.raises(NotFittedError, match="not fitted"):
            est.A  # noqa: B018 - the property raises
    for check in ("check_get_params_invariance", "check_set_params", "check_no_attributes_set_in_init",
                  "check_parameters_default_constructible", "check_estimator_repr",
                  "check_estimator_cloneable", "check_do_not_raise_errors_in_init_or_set_params"):
        getattr(ec, check)(name, make())


def test_a_fitted_estimator_passes_check_is_fitted() -> None:
    from sklearn.utils.validation import check_is_fitted

    rng = np.random.default_rng(0)
    U = rng.standard_normal((400, 1))
    Y = np.zeros((400, 1))
    for k in range(1, 400):
        Y[k] = 0.8 * Y[k - 1] + U[k - 1]
    m = DelayDMD(delays=1, rcond=1e-10).fit(Y, U)
    check_is_fitted(m)
    assert np.allclose(np.sort(np.abs(np.linalg.eigvals(m.A)))[-1], 0.8, atol=1e-6)


def test_the_oe_refit_s_modal_filter_filters_each_conjugate_pair_once_to_the_same_bits():
    from scipy import signal

    from node.sysid.refine import _modal_filter

    rng = np.random.default_rng(1)
    for scale in (0.1, 0.3, 0.5):  # poles inside and beyond the unit circle
        lam = np.linalg.eigvals(rng.normal(size=(12, 12)) * scale)
        U = rng.normal(size=(1500, 3))
        one_by_one = np.stack([signal.lfilter([0.0, 1.0], [1.0, -z], U.astype(complex), axis=0)
                               for z in lam], axis=1)
        np.testing.assert_array_equal(_modal_filter(lam, U), one_by_one)
