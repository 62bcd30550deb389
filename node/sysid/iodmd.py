"""Input-output DMD with the full state measured (eq. 4.8-4.13)."""

from __future__ import annotations

import numpy as np

from node.sysid.base import LinearDMD
from node.sysid.statespace import StateSpace
from node.sysid.validation import as_matrix, as_trajectories


class IODMD(LinearDMD):
    """ioDMD: x[k+1] = A x[k] + B u[k], y[k] = C x[k] + D u[k] from measured states X.

    ``fit(Y, U, X=X)`` with X (K, n) (or lists, one per trajectory); without X the
    outputs are the states (X = Y: DMD with control, C = I, D = 0). :meth:`simulate`
    seeds the state from a history (Y1, U1) with the least-squares observer over the
    last ``seed_window`` samples (by default at least 100 and one time constant of the
    slowest pole), which needs the model observable from the outputs; ``x0=`` gives the
    state directly. ``seed_window=0`` (the lifted state alone) works only without X.

    Learned attributes: as :class:`LinearDMD`, and ``states_from_outputs_`` (True when
    fitted without X).

    A two-state system, its states measured, is recovered exactly, and seeded from its
    measured past it continues exactly:

    >>> from node.sysid import StateSpace, eps_td
    >>> sys = StateSpace(np.array([[0.9, 0.2], [0.0, 0.5]]), np.array([[1.0], [0.5]]),
    ...                  np.array([[1.0, 0.0]]), np.zeros((1, 1)))
    >>> U = np.random.default_rng(0).normal(size=(300, 1))
    >>> Y, X = sys.simulate(U, return_states=True)
    >>> m = IODMD().fit(Y[:200], U[:200], X=X[:200])
    >>> np.round(np.sort(m.model_.poles().real), 6)
    array([0.5, 0.9])
    >>> bool(eps_td(Y[200:], m.simulate(U[200:], history=(Y[:200], U[:200]))) < 1e-8)
    True
    """

    states_from_outputs_: bool

    def fit(self, Y, U=None, X=None):
        """Fit on outputs Y (K, p), inputs U (K, m) and measured states X (K, n), or lists of
        such (one per trajectory); X None: the outputs are the states. Returns self."""
        if X is None:
            super().fit(Y, U)  # _lift: the outputs themselves
            self.states_from_outputs_ = True
            return self
        self._check_params()
        Ys, Us = as_trajectories(Y, U, strict_outputs=True)
        Xs_in = list(X) if isinstance(X, (list, tuple)) else [X]
        if len(Xs_in) != len(Ys):
            raise ValueError(f"{len(Ys)} output trajectories but {len(Xs_in)} state trajectories")
        Xs = []
        for i, (x, y) in enumerate(zip(Xs_in, Ys)):
            xa = as_matrix(x, f"X[{i}]" if len(Ys) > 1 else "X", min_cols=1, allow_1d=False)
            if xa.shape[0] != y.shape[0]:
                raise ValueError(f"X has {xa.shape[0]} samples but Y has {y.shape[0]}")
            Xs.append(xa)
        if len({x.shape[1] for x in Xs}) != 1:
            raise ValueError("every state trajectory must have the same number of states")
        self._fit_lifted(Xs, Ys, Us)
        self.states_from_outputs_ = False
        return self

    def restore(self, model: StateSpace, refined: bool = False, states_from_outputs: bool = False):
        """As :meth:`LinearDMD.restore`; ``states_from_outputs``: the model was fitted without X."""
        super().restore(model, refined)
        self.states_from_outputs_ = bool(states_from_outputs)
        return self

    def _lift(self, Y: np.ndarray, U: np.ndarray) -> np.ndarray:
        return Y

    def _lifted_state(self, Y1: np.ndarray, U1: np.ndarray) -> np.ndarray | None:
        # measured states X are not a function of the outputs: the observer starts from zero
        return super()._lifted_state(Y1, U1) if self.states_from_outputs_ else None
