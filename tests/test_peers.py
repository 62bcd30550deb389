"""Peer wrappers (harness/peers.py) recover a small known system; skipped without the peers extra."""

from __future__ import annotations

import numpy as np
import pytest

from harness.peers import estimate_state, fit_n4sid, fit_pykoop, pydmd_note
from node.sysid import StateSpace, eps_td


def small_system(rng, proper: bool = False) -> StateSpace:
    """4 states, 1 input, 2 outputs; poles 0.97 exp(+-0.3i), 0.9 exp(+-1.1i) in a random basis."""
    blocks = [r * np.array([[np.cos(w), -np.sin(w)], [np.sin(w), np.cos(w)]])
              for r, w in ((0.97, 0.3), (0.9, 1.1))]
    T = rng.standard_normal((4, 4))
    A = T @ np.block([[blocks[0], np.zeros((2, 2))], [np.zeros((2, 2)), blocks[1]]]) @ np.linalg.inv(T)
    D = rng.standard_normal((2, 1)) if proper else np.zeros((2, 1))
    return StateSpace(A, rng.standard_normal((4, 1)), rng.standard_normal((2, 4)), D)


def data(seed: int = 0, proper: bool = False, scale: float = 1.0, n: int = 2000):
    """Training (Y, U) of n white-noise samples, new inputs U2 and the truths after Y / from rest."""
    rng = np.random.default_rng(seed)
    sys = small_system(rng, proper)
    sys = StateSpace(sys.A, sys.B, scale * sys.C, scale * sys.D)
    U = rng.standard_normal((n, 1))
    Y, X = sys.simulate(U, return_states=True)
    U2 = rng.standard_normal((500, 1))
    return sys, Y, U, U2, sys.simulate(U2, X[-1]), sys.simulate(U2)


def test_estimate_state_recovers_true_state():
    sys, Y, U, _, _, _ = data(1, proper=True)
    _, X = sys.simulate(U, return_states=True)
    x = estimate_state(sys, Y, U, window=50)
    assert np.allclose(x, X[-1], rtol=1e-8, atol=1e-8 * np.abs(X[-1]).max())


@pytest.mark.parametrize("proper", [False, True])
def test_n4sid_free_run_on_new_inputs(proper):
    pytest.importorskip("nfoursid")
    pytest.importorskip("pandas")
    # outputs at the beam's 1e-5 scale: normalisation must make this harmless
    sys, Y, U, U2, Y_after, Y_rest = data(2, proper=proper, scale=1e-5, n=1000)
    pred, seconds = fit_n4sid(Y, U, order=4, block_rows=10, dt=1.0)
    assert pred.n_states == 4 and seconds > 0
    assert isinstance(pred.model, StateSpace)
    assert eps_td(Y_after, pred.simulate(U2, history=(Y, U))) < 1e-3
    assert eps_td(Y_rest, pred.simulate(U2)) < 1e-3
    assert np.allclose(np.sort_complex(pred.model.poles()), np.sort_complex(sys.poles()), atol=1e-6)


def test_n4sid_rejects_bad_arguments():
    pytest.importorskip("nfoursid")
    _, Y, U, _, _, _ = data(3, n=400)
    with pytest.raises(ValueError, match="block_rows"):
        fit_n4sid(Y, U, order=40, block_rows=10)
    with pytest.raises(ValueError, match="single trajectory"):
        fit_n4sid([Y, Y], [U, U])
    pred, _ = fit_n4sid(Y, U, order=4, block_rows=10)
    with pytest.raises(ValueError, match="history"):
        pred.simulate(U[:5], history=Y)


def test_pykoop_free_run_on_new_inputs():
    pytest.importorskip("pykoop")
    # pykoop's delay-lifted EDMD is an ARX model without feed-through: D = 0 here.
    # Measured (seed 0): eps_td ~ 5e-9 with alpha = 1e-6 and 4 delays, 1e-14 with alpha = 0;
    # the Tikhonov term (alpha / K on a unit-scaled Gram matrix) is the only error,
    # so 1e-5 still catches a wrong history alignment or scaling (those give O(1) errors).
    _, Y, U, U2, Y_after, Y_rest = data(0, scale=1e-5)
    pred, seconds = fit_pykoop(Y, U, n_delays=4)
    assert pred.n_states == 2 * 5 and seconds > 0
    assert eps_td(Y_after, pred.simulate(U2, history=(Y, U))) < 1e-5
    assert eps_td(Y_rest, pred.simulate(U2)) < 1e-5
    exact, _ = fit_pykoop(Y, U, n_delays=4, alpha=0.0)
    assert eps_td(Y_after, exact.simulate(U2, history=(Y, U))) < 1e-9


def test_pykoop_fast_path_equals_predict_trajectory():
    pytest.importorskip("pykoop")
    _, Y, U, U2, _, _ = data(4)
    pred, _ = fit_pykoop(Y, U, n_delays=3, alpha=1e-3)
    for history in ((Y, U), (Y[-2:], U[-2:]), None):
        fast = pred.simulate(U2[:30], history=history)
        ref = pred.simulate(U2[:30], history=history, method="pykoop")
        assert np.allclose(fast, ref, rtol=1e-10, atol=1e-12 * np.abs(ref).max())


def test_pykoop_several_episodes():
    pytest.importorskip("pykoop")
    _, Y, U, U2, Y_after, _ = data(5)
    pred, _ = fit_pykoop([Y[:1000], Y[1000:]], [U[:1000], U[1000:]], n_delays=2, alpha=0.0)
    assert eps_td(Y_after, pred.simulate(U2, history=(Y, U))) < 1e-9
    with pytest.raises(ValueError):
        fit_pykoop([Y], U)


def test_pydmd_note_names_the_checked_api():
    note = pydmd_note()
    assert "DMDc.reconstructed_data" in note and "\n" not in note
