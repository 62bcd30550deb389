"""One OC's model: the identified dynamics plus the input scaling, for any method.

``OCModel`` is what a bundle stores per OC and what training fits and
evaluates. ``OCModel.runtime()`` gives the online stepper the node runs:
seeded once from the measured history at the OC switch, then one ``step``
per sample, with bounded memory and no I/O.

Methods: ``wdmd`` and ``delay-dmd`` (state-space, free run across the OC)
and ``lasso`` (static regression, eq. 3.26-3.27). Inputs are standardised
per OC and a constant input (1) is appended, so every model is affine.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np

from node.contract import FS
from node.sysid import WDMD, DelayDMD, LinearDMD, StateSpace


class Method(StrEnum):
    WDMD = "wdmd"
    DELAY_DMD = "delay-dmd"
    LASSO = "lasso"


def _dmd(method: Method, params: dict) -> LinearDMD:
    # seed_window 0: at a switch the state is the lifted measured past itself; fitting this
    # OC's model to a window of the previous OC's data (the observer) seeds worse (measured)
    common = {"rcond": params.get("rcond", 1e-8), "estimator": params.get("estimator", "oe"),
              "dt": 1.0 / FS, "seed_window": params.get("seed_window", 0)}
    if method is Method.WDMD:
        return WDMD(levels=int(params["levels"]), wavelet=params.get("wavelet", "haar"), **common)
    if method is Method.DELAY_DMD:
        return DelayDMD(delays=int(params["delays"]), lag=int(params.get("lag", 1)), **common)
    raise ValueError(f"{method} is not a state-space method")


def memory(method: Method, params: dict) -> int:
    """Samples of past target the method's state needs at a switch."""
    return 0 if method is Method.LASSO else _dmd(method, params).memory()


@dataclass
class Trajectory:
    """One OC segment with the past before it: y (K,), U (K, m); samples [start, K) are the OC."""

    y: np.ndarray
    U: np.ndarray
    start: int

    @property
    def seg_y(self) -> np.ndarray:
        return self.y[self.start:]

    @property
    def seg_U(self) -> np.ndarray:
        return self.U[self.start:]


@dataclass
class OCModel:
    """A fitted per-OC model.

    Attributes:
        method, params: how it was made (params: levels/wavelet, delays/lag,
            alpha, rcond, estimator).
        u_mean, u_scale: (m,) input standardisation.
        ss: the state-space model (inputs: m standardised + the constant), or None.
        coef, intercept: the Lasso regression on standardised inputs, or None.
        repaired: number of unstable poles moved inside the unit circle.
    """

    method: Method
    params: dict
    u_mean: np.ndarray
    u_scale: np.ndarray
    ss: StateSpace | None = None
    coef: np.ndarray | None = None
    intercept: float = 0.0
    repaired: int = 0
    _dmd_cache: LinearDMD | None = field(default=None, repr=False, compare=False)

    # -- inputs -------------------------------------------------------------
    def scale_inputs(self, U: np.ndarray) -> np.ndarray:
        """(K, m) raw inputs -> (K, m + 1) standardised inputs plus the constant 1."""
        Un = (np.asarray(U, float) - self.u_mean) / self.u_scale
        return np.hstack([Un, np.ones((Un.shape[0], 1))])

    def dmd(self) -> LinearDMD:
        if self._dmd_cache is None:
            self._dmd_cache = _dmd(self.method, self.params).restore(self.ss)
        return self._dmd_cache

    # -- batch prediction (training, evaluation) -------------------------------
    def predict(self, traj: Trajectory) -> np.ndarray:
        """Free-run prediction over the OC samples of ``traj``, seeded from its past: (K_seg,)."""
        U = self.scale_inputs(traj.U)
        if self.method is Method.LASSO:
            return U[traj.start:, :-1] @ self.coef + self.intercept
        if traj.start == 0:
            return self.dmd().simulate(U, history=None)[:, 0]
        hist = (traj.y[:traj.start, None], U[:traj.start])
        return self.dmd().simulate(U[traj.start:], history=hist)[:, 0]

    def runtime(self) -> OCRuntime:
        return OCRuntime(self)

    # -- storage ---------------------------------------------------------------
    def arrays(self) -> dict[str, np.ndarray]:
        out = {"u_mean": self.u_mean, "u_scale": self.u_scale}
        if self.ss is not None:
            out.update(A=self.ss.A, B=self.ss.B, C=self.ss.C, D=self.ss.D)
        if self.coef is not None:
            out.update(coef=self.coef, intercept=np.array([self.intercept]))
        return out

    @classmethod
    def from_arrays(cls, method: str, params: dict, arrays: dict[str, np.ndarray],
                    repaired: int = 0) -> OCModel:
        m = Method(method)
        ss = None
        if m is not Method.LASSO:
            ss = StateSpace(arrays["A"], arrays["B"], arrays["C"], arrays["D"], 1.0 / FS)
        return cls(m, dict(params), arrays["u_mean"], arrays["u_scale"], ss=ss,
                   coef=arrays.get("coef"),
                   intercept=float(arrays["intercept"][0]) if "intercept" in arrays else 0.0,
                   repaired=repaired)


class OCRuntime:
    """Online stepper of one OC model: ``start`` at the switch, then ``step`` per sample.

    One matrix-vector product per sample: the input scaling is folded into
    G = [[C, D], [A, B]] acting on z = [x; u; 1] (raw inputs u).
    """

    def __init__(self, model: OCModel) -> None:
        self.model = model
        m = model
        inv = 1.0 / np.asarray(m.u_scale, float)
        shift = -np.asarray(m.u_mean, float) * inv
        k = inv.size
        if m.method is Method.LASSO:
            self._w = np.append(np.asarray(m.coef, float) * inv, m.intercept + float(shift @ m.coef))
            self._z = np.ones(k + 1)
            self._n = 0
            return
        ss = m.ss
        n = ss.n_states
        top = np.hstack([ss.C[:1], ss.D[:1, :k] * inv, ss.D[:1, k:] + ss.D[:1, :k] @ shift[:, None]])
        low = np.hstack([ss.A, ss.B[:, :k] * inv, ss.B[:, k:] + ss.B[:, :k] @ shift[:, None]])
        self._G = np.ascontiguousarray(np.vstack([top, low]))
        self._z = np.zeros(n + k + 1)
        self._z[-1] = 1.0
        self._n = n

    def start(self, y_hist: np.ndarray, U_hist: np.ndarray) -> None:
        """Seed from the measured past: y_hist (K1,), U_hist (K1, m) (K1 may be 0)."""
        m = self.model
        if m.method is Method.LASSO:
            return
        if len(y_hist) == 0:
            self._z[: self._n] = 0.0
            return
        Un = m.scale_inputs(U_hist)
        self._z[: self._n] = m.dmd().initial_state((np.asarray(y_hist, float)[:, None], Un))

    def step(self, u) -> float:
        """Prediction for this sample from its raw inputs u (m,); advances the state."""
        z, n = self._z, self._n
        z[n:-1] = u
        if self.model.method is Method.LASSO:
            return float(self._w @ z)
        out = self._G @ z
        z[:n] = out[1:]
        return float(out[0])


# -- fitting -------------------------------------------------------------------------------
def _stabilise(ss: StateSpace, radius: float = 0.999) -> tuple[StateSpace, int]:
    """Move poles outside ``radius`` onto it, keeping the state coordinates (A = V L V^-1)."""
    lam, V = np.linalg.eig(ss.A)
    bad = np.abs(lam) >= radius
    if not bad.any():
        return ss, 0
    lam = np.where(bad, lam / np.abs(lam) * radius, lam)
    A = (V @ np.diag(lam) @ np.linalg.inv(V)).real
    return StateSpace(A, ss.B, ss.C, ss.D, ss.dt), int(bad.sum())


def fit_oc_model(method: str, params: dict, trajs: list[Trajectory]) -> OCModel:
    """Fit one OC's model on its trajectories (the past before each segment warms the lifting)."""
    meth = Method(method)
    U_all = np.vstack([t.seg_U for t in trajs])
    u_mean = U_all.mean(axis=0)
    u_scale = U_all.std(axis=0)
    u_scale[u_scale < 1e-9 * (np.abs(u_mean) + 1.0)] = 1.0
    model = OCModel(meth, dict(params), u_mean, u_scale)
    if meth is Method.LASSO:
        from sklearn.exceptions import ConvergenceWarning  # training only: the node starts faster
        from sklearn.linear_model import Lasso

        X = np.vstack([model.scale_inputs(t.seg_U)[:, :-1] for t in trajs])
        y = np.concatenate([t.seg_y for t in trajs])
        with warnings.catch_warnings():  # a small alpha may stop at max_iter: still the CV's pick
            warnings.simplefilter("ignore", ConvergenceWarning)
            reg = Lasso(alpha=float(params["alpha"]), precompute=True, max_iter=5_000, tol=1e-6).fit(X, y)
        model.coef = reg.coef_.copy()
        model.intercept = float(reg.intercept_)
        return model
    need = memory(meth, params)
    Ys, Us = [], []
    for t in trajs:
        lo = max(0, t.start - need)
        y, U = t.y[lo:], model.scale_inputs(t.U[lo:])
        pad = need - (t.start - lo)
        if pad:  # not enough past: hold the first value (the lifting's own edge rule)
            y = np.concatenate([np.repeat(y[:1], pad), y])
            U = np.vstack([np.repeat(U[:1], pad, axis=0), U])
        Ys.append(y[:, None])
        Us.append(U)
    dmd = _dmd(meth, params)
    dmd.warmup = need
    dmd.fit(Ys, Us)
    ss, moved = _stabilise(dmd.model_)
    if moved:
        from node.sysid.refine import refit_bd
        x0s = [dmd._project(dmd._lift(y, u)[need]) for y, u in zip(Ys, Us)]
        bd = refit_bd(ss.A, ss.C, [y[need:] for y in Ys], [u[need:] for u in Us], x0s)
        if bd is not None:
            ss = StateSpace(ss.A, bd[0], ss.C, bd[1], ss.dt)
    model.ss = ss
    model.repaired = moved
    return model
