"""Peer identification libraries wrapped for the benchmark (optional extra ``peers``).

Every ``fit_*`` takes time-major arrays (samples, channels) and returns
``(predictor, fit_seconds)``. A predictor has

* ``simulate(U2, history=(Y1, U1))`` -> (len(U2), p): free run driven by the
  new inputs U2, the state seeded from the measured history just before U2;
* ``simulate(U2, history=None)``: free run from rest (zero state, zero past inputs);
* ``n_states``: size of the model's state.

Peers:

* :func:`fit_n4sid` -- ``nfoursid`` 1.0.x (PO-MOESP/N4SID on pandas DataFrames).
  The identified (A, B, C, D) become a :class:`node.sysid.StateSpace`; a
  history seeds the state by least squares over its last samples (observability
  matrix from the Markov parameters C A^i, forced response subtracted), then
  the state is propagated to the end of the history.
* :func:`fit_pykoop` -- ``pykoop`` 2.0.x Koopman pipeline: scaling, delay
  lifting of outputs and inputs, EDMD (Tikhonov) regression. Prediction is
  pykoop's own ``KoopmanPipeline.predict_trajectory(X0, U)`` (re-lifting every
  step), so the history seeds the delay coordinates directly.
* PyDMD has no class that free-runs from a chosen state with new exogenous
  inputs: see :func:`pydmd_note`.

The peer packages are imported lazily, so importing this module needs none of them.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np

from node.sysid.lstsq import truncated_lstsq
from node.sysid.refine import markov_parameters
from node.sysid.statespace import StateSpace
from node.sysid.validation import as_matrix, as_trajectories

__all__ = ["StateSpacePredictor", "PykoopPredictor", "fit_n4sid", "fit_pykoop", "pydmd_note",
           "estimate_state"]


# ---------------------------------------------------------------------------
# seeding observer for any (A, B, C, D)
# ---------------------------------------------------------------------------
def estimate_state(model: StateSpace, Y1: np.ndarray, U1: np.ndarray, window: int,
                   weights: np.ndarray | None = None, rcond: float = 1e-10) -> np.ndarray:
    """State at the first sample after the history (Y1, U1).

    The state at the start of the last ``window`` history samples is the least-
    squares solution of O x = Y_win - Y_forced (O stacks C A^i, i < window;
    Y_forced is the zero-state response to the window's inputs), each output
    channel weighted by ``weights`` (e.g. 1 / its scale). The state is then
    propagated through the window, so the result is x[K1] for the sample right
    after the history.
    """
    Y1 = np.asarray(Y1, float)
    U1 = np.asarray(U1, float)
    K1 = Y1.shape[0]
    n, p = model.n_states, model.n_outputs
    if K1 == 0 or n == 0:
        return np.zeros(n)
    W = max(1, min(int(window), K1))
    start = K1 - W
    w = np.ones(p) if weights is None else np.asarray(weights, float).reshape(p)
    Yf = model.simulate(U1[start:])
    O = markov_parameters(model.A, model.C, W) * w[None, :, None]  # (W, p, n)
    r = (Y1[start:] - Yf) * w[None, :]
    x_s, _ = truncated_lstsq(O.reshape(W * p, n), r.reshape(-1, 1), rcond=rcond)
    _, X = model.simulate(U1[start:], x_s[:, 0], return_states=True)
    return X[-1]


def _split_history(history, p: int, m: int) -> tuple[np.ndarray, np.ndarray] | None:
    if history is None:
        return None
    if not (isinstance(history, tuple) and len(history) == 2):
        raise ValueError("history must be (Y1, U1) or None")
    Y1 = as_matrix(history[0], "history outputs Y1", cols=p)
    U1 = as_matrix(history[1], "history inputs U1", cols=m)
    if Y1.shape[0] != U1.shape[0]:
        raise ValueError(f"history Y1 has {Y1.shape[0]} samples but U1 has {U1.shape[0]}")
    return Y1, U1


@dataclass
class StateSpacePredictor:
    """A fitted (A, B, C, D) with the shared seeding observer.

    Attributes:
        model: the identified :class:`StateSpace` in physical units.
        seed_window: history samples the observer uses (None: max(100, 20 n / p)).
        output_scale: (p,) output scales; residuals are divided by them when seeding.
        info: free-form details of the fit (peer, order, block rows, singular values).
    """

    model: StateSpace
    seed_window: int | None = None
    output_scale: np.ndarray | None = None
    info: dict = field(default_factory=dict)

    @property
    def n_states(self) -> int:
        return self.model.n_states

    def seed_window_length(self, n_history: int) -> int:
        if self.seed_window is not None:
            return min(int(self.seed_window), n_history)
        n, p = self.model.n_states, self.model.n_outputs
        return min(max(100, 20 * -(-n // p)), n_history)

    def initial_state(self, history) -> np.ndarray:
        h = _split_history(history, self.model.n_outputs, self.model.n_inputs)
        if h is None:
            return np.zeros(self.model.n_states)
        Y1, U1 = h
        w = None if self.output_scale is None else 1.0 / self.output_scale
        return estimate_state(self.model, Y1, U1, self.seed_window_length(Y1.shape[0]), w)

    def simulate(self, U2, history=None) -> np.ndarray:
        U2 = as_matrix(U2, "U2", cols=self.model.n_inputs)
        return cast(np.ndarray, self.model.simulate(U2, self.initial_state(history)))


# ---------------------------------------------------------------------------
# N4SID (nfoursid)
# ---------------------------------------------------------------------------
def _channel_scale(X: np.ndarray) -> np.ndarray:
    s = X.std(axis=0)
    s[~(s > 0)] = 1.0
    return s


def fit_n4sid(Y, U, order: int = 6, block_rows: int = 20, dt: float = 1.0,
              normalize: bool = True, seed_window: int | None = None
              ) -> tuple[StateSpacePredictor, float]:
    """N4SID (PO-MOESP instrumental variables, ``nfoursid.nfoursid.NFourSID``).

    Args:
        Y: (K, p) outputs; U: (K, m) inputs. One trajectory only (nfoursid
            builds a single block-Hankel matrix; concatenating trajectories
            would mix their seams).
        order: model order. Default 6: the beam has three modes in the
            10-800 Hz chirp band, two states each.
        block_rows: block rows of the Hankel matrices (needs block_rows * p >= order).
        dt: sample time (s) of the returned model.
        normalize: divide every input and output channel by its standard
            deviation before fitting and undo it on (B, C, D) afterwards.
            nfoursid's ``_identify_state_space`` uses a plain normal-equation
            ``pinv(x_and_u @ x_and_u.T)``, whose default cut-off discards the
            1e-5-scale outputs' information on raw beam data.
        seed_window: history samples used to seed a free run (None: automatic).

    Returns:
        (predictor, fit_seconds) with ``predictor.model`` a :class:`StateSpace`.
    """
    import pandas as pd
    from nfoursid.nfoursid import NFourSID

    if isinstance(Y, (list, tuple)) or isinstance(U, (list, tuple)):
        raise ValueError("fit_n4sid takes a single trajectory (nfoursid has no episode support)")
    Y = as_matrix(Y, "Y", min_rows=2)
    U = as_matrix(U, "U", min_rows=2)
    if U.shape[0] != Y.shape[0]:
        raise ValueError(f"Y has {Y.shape[0]} samples but U has {U.shape[0]}")
    p, m = Y.shape[1], U.shape[1]
    if block_rows * p < order:
        raise ValueError(f"block_rows * p = {block_rows * p} must be at least order = {order}")
    t0 = time.perf_counter()
    sy = _channel_scale(Y) if normalize else np.ones(p)
    su = _channel_scale(U) if normalize else np.ones(m)
    ycols = [f"y{i}" for i in range(p)]
    ucols = [f"u{j}" for j in range(m)]
    df = pd.DataFrame(np.hstack([Y / sy, U / su]), columns=ycols + ucols)
    n4 = NFourSID(df, output_columns=ycols, input_columns=ucols, num_block_rows=int(block_rows))
    n4.subspace_identification()
    ss, _ = n4.system_identification(rank=int(order))
    A = np.asarray(ss.a, float)
    B = np.asarray(ss.b, float) / su[None, :]
    C = sy[:, None] * np.asarray(ss.c, float)
    D = sy[:, None] * np.asarray(ss.d, float) / su[None, :]
    model = StateSpace(A, B, C, D, float(dt))
    seconds = time.perf_counter() - t0
    sv = np.diagonal(n4.R32_decomposition.eigenvalues).copy()
    pred = StateSpacePredictor(model, seed_window, sy.copy(),
                               {"peer": "nfoursid", "order": int(order),
                                "block_rows": int(block_rows), "normalize": bool(normalize),
                                "singular_values": sv})
    return pred, seconds


# ---------------------------------------------------------------------------
# pykoop
# ---------------------------------------------------------------------------
@dataclass
class PykoopPredictor:
    """A fitted ``pykoop.KoopmanPipeline`` (outputs as its "state", inputs as inputs).

    ``n_states`` is the Koopman (lifted) state size p (n_delays + 1); the input
    delays u[k-1..k-d] are carried by the pipeline as lifted inputs.

    ``simulate(..., method="pykoop")`` calls pykoop's own
    ``KoopmanPipeline.predict_trajectory(X0, U, relift_state=True)``, which
    costs several milliseconds per sample (it re-lifts through the sklearn
    machinery every step: ~1 min for the 10000-sample chirp). ``method="arx"``
    (default) runs the identical recursion in numpy: every lifting function used
    here is linear, so pykoop's one-step map (lift window, apply the Koopman
    matrices, retract, keep the newest sample) is a linear map of the last
    ``min_samples`` outputs and inputs; it is read off once by evaluating that
    map with pykoop's own ``lift_state`` / ``lift_input`` / ``retract_state``
    on unit windows (checked on a random window), then iterated.
    """

    pipeline: Any  # pykoop.KoopmanPipeline (an optional extra)
    n_outputs: int
    n_inputs: int
    info: dict = field(default_factory=dict)
    _step_map: np.ndarray | None = field(default=None, init=False, repr=False)

    @property
    def n_states(self) -> int:
        return int(self.pipeline.n_states_out_)

    @property
    def min_samples(self) -> int:
        return int(self.pipeline.min_samples_)

    def _one_step(self, Z: np.ndarray) -> np.ndarray:
        """pykoop's prediction of the next output for windows Z (N, ms, p + m) -> (N, p)."""
        kp, p = self.pipeline, self.n_outputs
        N, ms, _ = Z.shape
        X = np.concatenate([np.repeat(np.arange(N, dtype=float), ms)[:, None],
                            Z.reshape(N * ms, -1)], axis=1)
        Theta = kp.lift_state(X[:, :1 + p], episode_feature=True)  # one row per episode
        Ups = kp.lift_input(X, episode_feature=True)
        koop = kp.regressor_.coef_.T
        A, B = koop[:, :koop.shape[0]], koop[:, koop.shape[0]:]
        nxt = Theta[:, 1:] @ A.T + Ups[:, 1:] @ B.T
        R = kp.retract_state(np.hstack([Theta[:, :1], nxt]), episode_feature=True)
        ep = R[:, 0]
        last = np.r_[ep[1:] != ep[:-1], True]  # newest retracted sample of each episode
        return R[last, 1:]

    def step_map(self) -> np.ndarray:
        """(p, ms * (p + m)) matrix M: y[k] = M [y[k-ms..k-1], u[k-ms..k-1]] (row-major window)."""
        if self._step_map is None:
            ms, q = self.min_samples, self.n_outputs + self.n_inputs
            basis = np.vstack([np.zeros((1, ms * q)), np.eye(ms * q)]).reshape(-1, ms, q)
            out = self._one_step(basis)
            M = (out[1:] - out[0]).T
            if np.max(np.abs(out[0])) > 0:
                raise ValueError("pykoop pipeline is not linear (nonzero response to a zero window)")
            z = np.random.default_rng(0).standard_normal((1, ms, q))
            ref = self._one_step(z)[0]
            if not np.allclose(M @ z.ravel(), ref, rtol=1e-8, atol=1e-10 * np.max(np.abs(ref))):
                raise ValueError("pykoop pipeline is not linear; use method='pykoop'")
            self._step_map = M
        return self._step_map

    def _initial_window(self, history) -> tuple[np.ndarray, np.ndarray]:
        ms = self.min_samples
        h = _split_history(history, self.n_outputs, self.n_inputs)
        X0 = np.zeros((ms, self.n_outputs))
        Uh = np.zeros((ms, self.n_inputs))
        if h is not None:  # a history shorter than the delays is padded with rest
            Y1, U1 = h
            k = min(ms, Y1.shape[0])
            if k:
                X0[ms - k:] = Y1[-k:]
                Uh[ms - k:] = U1[-k:]
        return X0, Uh

    def simulate(self, U2, history=None, method: str = "arx") -> np.ndarray:
        U2 = as_matrix(U2, "U2", cols=self.n_inputs)
        ms, p, m = self.min_samples, self.n_outputs, self.n_inputs
        X0, Uh = self._initial_window(history)
        K = U2.shape[0]
        if K == 0:
            return np.zeros((0, p))
        Uall = np.vstack([Uh, U2])
        if method == "pykoop":
            # rows 0..ms-1 are the given window; row k >= ms is predicted from rows
            # k-ms..k-1 of states and inputs, so U row k is aligned with X row k.
            Xp = self.pipeline.predict_trajectory(X0, Uall, relift_state=True,
                                                  episode_feature=False)
            return np.asarray(Xp)[ms:]
        if method != "arx":
            raise ValueError(f"method must be 'arx' or 'pykoop', got {method!r}")
        M = self.step_map().reshape(p, ms, p + m)
        My, Mu = M[:, :, :p], M[:, :, p:]
        # input part for every step at once: c[k] = sum_j Mu[:, j] u[k + j]  (window k..k+ms-1)
        c = np.zeros((K, p))
        for j in range(ms):
            c += Uall[j:j + K] @ Mu[:, j, :].T
        Yall = np.vstack([X0, np.zeros((K, p))])
        My2 = My.transpose(1, 2, 0).reshape(ms * p, p)  # window (ms*p,) @ My2 -> (p,)
        for k in range(K):
            Yall[ms + k] = Yall[k:k + ms].reshape(-1) @ My2 + c[k]
        return Yall[ms:]


def fit_pykoop(Y, U, n_delays: int = 4, n_delays_input: int | None = None,
               alpha: float = 1e-6, scale: bool = True) -> tuple[PykoopPredictor, float]:
    """Koopman pipeline of pykoop: [scaling], delay lifting, EDMD.

    The lifted state is [y[k], ..., y[k-d]], the lifted input [u[k], ..., u[k-d_u]],
    and EDMD regresses the next lifted state on both: an ARX model
    y[k+1] = sum_i A_i y[k-i] + sum_i B_i u[k-i] (no direct feed-through, which
    suits zero-order-hold sampled mechanics, D = 0).

    Args:
        Y: (K, p) outputs, or a list of such (one per trajectory; pykoop's
            episode feature keeps the delays from crossing trajectory seams).
        U: (K, m) inputs, or a list matching Y.
        n_delays: delays d of the outputs.
        n_delays_input: delays of the inputs (None: same as n_delays).
        alpha: ``pykoop.Edmd`` Tikhonov coefficient (added as alpha / K to the
            normalised Gram matrix of the unit-variance lifted features).
        scale: divide every channel by its standard deviation first
            (``SkLearnLiftingFn(StandardScaler(with_mean=False))``, linear, so
            the ARX structure is kept).
    """
    import pykoop
    from sklearn.preprocessing import StandardScaler

    Ys, Us = as_trajectories(Y, U)
    d = int(n_delays)
    du = d if n_delays_input is None else int(n_delays_input)
    if d < 0 or du < 0:
        raise ValueError("delay counts must be non-negative")
    p, m = Ys[0].shape[1], Us[0].shape[1]
    for i, y in enumerate(Ys):
        if y.shape[0] < max(d, du) + 2:
            raise ValueError(f"trajectory {i} has {y.shape[0]} samples; at least "
                             f"{max(d, du) + 2} are needed for {max(d, du)} delays")
    t0 = time.perf_counter()
    X = np.vstack([np.hstack([np.full((y.shape[0], 1), float(i)), y, u])
                   for i, (y, u) in enumerate(zip(Ys, Us))])
    lifting = []
    if scale:
        lifting.append(("scale", pykoop.SkLearnLiftingFn(StandardScaler(with_mean=False))))
    lifting.append(("delay", pykoop.DelayLiftingFn(n_delays_state=d, n_delays_input=du)))
    kp = pykoop.KoopmanPipeline(lifting_functions=lifting, regressor=pykoop.Edmd(alpha=alpha))
    kp.fit(X, n_inputs=m, episode_feature=True)
    seconds = time.perf_counter() - t0
    return PykoopPredictor(kp, p, m, {"peer": "pykoop", "n_delays": d, "n_delays_input": du,
                                      "alpha": alpha, "scale": scale}), seconds


# ---------------------------------------------------------------------------
# PyDMD
# ---------------------------------------------------------------------------
def pydmd_note() -> str:
    """Why PyDMD is not in the free-run benchmark (checked against the installed version)."""
    try:
        import importlib.metadata as md
        version = md.version("pydmd")
    except Exception:  # noqa: BLE001 - any metadata failure just means "unknown"
        version = "not installed"
    return (f"PyDMD {version}: no class free-runs from a chosen state with new exogenous inputs: "
            "DMDc.reconstructed_data(control_input) always restarts from the first training "
            "snapshot(s) (self.snapshots[:, :lag]), needs exactly n_train - lag input columns, "
            "and treats the snapshots as the full state (6 displacement outputs of a 120-state "
            "beam are not); DMD.predict(X) and OptDMD.predict(X) are one-step autonomous maps, "
            "HAVOK.predict(forcing, time, V0) takes its own intermittent-forcing delay coordinate, "
            "not a measured input, and LANDO.predict(x0, tend) is autonomous.")
