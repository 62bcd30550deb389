"""Seeding a free run from measured history: least-squares state estimation."""

from __future__ import annotations

import numpy as np

from node.sysid.lstsq import truncated_lstsq
from node.sysid.refine import markov_parameters
from node.sysid.statespace import StateSpace


def estimate_state(model: StateSpace, Y1: np.ndarray, U1: np.ndarray,
                   x_start: np.ndarray | None = None, rcond: float = 1e-4) -> np.ndarray:
    """State right after the history (Y1, U1) (K1, p), (K1, m), fitted by least squares.

    The state at the first history sample is ``x_start`` (zero if None) plus
    the correction that makes the model's free run over the history fit Y1
    best (truncated pseudo-inverse of the observability matrix with relative
    tolerance ``rcond``; unobservable directions keep ``x_start``). Measurement
    noise averages out over the window. Returns x (n,) at sample K1.
    """
    K1 = Y1.shape[0]
    x_s = np.zeros(model.n_states) if x_start is None else np.asarray(x_start, float)
    Yhat = model.simulate(U1, x_s)
    O = markov_parameters(model.A, model.C, K1).reshape(K1 * model.n_outputs, model.n_states)
    delta, _ = truncated_lstsq(O, (Y1 - Yhat).reshape(-1, 1), rcond=rcond)
    _, X = model.simulate(U1, x_s + delta[:, 0], return_states=True)
    return X[-1]
