"""Input-output DMD with the full state measured (eq. 4.8-4.13)."""

from __future__ import annotations

import numpy as np

from node.sysid.base import LinearDMD
from node.sysid.validation import as_matrix, as_trajectories


class IODMD(LinearDMD):
    """ioDMD: x[k+1] = A x[k] + B u[k], y[k] = C x[k] + D u[k] from measured states X.

    ``fit(Y, U, X=X)`` with X (K, n) (or lists, one per trajectory). A history
    of outputs does not give the state: pass ``x0=`` to :meth:`simulate`.

    A two-state system, its states measured, is recovered exactly:

    >>> from node.sysid import StateSpace
    >>> sys = StateSpace(np.array([[0.9, 0.2], [0.0, 0.5]]), np.array([[1.0], [0.5]]),
    ...                  np.array([[1.0, 0.0]]), np.zeros((1, 1)))
    >>> U = np.random.default_rng(0).normal(size=(200, 1))
    >>> Y, X = sys.simulate(U, return_states=True)
    >>> m = IODMD().fit(Y, U, X=X[:-1])
    >>> np.round(np.sort(m.model_.poles().real), 6)
    array([0.5, 0.9])
    """

    def fit(self, Y, U=None, X=None):
        if X is None:
            raise ValueError("IODMD needs the measured states: fit(Y, U, X=X)")
        self._check_params()
        Ys, Us = as_trajectories(Y, U)
        Xs_in = list(X) if isinstance(X, (list, tuple)) else [X]
        if len(Xs_in) != len(Ys):
            raise ValueError(f"{len(Ys)} output trajectories but {len(Xs_in)} state trajectories")
        Xs = []
        for i, (x, y) in enumerate(zip(Xs_in, Ys)):
            xa = as_matrix(x, f"X[{i}]" if len(Ys) > 1 else "X")
            if xa.shape[0] != y.shape[0]:
                raise ValueError(f"X has {xa.shape[0]} samples but Y has {y.shape[0]}")
            Xs.append(xa)
        if len({x.shape[1] for x in Xs}) != 1:
            raise ValueError("every state trajectory must have the same number of states")
        return self._fit_lifted(Xs, Ys, Us)

    def _lift(self, Y: np.ndarray, U: np.ndarray) -> np.ndarray:
        raise ValueError("IODMD cannot seed its state from outputs alone: pass x0= to simulate")
