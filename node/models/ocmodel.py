"""One OC's model: the identified dynamics plus the input scaling.

Three kinds, one class each, behind the small protocol :class:`OCModel`:

* :class:`StateSpaceModel` (``wdmd``, ``delay-dmd``): seeded from the measured
  past at the OC switch, then free-running across the OC;
* :class:`RegressionModel` (``lasso``): a static regression, eq. 3.26-3.27;
* ``CurveModel`` (``curve``, in ``node.models.curve``): the OC's characteristic
  curve, or the derived ``run_curve`` input itself: the baseline every other kind must beat.

Each is a frozen dataclass built complete by its ``fit`` (training) or its
``from_arrays`` (the bundle loader); ``node.models.kinds`` maps a method to its class.
``model.runtime()`` gives the online stepper the node runs (:class:`OCRuntime`):
``start`` once at the switch, then one ``step`` per sample, with bounded memory
and no I/O. Inputs are standardised per OC and a constant input (1) is
appended, so every model is affine.

A state-space model takes its inputs in one of two forms (``params["form"]``,
:class:`InputForm`): as measured (``abs``), or as increments from their value
at the OC switch (``inc``: the last sample before the OC, or the OC's first
sample when there is no past), so that the level the run's past set is carried
by the seeded state and not pulled towards the training runs' mean.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import ClassVar, Protocol

import numpy as np

from node.contract import FS
from node.sysid import WDMD, DelayDMD, LinearDMD, StateSpace

RUN_CURVE = "run_curve"  # the derived input channel's name (node.runtime.runcurve computes it)

class InputForm(StrEnum):
    ABSOLUTE = "abs"  # the inputs as measured
    INCREMENT = "inc"  # the inputs minus their value at the OC switch


def input_form(params: Mapping) -> InputForm:
    return InputForm(params.get("form", InputForm.ABSOLUTE))


class Method(StrEnum):
    WDMD = "wdmd"
    DELAY_DMD = "delay-dmd"
    LASSO = "lasso"
    CURVE = "curve"
    PROM = "prom"  # a parametric model (node.models.prom)
    AVERAGE = "average"  # the mean of an OC's best models (node.models.average)


def _readonly(a: np.ndarray, dtype: type = float) -> np.ndarray:
    out: np.ndarray = np.array(a, dtype=dtype)
    out.setflags(write=False)
    return out


@dataclass(frozen=True, eq=False)
class Trajectory:
    """One OC segment with the past before it: y (K,), U (K, m); samples [start, K) are the OC.

    z: the target order's 1x vectors (K,) complex (amplitude x exp(-j phase)), when its phase
    is recorded (None: amplitude only); the vector curve takes its measured past from it.
    """

    y: np.ndarray
    U: np.ndarray
    start: int
    z: np.ndarray | None = None

    @property
    def seg_y(self) -> np.ndarray:
        return self.y[self.start:]

    @property
    def seg_U(self) -> np.ndarray:
        return self.U[self.start:]

    def reference(self) -> np.ndarray:
        """The inputs at the OC switch (m,): the last sample before the OC, else its first."""
        return self.U[self.start - 1] if self.start > 0 else self.U[0]

    def in_form(self, form: InputForm) -> Trajectory:
        """This trajectory with its inputs in ``form`` (itself for ``abs``)."""
        if form is InputForm.ABSOLUTE:
            return self
        return Trajectory(self.y, self.U - self.reference(), self.start, self.z)


@dataclass(frozen=True, eq=False)
class InputScaling:
    """Per-OC input standardisation: (u - mean) / scale, then the constant 1 appended.

    mean, scale: (m,), in the inputs' units; a (nearly) constant input keeps scale 1.

    >>> s = InputScaling.fit(np.array([[1.0, 5.0], [3.0, 5.0]]))
    >>> s.mean, s.scale
    (array([2., 5.]), array([1., 1.]))
    >>> s.apply(np.array([[3.0, 5.0]]))
    array([[1., 0., 1.]])
    """

    mean: np.ndarray
    scale: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "mean", _readonly(self.mean))
        object.__setattr__(self, "scale", _readonly(self.scale))

    @classmethod
    def fit(cls, U: np.ndarray) -> InputScaling:
        """From the OC samples' inputs U (K, m)."""
        mean = U.mean(axis=0)
        scale = U.std(axis=0)
        scale[scale < 1e-9 * (np.abs(mean) + 1.0)] = 1.0
        return cls(mean, scale)

    def apply(self, U: np.ndarray) -> np.ndarray:
        """(K, m) raw inputs -> (K, m + 1) standardised inputs plus the constant 1."""
        Un = (np.asarray(U, float) - self.mean) / self.scale
        return np.hstack([Un, np.ones((Un.shape[0], 1))])

    def folded(self) -> tuple[np.ndarray, np.ndarray]:
        """(inv, shift), each (m,): standardised u = inv * u + shift (for the steppers)."""
        inv = 1.0 / np.asarray(self.scale, float)
        return inv, -np.asarray(self.mean, float) * inv

    def arrays(self) -> dict[str, np.ndarray]:
        return {"u_mean": self.mean, "u_scale": self.scale}

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray]) -> InputScaling:
        return cls(arrays["u_mean"], arrays["u_scale"])


class OCRuntime(Protocol):
    """The online stepper of one OC model (bounded memory, no I/O)."""

    def start(self, y_hist: np.ndarray, U_hist: np.ndarray) -> None:
        """Seed from the measured past: y_hist (K1,), U_hist (K1, m) (K1 may be 0)."""

    def step(self, u: Sequence[float] | np.ndarray) -> float:
        """Prediction for this sample from its raw inputs u (m,); advances the state."""
        ...


class OCModel(Protocol):
    """What every OC model kind gives (see :class:`StateSpaceModel`, :class:`RegressionModel`)."""

    @property
    def method(self) -> Method: ...

    @property
    def params(self) -> dict: ...

    @property
    def repaired(self) -> int:
        """Number of unstable poles moved inside the unit circle."""
        ...

    @property
    def n_states(self) -> int: ...

    def predict(self, traj: Trajectory) -> np.ndarray:
        """Prediction over the OC samples of ``traj``, seeded from its past: (K_seg,)."""
        ...

    def runtime(self) -> OCRuntime: ...

    def arrays(self) -> dict[str, np.ndarray]:
        """The arrays a bundle stores (``from_arrays`` reads them back)."""
        ...


class OCModelKind(Protocol):
    """A model class: how training fits it and how a bundle loads it."""

    def fit(self, method: Method, params: dict, trajs: Sequence[Trajectory]) -> OCModel: ...

    def from_arrays(self, method: Method, params: dict, arrays: Mapping[str, np.ndarray],
                    repaired: int = 0) -> OCModel: ...


# -- state space -----------------------------------------------------------------------------
def _dmd(method: Method, params: dict) -> LinearDMD:
    # seed_window 0: at a switch the state is the lifted measured past itself; fitting this
    # OC's model to a window of the previous OC's data (the observer) seeds worse (measured)
    common = {"rcond": params.get("rcond", 1e-8), "estimator": params.get("estimator", "oe"),
              "dt": 1.0 / FS, "seed_window": params.get("seed_window", 0),
              "ridge": float(params.get("ridge", 0.0))}
    if method is Method.WDMD:
        return WDMD(levels=int(params["levels"]), wavelet=params.get("wavelet", "haar"), **common)
    if method is Method.DELAY_DMD:
        return DelayDMD(delays=int(params["delays"]), lag=int(params.get("lag", 1)), **common)
    raise ValueError(f"{method} is not a state-space method")


def _stabilise(ss: StateSpace, radius: float = 0.999) -> tuple[StateSpace, int]:
    """Move poles outside ``radius`` onto it, keeping the state coordinates (A = V L V^-1)."""
    lam, V = np.linalg.eig(ss.A)
    bad = np.abs(lam) >= radius
    if not bad.any():
        return ss, 0
    lam = np.where(bad, lam / np.abs(lam) * radius, lam)
    A = (V @ np.diag(lam) @ np.linalg.inv(V)).real
    return StateSpace(A, ss.B, ss.C, ss.D, ss.dt), int(bad.sum())


def lifted_pair(t: Trajectory, scaling: InputScaling, need: int) -> tuple[np.ndarray, np.ndarray]:
    """A trajectory's target (K', 1) and standardised inputs (K', m + 1) from ``need`` samples
    before its OC on (the first held where it has less past: the lifting's own edge rule)."""
    lo = max(0, t.start - need)
    y, U = t.y[lo:], scaling.apply(t.U[lo:])
    pad = need - (t.start - lo)
    if pad:
        y = np.concatenate([np.repeat(y[:1], pad), y])
        U = np.vstack([np.repeat(U[:1], pad, axis=0), U])
    return y[:, None], U


def stable_fit(dmd: LinearDMD, Ys: list[np.ndarray], Us: list[np.ndarray],
               need: int) -> tuple[StateSpace, int]:
    """Fit ``dmd`` on trajectories whose first ``need`` samples warm the lifting; poles on or
    beyond the unit circle are moved onto radius 0.999 and B, D refitted to the data given
    A and C (the gain a moved pole carried, put back). Returns the model and the poles moved."""
    dmd.warmup = need
    dmd.fit(Ys, Us)
    ss, moved = _stabilise(dmd.model_)
    if moved:
        from node.sysid.refine import refit_bd
        x0s = [dmd._project(dmd._lift(y, u)[need]) for y, u in zip(Ys, Us)]
        bd = refit_bd(ss.A, ss.C, [y[need:] for y in Ys], [u[need:] for u in Us], x0s)
        if bd is not None:
            ss = StateSpace(ss.A, bd[0], ss.C, bd[1], ss.dt)
    return ss, moved


def stepper_matrix(ss: StateSpace, scaling: InputScaling) -> np.ndarray:
    """G = [[C, D], [A, B]] (first output only) acting on z = [x; u; 1] with raw inputs u (m,):
    ``ss`` takes the m standardised inputs and the constant 1, the scaling is folded in."""
    inv, shift = scaling.folded()
    k = inv.size
    top = np.hstack([ss.C[:1], ss.D[:1, :k] * inv, ss.D[:1, k:] + ss.D[:1, :k] @ shift[:, None]])
    low = np.hstack([ss.A, ss.B[:, :k] * inv, ss.B[:, k:] + ss.B[:, :k] @ shift[:, None]])
    return np.ascontiguousarray(np.vstack([top, low]))


@dataclass(frozen=True, eq=False)
class StateSpaceModel:
    """A state-space OC model (``wdmd`` or ``delay-dmd``) on standardised inputs.

    Attributes:
        method, params: how it was made (levels/wavelet or delays/lag, rcond, ridge,
            estimator, form: the :class:`InputForm`).
        scaling: the input standardisation (of the inputs in their form).
        ss: the identified model; inputs are the m standardised inputs and the constant 1.
        repaired: number of unstable poles moved inside the unit circle.

    A first-order system y[k+1] = 0.9 y[k] + 0.5 u[k] is recovered and its
    stepper, seeded from the measured past, follows it:

    >>> rng = np.random.default_rng(0)
    >>> u = rng.normal(size=400)
    >>> y = np.zeros(400)
    >>> for k in range(399):
    ...     y[k + 1] = 0.9 * y[k] + 0.5 * u[k]
    >>> traj = Trajectory(y[:300], u[:300, None], start=100)
    >>> m = StateSpaceModel.fit(Method.DELAY_DMD, {"delays": 1}, [traj])
    >>> m.n_states, np.round(m.ss.poles().real, 6)
    (1, array([0.9]))
    >>> rt = m.runtime()
    >>> rt.start(y[:300], u[:300, None])
    >>> pred = [rt.step(u[k:k + 1]) for k in range(300, 400)]
    >>> bool(np.max(np.abs(np.array(pred) - y[300:])) < 1e-9)
    True
    """

    method: Method
    params: dict
    scaling: InputScaling
    ss: StateSpace
    repaired: int = 0
    dmd: LinearDMD = field(init=False, repr=False)  # lifting and seeding, restored from ss

    def __post_init__(self) -> None:
        object.__setattr__(self, "dmd", _dmd(self.method, self.params).restore(self.ss))

    @property
    def n_states(self) -> int:
        return self.ss.n_states

    @classmethod
    def fit(cls, method: Method, params: dict, trajs: Sequence[Trajectory]) -> StateSpaceModel:
        """Fit on the OC's trajectories (the past before each segment warms the lifting)."""
        form = input_form(params)
        trajs = [t.in_form(form) for t in trajs]
        scaling = InputScaling.fit(np.vstack([t.seg_U for t in trajs]))
        dmd = _dmd(method, params)
        need = dmd.memory()
        Ys, Us = [], []
        for t in trajs:
            y, U = lifted_pair(t, scaling, need)
            Ys.append(y)
            Us.append(U)
        ss, moved = stable_fit(dmd, Ys, Us, need)
        return cls(method, dict(params), scaling, ss, moved)

    def predict(self, traj: Trajectory) -> np.ndarray:
        """Free-run prediction over the OC samples of ``traj``, seeded from its past: (K_seg,)."""
        traj = traj.in_form(input_form(self.params))
        U = self.scaling.apply(traj.U)
        if traj.start == 0:
            return self.dmd.simulate(U, history=None)[:, 0]
        hist = (traj.y[:traj.start, None], U[:traj.start])
        return self.dmd.simulate(U[traj.start:], history=hist)[:, 0]

    def runtime(self) -> StateSpaceRuntime:
        return StateSpaceRuntime(self)

    def arrays(self) -> dict[str, np.ndarray]:
        return {**self.scaling.arrays(), "A": self.ss.A, "B": self.ss.B, "C": self.ss.C, "D": self.ss.D}

    @classmethod
    def from_arrays(cls, method: Method, params: dict, arrays: Mapping[str, np.ndarray],
                    repaired: int = 0) -> StateSpaceModel:
        ss = StateSpace(arrays["A"], arrays["B"], arrays["C"], arrays["D"], 1.0 / FS)
        return cls(method, dict(params), InputScaling.from_arrays(arrays), ss, repaired)


class StateSpaceRuntime:
    """Online stepper of a :class:`StateSpaceModel`: ``start`` at the switch, then ``step`` per sample.

    One matrix-vector product per sample: the input scaling is folded into
    G = [[C, D], [A, B]] acting on z = [x; u; 1] (raw inputs u). Memory: z (n + m + 1,).

    x[k+1] = 0.5 x[k] + u[k], y = x, from rest under a unit step:

    >>> ss = StateSpace(np.array([[0.5]]), np.array([[1.0, 0.0]]), np.array([[1.0]]),
    ...                 np.zeros((1, 2)), 1.0 / FS)
    >>> m = StateSpaceModel(Method.DELAY_DMD, {"delays": 1}, InputScaling(np.zeros(1), np.ones(1)), ss)
    >>> rt = m.runtime()
    >>> rt.start(np.zeros(0), np.zeros((0, 1)))
    >>> [rt.step(np.array([1.0])) for _ in range(3)]
    [0.0, 1.0, 1.5]
    """

    def __init__(self, model: StateSpaceModel) -> None:
        self._model = model
        self._G = stepper_matrix(model.ss, model.scaling)
        n, k = model.ss.n_states, model.scaling.mean.size
        self._z = np.zeros(n + k + 1)
        self._z[-1] = 1.0
        self._n = n
        self._inc = input_form(model.params) is InputForm.INCREMENT
        self._ref: np.ndarray | None = None  # the inputs at the switch (increment form)

    def start(self, y_hist: np.ndarray, U_hist: np.ndarray) -> None:
        """Seed from the measured past: y_hist (K1,), U_hist (K1, m) (K1 may be 0: from rest)."""
        self._ref = None
        if len(y_hist) == 0:
            self._z[: self._n] = 0.0
            return
        m = self._model
        U_hist = np.asarray(U_hist, float)
        if self._inc and np.isfinite(U_hist[-1]).all():
            self._ref = U_hist[-1].copy()
        if self._inc:
            U_hist = U_hist - (U_hist[-1] if self._ref is None else self._ref)
        Un = m.scaling.apply(U_hist)
        self._z[: self._n] = m.dmd.initial_state((np.asarray(y_hist, float)[:, None], Un))

    def step(self, u: Sequence[float] | np.ndarray) -> float:
        """Prediction for this sample from its raw inputs u (m,); advances the state."""
        z, n = self._z, self._n
        z[n:-1] = u
        if self._inc:
            if self._ref is None:  # no past: the OC's first sample is the reference
                self._ref = z[n:-1].copy()
            z[n:-1] -= self._ref
        out = self._G @ z
        z[:n] = out[1:]
        return float(out[0])


# -- regression ------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class RegressionModel:
    """A static regression OC model (``lasso``): y = coef . standardised u + intercept.

    Attributes:
        params: how it was made (alpha).
        scaling: the input standardisation.
        coef: (m,) weights on the standardised inputs; intercept: target units.

    >>> u = np.linspace(0.0, 10.0, 200)
    >>> traj = Trajectory(2.0 * u + 1.0, u[:, None], start=0)
    >>> m = RegressionModel.fit(Method.LASSO, {"alpha": 1e-6}, [traj])
    >>> rt = m.runtime()
    >>> rt.start(np.zeros(0), np.zeros((0, 1)))
    >>> round(rt.step(np.array([4.0])), 4), round(float(m.predict(traj)[-1]), 4)
    (9.0, 21.0)
    """

    params: dict
    scaling: InputScaling
    coef: np.ndarray
    intercept: float
    method: ClassVar[Method] = Method.LASSO
    repaired: ClassVar[int] = 0
    n_states: ClassVar[int] = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "coef", _readonly(self.coef))

    @classmethod
    def fit(cls, method: Method, params: dict, trajs: Sequence[Trajectory]) -> RegressionModel:
        """Lasso on the OC samples of ``trajs`` (their past is not used)."""
        from sklearn.exceptions import ConvergenceWarning  # training only: the node starts faster
        from sklearn.linear_model import Lasso

        scaling = InputScaling.fit(np.vstack([t.seg_U for t in trajs]))
        X = np.vstack([scaling.apply(t.seg_U)[:, :-1] for t in trajs])
        y = np.concatenate([t.seg_y for t in trajs])
        with warnings.catch_warnings():  # a small alpha may stop at max_iter: still the CV's pick
            warnings.simplefilter("ignore", ConvergenceWarning)
            reg = Lasso(alpha=float(params["alpha"]), precompute=True, max_iter=5_000, tol=1e-6).fit(X, y)
        return cls(dict(params), scaling, reg.coef_.copy(), float(reg.intercept_))

    def predict(self, traj: Trajectory) -> np.ndarray:
        """Prediction over the OC samples of ``traj`` from their inputs: (K_seg,)."""
        U = self.scaling.apply(traj.U)
        return U[traj.start:, :-1] @ self.coef + self.intercept

    def runtime(self) -> RegressionRuntime:
        return RegressionRuntime(self)

    def arrays(self) -> dict[str, np.ndarray]:
        return {**self.scaling.arrays(), "coef": self.coef, "intercept": np.array([self.intercept])}

    @classmethod
    def from_arrays(cls, method: Method, params: dict, arrays: Mapping[str, np.ndarray],
                    repaired: int = 0) -> RegressionModel:
        return cls(dict(params), InputScaling.from_arrays(arrays), arrays["coef"],
                   float(arrays["intercept"][0]))


class RegressionRuntime:
    """Online stepper of a :class:`RegressionModel`: one dot product per sample, no state.

    The input scaling is folded into the weights w acting on z = [u; 1] (raw inputs u).

    >>> m = RegressionModel({"alpha": 0.1}, InputScaling(np.array([2.0]), np.array([0.5])),
    ...                     coef=np.array([3.0]), intercept=1.0)
    >>> rt = m.runtime()
    >>> rt.step(np.array([2.5]))  # 3 (2.5 - 2) / 0.5 + 1
    4.0
    """

    def __init__(self, model: RegressionModel) -> None:
        inv, shift = model.scaling.folded()
        coef = np.asarray(model.coef, float)
        self._w = np.append(coef * inv, model.intercept + float(shift @ coef))
        self._z = np.ones(inv.size + 1)

    def start(self, y_hist: np.ndarray, U_hist: np.ndarray) -> None:
        """Nothing to seed: a static model ignores the past."""

    def step(self, u: Sequence[float] | np.ndarray) -> float:
        """Prediction for this sample from its raw inputs u (m,)."""
        z = self._z
        z[:-1] = u
        return float(self._w @ z)


# -- characteristic curve --------------------------------------------------------------------
