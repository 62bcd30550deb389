"""What every identification method shares: snapshot pairs, the least-squares
fit (eq. 4.13), the optional output-error refinement, seeding and free run.

A method only says how it lifts measurements into (pseudo-)states: ``_lift``
turns one trajectory's outputs (K, p) and inputs (K, m) into states (K, n);
the state at the last sample of a measured history is its last row.
"""

from __future__ import annotations

from enum import StrEnum

import numpy as np
from sklearn.base import BaseEstimator
from sklearn.exceptions import NotFittedError
from sklearn.utils import InputTags, Tags, TargetTags

from node.sysid.lstsq import pod_basis, truncated_lstsq
from node.sysid.observer import estimate_state
from node.sysid.refine import refine_poles, refit_bd
from node.sysid.statespace import StateSpace
from node.sysid.validation import as_matrix, as_trajectories


class Estimator(StrEnum):
    """How (A, B, C, D) are estimated from the snapshots."""

    LS = "ls"  # plain least squares, eq. 4.13 (biased by output noise)
    OE = "oe"  # least squares, then (B, D) re-estimated on the free-run output error
    IV = "iv"  # instrumental variables (delayed states, inputs), then the OE (B, D) step
    PEM = "pem"  # least squares, then poles and (B, D) refined on the free-run output error


class LinearDMD(BaseEstimator):
    """Base of IODMD, DelayDMD and WDMD: scikit-learn estimators (``get_params``, ``set_params``,
    ``sklearn.base.clone``, a readable repr; ``fit`` returns self; used before ``fit``, they
    raise ``sklearn.exceptions.NotFittedError``, which ``check_is_fitted`` agrees with).

    Args:
        rcond: relative singular-value tolerance of the pseudo-inverse (beta).
        ridge: Tikhonov weight of the operator fit relative to the largest squared singular
            value of the (column-scaled) regressors; 0: none. Shrinks the weakly excited
            directions that make free runs drift.
        rank: optional POD truncation of the (pseudo-)state, None keeps all.
        estimator: ``"ls"`` or ``"oe"`` (see :class:`Estimator`).
        dt: sample time in seconds (for frequency responses).
        warmup: leading samples of each trajectory used only to fill the
            lifting's memory, not as snapshot pairs (0: the signal is taken
            as constant before its first sample).
        seed_window: samples of a history used to seed a free run: the
            lifted state at the window start is corrected by least squares
            so that the model's free run fits the window's outputs (which
            averages measurement noise out). None: automatic (see
            :meth:`seed_window_length`); 0: the lifted state alone.

    Learned attributes: ``model_`` (:class:`StateSpace`), ``rank_`` (rank kept
    by the pseudo-inverse), ``basis_`` (POD basis or None), ``n_inputs_``,
    ``n_outputs_`` (= ``n_features_in_``: Y is scikit-learn's X), ``refined_``
    (whether the OE step ran).

    Y must be a dense, real, finite 2-D array (a 1-D U is one input); anything else is
    refused with a one-line error. scikit-learn's ``check_estimator`` passes but for the
    name of ``fit``'s second argument (see docs/sysid.md).
    """

    min_samples = 3
    rank_: int | None
    seed_rcond = 1e-4  # relative tolerance of the seeding observer

    def __init__(self, rcond: float = 1e-10, rank: int | None = None,
                 estimator: str = "oe", dt: float = 1.0, warmup: int = 0,
                 seed_window: int | None = None, ridge: float = 0.0) -> None:
        self.rcond = rcond
        self.ridge = ridge
        self.rank = rank
        self.estimator = estimator
        self.dt = dt
        self.warmup = warmup
        self.seed_window = seed_window

    def __sklearn_tags__(self) -> Tags:
        """Dense, finite, real 2-D outputs Y (the ``X`` of scikit-learn's checks); inputs U
        (its ``y``) optional, one column or several."""
        tags = super().__sklearn_tags__()
        tags.input_tags = InputTags(two_d_array=True, sparse=False, allow_nan=False)
        tags.target_tags = TargetTags(required=False, one_d_labels=False, two_d_labels=False,
                                      multi_output=True, single_output=True)
        return tags

    # --- what a method defines ------------------------------------------
    def _lift(self, Y: np.ndarray, U: np.ndarray) -> np.ndarray:
        """(Pseudo-)states of one trajectory: Y (K, p), U (K, m) -> (K, n_lift).

        Row k may use samples up to k only (except non-causal variants).
        """
        raise NotImplementedError

    def memory(self) -> int:
        """Samples of past a lifted state depends on (its warm-up length)."""
        return 0

    # --- fit ---------------------------------------------------------------
    def _check_params(self) -> Estimator:
        if not (isinstance(self.rcond, (int, float)) and self.rcond > 0):
            raise ValueError(f"rcond must be a positive number, got {self.rcond!r}")
        if not (isinstance(self.ridge, (int, float)) and self.ridge >= 0):
            raise ValueError(f"ridge must be a number >= 0, got {self.ridge!r}")
        if self.rank is not None and (int(self.rank) != self.rank or self.rank < 1):
            raise ValueError(f"rank must be a positive integer or None, got {self.rank!r}")
        if not self.dt > 0:
            raise ValueError(f"dt must be positive, got {self.dt!r}")
        if self.seed_window is not None and (int(self.seed_window) != self.seed_window
                                             or self.seed_window < 0):
            raise ValueError(f"seed_window must be a non-negative integer or None, "
                             f"got {self.seed_window!r}")
        if int(self.warmup) != self.warmup or self.warmup < 0:
            raise ValueError(f"warmup must be a non-negative integer, got {self.warmup!r}")
        try:
            return Estimator(self.estimator)
        except ValueError:
            raise ValueError(f"estimator must be one of {[e.value for e in Estimator]}, "
                             f"got {self.estimator!r}") from None

    def _fit_lifted(self, Zs: list[np.ndarray], Ys: list[np.ndarray], Us: list[np.ndarray]):
        estimator = self._check_params()
        w = int(self.warmup)
        for i, y in enumerate(Ys):
            if y.shape[0] < self.min_samples + w:
                raise ValueError(f"trajectory {i} has {y.shape[0]} samples; at least "
                                 f"{self.min_samples + w} are needed (warmup {w})")
        Zs, Ys, Us = [z[w:] for z in Zs], [y[w:] for y in Ys], [u[w:] for u in Us]
        self.basis_ = pod_basis(np.vstack(Zs), self.rank)
        Xs = [z if self.basis_ is None else z @ self.basis_ for z in Zs]
        # snapshot pairs inside each trajectory only (eq. 5.22): never across the seam
        if estimator is Estimator.IV:
            W, self.rank_ = self._iv_solve(Xs, Ys, Us)
        else:
            R = np.vstack([np.hstack([x[:-1], u[:-1]]) for x, u in zip(Xs, Us)])
            T = np.vstack([np.hstack([x[1:], y[:-1]]) for x, y in zip(Xs, Ys)])
            W, self.rank_ = truncated_lstsq(R, T, self.rcond, ridge=float(self.ridge))
        n = Xs[0].shape[1]
        G = W.T  # [[A, B], [C, D]]
        A, B, C, D = G[:n, :n], G[:n, n:], G[n:, :n], G[n:, n:]
        self.refined_ = False
        if estimator is Estimator.PEM and Us[0].shape[1] > 0:
            abd = refine_poles(A, C, Ys, Us, [x[0] for x in Xs])
            if abd is not None:
                A, B, D = abd
                self.refined_ = True
        if estimator in (Estimator.OE, Estimator.IV) and Us[0].shape[1] > 0:
            if np.max(np.abs(np.linalg.eigvals(A))) < 1.0:
                bd = refit_bd(A, C, Ys, Us, [x[0] for x in Xs])
                if bd is not None:
                    B, D = bd
                    self.refined_ = True
        self.model_ = StateSpace(A.copy(), B.copy(), C.copy(), D.copy(), float(self.dt))
        self.n_inputs_ = Us[0].shape[1]
        self.n_outputs_ = Ys[0].shape[1]
        self.n_features_in_ = self.n_outputs_
        return self

    def _iv_solve(self, Xs, Ys, Us) -> tuple[np.ndarray, int]:
        """Two-stage least squares with instruments the lifted state d = ``memory() + 1``
        samples earlier and the inputs since then: their noise is independent of the noise in
        the regressors and targets of sample k, so the estimate is not biased by it, and
        without noise they determine the regressors exactly."""
        d = self.memory() + 1
        input_lags = d + 1
        Rs, Ts, Ws = [], [], []
        for x, y, u in zip(Xs, Ys, Us):
            K = x.shape[0]
            lo = max(d, input_lags - 1)
            if K - 1 - lo < 2:
                continue
            k = np.arange(lo, K - 1)
            Rs.append(np.hstack([x[k], u[k]]))
            Ts.append(np.hstack([x[k + 1], y[k]]))
            Ws.append(np.hstack([x[k - d]] + [u[k - i] for i in range(input_lags)]))
        if not Rs:
            raise ValueError(f"trajectories too short for instrumental variables (need more than "
                             f"{d + 2} samples each)")
        R, T, Wi = np.vstack(Rs), np.vstack(Ts), np.vstack(Ws)
        P, _ = truncated_lstsq(Wi, R, self.rcond)  # first stage: R projected on the instruments
        return truncated_lstsq(Wi @ P, T, self.rcond)

    def fit(self, Y, U=None):
        """Fit on outputs Y (K, p) and inputs U (K, m), or lists of such (one per trajectory)."""
        self._check_params()
        Ys, Us = as_trajectories(Y, U, strict_outputs=True)
        Zs = [self._lift(y, u) for y, u in zip(Ys, Us)]
        return self._fit_lifted(Zs, Ys, Us)

    # --- the fitted model ----------------------------------------------------
    def restore(self, model: StateSpace, refined: bool = False):
        """Install a model identified earlier (e.g. loaded from a bundle); returns self.

        The method's own parameters must be those it was fitted with, so that
        lifting and seeding work as at fit time.
        """
        self._check_params()
        if self.rank is not None:
            raise ValueError("a model with a POD rank cannot be restored from (A, B, C, D) alone")
        self.model_ = model
        self.basis_ = None
        self.rank_ = None
        self.refined_ = refined
        self.n_inputs_ = model.n_inputs
        self.n_outputs_ = model.n_outputs
        self.n_features_in_ = model.n_outputs
        return self

    def _require_fit(self) -> StateSpace:
        model = getattr(self, "model_", None)
        if model is None:
            raise NotFittedError(f"{type(self).__name__} is not fitted yet: call fit first")
        return model

    @property
    def A(self) -> np.ndarray:
        return self._require_fit().A

    @property
    def B(self) -> np.ndarray:
        return self._require_fit().B

    @property
    def C(self) -> np.ndarray:
        return self._require_fit().C

    @property
    def D(self) -> np.ndarray:
        return self._require_fit().D

    def _project(self, z: np.ndarray) -> np.ndarray:
        return z if self.basis_ is None else z @ self.basis_

    def initial_state(self, history, u_next: np.ndarray | None = None) -> np.ndarray:
        """State at the first sample after ``history`` (see :meth:`simulate`).

        ``u_next`` (m,) stands in for the last history input when the history
        has no inputs.
        """
        model = self._require_fit()
        if history is None:
            return np.zeros(model.n_states)
        if isinstance(history, tuple):
            if len(history) != 2:
                raise ValueError("history must be Y1, (Y1, U1) or None")
            Y1, U1 = history
        else:
            Y1, U1 = history, None
        Y1 = as_matrix(Y1, "history outputs Y1", cols=self.n_outputs_, min_rows=1)
        if U1 is not None:
            U1 = as_matrix(U1, "history inputs U1", cols=self.n_inputs_)
            if U1.shape[0] != Y1.shape[0]:
                raise ValueError(f"history Y1 has {Y1.shape[0]} samples but U1 has {U1.shape[0]}")
        else:
            guess = np.zeros(self.n_inputs_) if u_next is None else np.asarray(u_next, float)
            U1 = np.tile(guess, (Y1.shape[0], 1))
        K1 = Y1.shape[0]
        W = self.seed_window_length(K1)
        x_last = self._lifted_state(Y1, U1) if W <= 1 else None
        if x_last is not None:
            return model.A @ x_last + model.B @ U1[-1]
        if W == 0:
            raise ValueError(f"{type(self).__name__} has no lifted state to seed from "
                             f"(seed_window=0): use seed_window=None or >= 1, or pass x0=")
        # lifted state at the window start (zero where there is none), corrected by least
        # squares on the window's outputs
        start = K1 - W
        x_s = self._lifted_state(Y1[:start + 1], U1[:start + 1])
        return estimate_state(model, Y1[start:], U1[start:], x_s, rcond=self.seed_rcond)

    def _lifted_state(self, Y1: np.ndarray, U1: np.ndarray) -> np.ndarray | None:
        """The (projected) lifted state at the last sample of (Y1, U1), or None where the
        method cannot lift measurements into its state."""
        keep = self.memory() + 1
        return self._project(self._lift(Y1[-keep:], U1[-keep:])[-1])

    def seed_window_length(self, n_history: int) -> int:
        """Samples of history the seeding observer uses (0 or 1: the lifted state alone).

        Auto (``seed_window=None``): at least 20 n / p samples and one time
        constant of the slowest pole (capped at 10,000), at least 100.
        """
        if self.seed_window is not None:
            return min(int(self.seed_window), n_history)
        model = self._require_fit()
        auto = max(100, 20 * -(-model.n_states // model.n_outputs))
        rho = model.spectral_radius()
        if rho < 1.0:
            auto = max(auto, min(10_000, int(np.ceil(1.0 / (1.0 - rho)))))
        return min(auto, n_history)

    def simulate(self, U, history=None, x0: np.ndarray | None = None) -> np.ndarray:
        """Free-run prediction (len(U), p) driven by U (K, m).

        The state is seeded from ``history``: (Y1, U1) measured just before U
        starts, or Y1 alone (the last unknown input taken equal to U[0]), or
        None to start from rest. ``x0`` overrides the seed with a state.
        """
        model = self._require_fit()
        U = as_matrix(U, "U", cols=self.n_inputs_)
        if x0 is None:
            x0 = self.initial_state(history, U[0] if len(U) else None)
        else:
            x0 = np.asarray(x0, dtype=float).reshape(model.n_states)
        return model.simulate(U, x0)
