"""One OC's model: the identified dynamics plus the input scaling.

Three kinds, one class each, behind the small protocol :class:`OCModel`:

* :class:`StateSpaceModel` (``wdmd``, ``delay-dmd``): seeded from the measured
  past at the OC switch, then free-running across the OC;
* :class:`RegressionModel` (``lasso``): a static regression, eq. 3.26-3.27;
* :class:`CurveModel` (``curve``): the OC's characteristic curve (the training
  runs' mean target per speed bin, rising, falling and steady speed apart), or
  the derived ``run_curve`` input itself: the baseline every other kind must beat.

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

import bisect
import cmath
import math
import warnings
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import ClassVar, Protocol

import numpy as np

from node.contract import FS
from node.models.baseline import bin_sums
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


NAN_VECTOR = complex(math.nan, math.nan)  # the 1x vector of a sample without amplitude or phase


def order_vector(amplitude: float, phase_deg: float) -> complex:
    """An order's 1x vector from its amplitude and phase lag (degrees): A exp(-j phase); NaN if either is.

    >>> order_vector(2.0, 90.0)
    (1.2246467991473532e-16-2j)
    """
    if not math.isfinite(phase_deg):  # (math.cos raises on inf; the payload rule lets none through)
        return NAN_VECTOR
    rad = math.radians(phase_deg)
    return amplitude * complex(math.cos(rad), -math.sin(rad))


def lag_degrees(v: complex) -> float:
    """The phase lag (degrees, in [-180, 180)) of a 1x vector A exp(-j phase); NaN for NaN or 0."""
    if not (cmath.isfinite(v) and v != 0):
        return math.nan
    lag = -math.degrees(cmath.phase(v))
    return lag - 360.0 if lag >= 180.0 else lag


def order_vectors(amplitude: np.ndarray, phase_deg: np.ndarray) -> np.ndarray:
    """(K,) complex 1x vectors A exp(-j phase) (the phase a lag: ``Trajectory.z``); NaN where either is.

    >>> order_vectors(np.array([2.0, 1.0]), np.array([90.0, np.nan])).round(12)
    array([ 0. -2.j, nan+nanj])
    """
    rad = np.radians(phase_deg)
    out: np.ndarray = amplitude * (np.cos(rad) - 1j * np.sin(rad))
    return np.where(np.isfinite(out), out, complex(np.nan, np.nan))


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
class Variant(StrEnum):
    FLEET = "fleet"  # the training runs' characteristic curve of this OC; input: the switch speed
    RUN = "run"  # the derived run_curve input itself (node.runtime.runcurve); input: run_curve
    ANCHORED = "anchored"  # the fleet curve moved to the level this run had at the switch
    VECTOR = "vector"  # anchored, on the order's 1x vector (its phase recorded): |vector| predicted
    INFLUENCE = "influence"  # the 1x vector from its value at the switch by per-speed influence coefficients

    @property
    def on_vector(self) -> bool:
        """Whether the variant predicts the order's 1x vector (needs its phase)."""
        return self in (Variant.VECTOR, Variant.INFLUENCE)

    @property
    def anchored(self) -> bool:
        """Whether the variant is moved by the run's measured level (or vector) at the switch."""
        return self in (Variant.ANCHORED, Variant.VECTOR, Variant.INFLUENCE)


STEADY, RISING, FALLING = 0, 1, 2  # the speed's recent change: the rows of CurveModel.means
GAINS = 3  # an influence curve's runtime row of gains


def direction_codes(hist: np.ndarray, speed: np.ndarray, window: int, deadband: float) -> np.ndarray:
    """Each sample's direction code (K,) as :class:`CurveRuntime` finds it, vectorised (for fitting).

    The change is speed[k] - speed[k - window] (the oldest of the last ``window`` finite samples,
    ``hist`` (K1,) before ``speed`` (K,) included); beyond +deadband RISING, below -deadband
    FALLING, else STEADY (also without any past, or with window 0). NaN speeds are skipped.

    >>> direction_codes(np.array([100.0]), np.array([150.0, 140.0, 110.0, 110.0]), 2, 20.0)
    array([1, 1, 2, 2])
    """
    full = np.concatenate([np.asarray(hist, float), np.asarray(speed, float)])
    keep = np.isfinite(full)
    out = np.zeros(len(speed), dtype=np.int64)
    if window <= 0:
        return out
    n_hist = int(keep[:len(hist)].sum())
    vals = full[keep]
    pos = np.arange(n_hist, vals.size)  # the finite samples of ``speed`` in ``vals``
    ref = vals[np.maximum(pos - window, 0)]
    change = np.where(pos > 0, vals[pos] - ref, 0.0)
    codes = np.where(change > deadband, RISING, np.where(change < -deadband, FALLING, STEADY))
    out[keep[len(hist):]] = codes
    return out


def _binned_means(speed: np.ndarray, y: np.ndarray, code: np.ndarray, width: float,
                  min_count: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Bin centres (B,) and the mean target per bin and direction (3, B) (every sample's mean
    where a direction has fewer than ``min_count`` samples); complex y: complex means."""
    if np.iscomplexobj(y):
        ok = np.isfinite(y)
        centres, re = _binned_means(speed[ok], y.real[ok], code[ok], width, min_count)
        return centres, re + 1j * _binned_means(speed[ok], y.imag[ok], code[ok], width, min_count)[1]
    ok = np.isfinite(speed) & np.isfinite(y)
    if not ok.any():
        raise ValueError("no finite (speed, target) pairs to fit a curve")
    bins, sums, counts = bin_sums(speed[ok], y[ok], width)
    means = np.tile(sums / counts, (3, 1))
    for c in (STEADY, RISING, FALLING):
        mine = ok & (code == c)
        if mine.any():
            b, sm, n = bin_sums(speed[mine], y[mine], width)
            enough = n >= min_count
            means[c, np.searchsorted(bins, b[enough])] = sm[enough] / n[enough]
    return (bins + 0.5) * width, means


@dataclass(frozen=True, eq=False)
class CurveModel:
    """A characteristic-curve OC model (``curve``): no dynamics, a lookup of the speed.

    Attributes:
        params: variant (``Variant``: "fleet", "run", "anchored", "vector" or "influence"),
            and but for run: bin (rpm), window (samples the speed's change is taken over; 0:
            one curve; influence: one curve whatever it), deadband (rpm over the window),
            min_count (a direction's own mean in a bin needs this many samples, else the
            bin's mean of every sample; default 1), and for the anchored ones: anchor
            (samples before the switch whose mean level, or 1x vector, anchors the curve);
            influence: ridge.
        centres: (B,) the speed bins' centres, rpm (empty for run).
        means: (3, B) the mean target per bin when the speed is steady, rising, falling
            (rows STEADY, RISING, FALLING); a bin without samples of a direction holds the
            mean of every sample in it.
        weights: anchored only, (2,): (w_mul, w_add). With c the curve at the speed, y_sw and
            c_sw the measured mean and the steady curve's mean over the ``anchor`` samples
            before the switch, the prediction is
            c + w_mul c (y_sw / c_sw - 1) + w_add (y_sw - c_sw): the curve scaled and shifted
            towards this run's level (a new run's imbalance and bow move its level, its
            curve keeps its shape). The weights are least squares over the training runs.
            vector: the same on the order's 1x vector (``Trajectory.z``; means complex, y_sw
            and c_sw complex, the weights real), the predicted amplitude the modulus: a run's
            own imbalance and bow turn the vector, which the amplitude alone cannot tell
            from a change of level.
        gains: influence only, (B,) complex: the influence coefficients g per bin. With z_sw
            the measured 1x vector over the ``anchor`` samples before the switch and
            ``anchor_mean`` its mean over the training runs, the predicted vector at speed v is
            b(v) + g(v) (z_sw - anchor_mean), b the ``means`` (the training runs' mean vector):
            a linear rotor's response to the run's own unbalance u is H(v) u, so the vector at
            any speed is an affine function of the vector at the switch, the ratio H(v) / H(v_sw)
            being what trim balancing calls an influence coefficient. b and g are least squares
            per bin over every training sample (with its run's z_sw), g shrunk by ``ridge``
            (relative to the spread of the runs' z_sw; default 1e-3) where the runs' anchors
            cannot tell it.
        anchor_mean: influence only, the training runs' mean z_sw (complex).

    A law that differs on the way up and down is recovered exactly:

    >>> up = np.arange(1002.5, 2000.0, 5.0)  # the bins' centres
    >>> speed = np.concatenate([up, up[::-1]])
    >>> law = np.where(np.diff(speed, prepend=speed[0]) >= 0, speed / 1000.0, 3.0)
    >>> traj = Trajectory(law, speed[:, None], start=0)
    >>> m = CurveModel.fit(Method.CURVE, {"variant": "fleet", "bin": 5.0, "window": 1,
    ...                                   "deadband": 1.0}, [traj])
    >>> rt = m.runtime()
    >>> rt.start(np.array([1.0]), np.array([[1497.5]]))
    >>> rt.step([1502.5]), rt.step([1497.5])
    (1.5025, 3.0)

    Runs whose level is the curve's times a run factor are followed from their switch:

    >>> speed = np.concatenate([np.full(50, 1010.0), np.arange(1010.0, 3000.0, 20.0)])  # bin centres
    >>> trajs = [Trajectory(f * speed / 1000.0, speed[:, None], start=50) for f in (1.0, 2.0, 3.0)]
    >>> m = CurveModel.fit(Method.CURVE, {"variant": "anchored", "bin": 20.0, "anchor": 10}, trajs)
    >>> np.round(m.weights, 6) + 0.0
    array([1., 0.])
    >>> new = Trajectory(2.5 * speed / 1000.0, speed[:, None], start=50)
    >>> round(float(m.predict(new)[-1]), 6)  # the fleet curve says 2 x 2.99 at 2990 rpm
    7.475
    """

    params: dict
    centres: np.ndarray
    means: np.ndarray
    weights: np.ndarray = field(default_factory=lambda: np.zeros(2))
    gains: np.ndarray = field(default_factory=lambda: np.zeros(0, complex))
    anchor_mean: complex = 0j
    method: ClassVar[Method] = Method.CURVE
    repaired: ClassVar[int] = 0
    n_states: ClassVar[int] = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "centres", _readonly(self.centres))
        kind = complex if self.variant.on_vector else float
        object.__setattr__(self, "means", _readonly(np.reshape(self.means, (3, -1)), kind))
        object.__setattr__(self, "weights", _readonly(np.reshape(self.weights, (2,))))
        object.__setattr__(self, "gains", _readonly(np.reshape(self.gains, (-1,)), complex))
        object.__setattr__(self, "anchor_mean", complex(self.anchor_mean))

    @property
    def variant(self) -> Variant:
        return Variant(self.params.get("variant", Variant.FLEET))

    @classmethod
    def fit(cls, method: Method, params: dict, trajs: Sequence[Trajectory]) -> CurveModel:
        """The binned mean of the OC samples' target against their one input (the speed);
        anchored: of every sample with its past (so the curve knows the speed at the switch),
        then the anchoring weights by least squares over the OC samples."""
        if any(t.U.shape[1] != 1 for t in trajs):
            raise ValueError("a curve model takes exactly one input")
        variant = Variant(params.get("variant", Variant.FLEET))
        if variant is Variant.RUN:
            return cls(dict(params), np.zeros(0), np.zeros((3, 0)))
        width, window = float(params.get("bin", 25.0)), int(params.get("window", 0))
        deadband = float(params.get("deadband", 0.0))
        vector = variant.on_vector
        if vector and any(t.z is None for t in trajs):
            raise ValueError("a vector curve needs the target's phase")
        if variant is Variant.INFLUENCE:
            return cls._fit_influence(params, trajs)
        if variant.anchored:  # whole trajectories: the switch is in the past
            speed = np.concatenate([t.U[:, 0] for t in trajs])
            y = np.concatenate([_levels(t, vector) for t in trajs])
            code = np.concatenate([direction_codes(t.U[:0, 0], t.U[:, 0], window, deadband) for t in trajs])
        else:
            speed = np.concatenate([t.seg_U[:, 0] for t in trajs])
            y = np.concatenate([t.seg_y for t in trajs])
            code = np.concatenate([direction_codes(t.U[:t.start, 0][-window:] if window else t.U[:0, 0],
                                                   t.seg_U[:, 0], window, deadband) for t in trajs])
        centres, means = _binned_means(speed, y, code, width, int(params.get("min_count", 1)))
        plain = cls(dict(params), centres, means)
        if not variant.anchored:
            return plain
        rows, targets = [], []
        for t in trajs:
            rt = plain.runtime()
            level = _levels(t, vector)
            rt.start(level[:t.start], t.U[:t.start])
            c = rt.speeds_ahead(t.seg_U[:, 0])
            c = c if vector else c.real
            if rt.anchor is None:
                continue
            y_sw, c_sw = rt.anchor
            rows.append(np.column_stack([c * (y_sw / c_sw - 1.0), np.full(c.size, y_sw - c_sw)]))
            targets.append(level[t.start:] - c)
        weights = np.zeros(2)
        if rows:
            X, r = np.vstack(rows), np.concatenate(targets)
            if vector:  # real weights: both components of the complex residual
                X, r = np.vstack([X.real, X.imag]), np.concatenate([r.real, r.imag])
            ok = np.isfinite(r) & np.isfinite(X).all(axis=1)
            if ok.sum() > 2:
                weights = np.linalg.lstsq(X[ok], r[ok], rcond=None)[0]
        return cls(dict(params), centres, means, weights)

    @classmethod
    def _fit_influence(cls, params: dict, trajs: Sequence[Trajectory]) -> CurveModel:
        """b and g per speed bin by least squares over every sample of the trajectories (with
        their past) against its run's vector at the switch (see the class's ``gains``)."""
        width, ridge = float(params.get("bin", 25.0)), float(params.get("ridge", 1e-3))
        speeds, zs, anchors = [], [], []
        for t in trajs:
            rt = cls(dict(params), np.zeros(1), np.zeros((3, 1)), gains=np.zeros(1)).runtime()
            rt.start(_levels(t, True)[:t.start], t.U[:t.start])
            ok = np.isfinite(t.U[:, 0]) & np.isfinite(_levels(t, True))
            speeds.append(t.U[ok, 0])
            zs.append(_levels(t, True)[ok])
            anchors.append(np.full(int(ok.sum()), np.nan if rt.anchor is None else rt.anchor[0]))
        v, z, a = np.concatenate(speeds), np.concatenate(zs), np.concatenate(anchors)
        if not v.size:
            raise ValueError("no finite (speed, 1x vector) pairs to fit a curve")
        known = np.isfinite(a)
        if known.any():  # only runs with their vector at the switch tell the gains
            v, z, a = v[known], z[known], a[known]
            a_mean = complex(np.mean(a))
        else:  # none: the plain mean vector per bin (as a node without the anchor predicts)
            a, a_mean = np.zeros(v.size, complex), 0j
        x = a - a_mean
        bins, inv = np.unique(np.floor(v / width).astype(np.int64), return_inverse=True)
        n = np.bincount(inv).astype(float)

        def bin_mean(w: np.ndarray) -> np.ndarray:
            return (np.bincount(inv, w.real) + 1j * np.bincount(inv, w.imag)) / n

        xm, zm = bin_mean(x), bin_mean(z)
        dx, dz = x - xm[inv], z - zm[inv]
        sxx = np.bincount(inv, np.abs(dx) ** 2)
        sxz = bin_mean(np.conj(dx) * dz) * n
        g = sxz / (sxx + ridge * n * float(np.mean(np.abs(x) ** 2)) + 1e-300)  # 0 where x is 0
        b = zm - g * xm  # the mean vector at the runs' mean anchor
        return cls(dict(params), (bins + 0.5) * width, np.tile(b, (3, 1)), gains=g, anchor_mean=a_mean)

    def predict(self, traj: Trajectory) -> np.ndarray:
        """Prediction over the OC samples of ``traj``, by the node's stepper vectorised
        (``CurveRuntime.speeds_ahead``: the same numbers to the last bit): (K_seg,)."""
        if self.variant is Variant.RUN:
            return np.array(traj.seg_U[:, 0], dtype=float)
        rt = self.runtime()
        rt.start(_levels(traj, self.variant.on_vector)[:traj.start], traj.U[:traj.start])
        pred = rt.speeds_ahead(traj.seg_U[:, 0])
        # the modulus as Python's abs() takes it (numpy's own may differ in the last bit)
        return np.hypot(pred.real, pred.imag) if self.variant.on_vector else pred.real

    def runtime(self) -> CurveRuntime:
        return CurveRuntime(self)

    def arrays(self) -> dict[str, np.ndarray]:
        out = {"centres": self.centres, "means": self.means.real}
        if self.variant.on_vector:
            out["means_im"] = self.means.imag
        if self.variant in (Variant.ANCHORED, Variant.VECTOR):
            out["weights"] = self.weights
        if self.variant is Variant.INFLUENCE:
            out["gains"], out["gains_im"] = self.gains.real, self.gains.imag
            out["anchor_mean"] = np.array([self.anchor_mean.real, self.anchor_mean.imag])
        return out

    @classmethod
    def from_arrays(cls, method: Method, params: dict, arrays: Mapping[str, np.ndarray],
                    repaired: int = 0) -> CurveModel:
        means = arrays["means"] + 1j * arrays["means_im"] if "means_im" in arrays else arrays["means"]
        gains = arrays["gains"] + 1j * arrays["gains_im"] if "gains" in arrays else np.zeros(0, complex)
        a_mean = complex(*arrays["anchor_mean"]) if "anchor_mean" in arrays else 0j
        return cls(dict(params), arrays["centres"], means,
                   arrays["weights"] if "weights" in arrays else np.zeros(2), gains, a_mean)


def _levels(traj: Trajectory, vector: bool) -> np.ndarray:
    """What a curve is fitted to and anchored on: the 1x vectors (K,) complex, or the target (K,)."""
    if not vector:
        return traj.y
    if traj.z is None:  # no phase recorded: as the node without it, no anchor
        return np.full(traj.y.shape, complex(np.nan, np.nan))
    return traj.z


class CurveRuntime:
    """Online stepper of a :class:`CurveModel`: a bin lookup per sample.

    Memory: the last ``window`` speeds (the direction of the speed's recent change), and
    for an anchored curve the run's level at the switch (``anchor``: (y_sw, c_sw) or None);
    a vector curve's are complex, ``start`` takes the 1x vectors as its measured past, and
    ``step`` returns the predicted amplitude, the predicted vector left in ``vector``.

    >>> m = CurveModel({"variant": "fleet", "window": 0}, np.array([0.0, 100.0]),
    ...                np.tile([0.0, 10.0], (3, 1)))
    >>> rt = m.runtime()
    >>> rt.start(np.zeros(0), np.zeros((0, 1)))
    >>> rt.step([25.0]), rt.step([500.0])
    (2.5, 10.0)
    """

    def __init__(self, model: CurveModel) -> None:
        self._run = model.variant is Variant.RUN
        self._vector = model.variant.on_vector
        self._anchored = model.variant.anchored
        self._influence = model.variant is Variant.INFLUENCE
        self._anchor_mean = model.anchor_mean
        self._anchor_n = int(model.params.get("anchor", FS))
        self._w_mul, self._w_add = (float(w) for w in model.weights)
        self.anchor: tuple[complex, complex] | None = None
        self._shift: complex = 0.0
        self._gain: complex = 0.0
        self.vector: complex = math.nan  # the last predicted 1x vector (vector curves)
        self._xs = [float(x) for x in model.centres]
        self._rows: list[list[complex]] = [row.tolist() for row in model.means]
        if self._influence:  # the gains, looked up as a fourth row (GAINS)
            self._rows.append(model.gains.tolist())
        self._slopes = [[(r[i + 1] - r[i]) / (self._xs[i + 1] - self._xs[i]) for i in range(len(r) - 1)]
                        for r in self._rows]
        # the same tables as arrays, for the vectorised lookups (speeds_ahead, the anchor)
        self._xa = np.array(self._xs)
        self._ra = np.array(self._rows, complex)
        self._sa = np.array(self._slopes, complex).reshape(len(self._rows), -1)
        window = int(model.params.get("window", 0))
        self._deadband = float(model.params.get("deadband", 0.0))
        self._past: deque[float] | None = deque(maxlen=window) if window > 0 else None

    def start(self, y_hist: np.ndarray, U_hist: np.ndarray) -> None:
        """Seed the recent speeds (and the anchor) from the measured past y_hist (K1,) (the 1x
        vectors, complex, for a vector curve), U_hist (K1, 1) (K1 may be 0)."""
        if self._anchored:
            levels = np.asarray(y_hist, complex if self._vector else float)
            self._set_anchor(levels, np.asarray(U_hist, float))
        if self._past is None:
            return
        self._past.clear()
        n = self._past.maxlen or 0
        for x in np.asarray(U_hist, float)[:, 0][-n:].tolist() if len(U_hist) else []:
            if x == x:
                self._past.append(x)

    def _set_anchor(self, y_hist: np.ndarray, U_hist: np.ndarray) -> None:
        """The run's level just before the switch against the steady curve's there."""
        self.anchor, self._shift, self._gain = None, 0.0, 0.0
        n = self._anchor_n
        if n <= 0 or len(y_hist) < n:
            return
        y, x = y_hist[-n:], U_hist[-n:, 0]
        ok = np.isfinite(y) & np.isfinite(x)
        if not ok.any():
            return
        y_sw = _mean(y[ok].tolist())
        if self._influence:
            if cmath.isfinite(y_sw):
                self.anchor = (y_sw, self._anchor_mean)
                self._shift = y_sw - self._anchor_mean
            return
        c = self._lookups(x[ok], STEADY)  # each sample's _lookup, at once
        c_sw = _mean(c.tolist() if self._vector else c.real.tolist())
        if not (cmath.isfinite(y_sw) and cmath.isfinite(c_sw)) or c_sw == 0.0:
            return
        self.anchor = (y_sw, c_sw)
        self._gain = self._w_mul * (y_sw / c_sw - 1.0)
        self._shift = self._w_add * (y_sw - c_sw)

    def step(self, u: Sequence[float] | np.ndarray) -> float:
        """Prediction for this sample from its raw input u (1,): the speed, or run_curve itself."""
        if self._run:
            return float(u[0])
        if self._vector:
            self.vector = self.step_speed(float(u[0]))
            return abs(self.vector)
        return self.step_speed(float(u[0])).real

    def speeds_ahead(self, speeds: np.ndarray) -> np.ndarray:
        """``step_speed`` over speeds (K,) at once, vectorised for training: the same numbers to
        the last bit (the same real operations in the same order: numpy's own complex product
        and modulus may round otherwise); complex (K,). The stepper's recent speeds are left
        as ``start`` set them."""
        x = np.asarray(speeds, float)
        codes = np.zeros(x.size, dtype=np.int64)
        if self._past is not None:
            codes = direction_codes(np.array(self._past, float), x, self._past.maxlen or 0, self._deadband)
        xs, rows, slopes = self._xa, self._ra, self._sa
        i = np.searchsorted(xs, x, side="right")
        j = np.clip(i - 1, 0, max(xs.size - 2, 0))
        c = np.empty(x.size, complex)
        for code in np.unique(codes):
            m = codes == code
            c[m] = _interp(rows[code], slopes[code], xs, i[m], j[m], x[m])
        if self.anchor is not None:
            if self._influence:
                c = c + _cmul(_interp(rows[GAINS], slopes[GAINS], xs, i, j, x), complex(self._shift))
            elif self._vector:
                c = c + _cmul(c, complex(self._gain)) + complex(self._shift)
            else:  # real: as Python floats
                c = (c.real + float(self._gain.real) * c.real + float(self._shift.real)).astype(complex)
        c[~np.isfinite(x)] = complex(math.nan, 0.0)
        return c

    def _lookups(self, x: np.ndarray, code: int) -> np.ndarray:
        """``_lookup`` of each speed x (K,) (finite) on row ``code``: complex (K,), the same
        numbers to the last bit (``_interp``)."""
        i = np.searchsorted(self._xa, x, side="right")
        j = np.clip(i - 1, 0, max(self._xa.size - 2, 0))
        return _interp(self._ra[code], self._sa[code], self._xa, i, j, x)

    def _lookup(self, x: float, code: int) -> complex:
        xs, ys = self._xs, self._rows[code]
        i = bisect.bisect_right(xs, x)
        if i == 0:
            return ys[0]
        if i == len(xs):
            return ys[-1]
        return ys[i - 1] + self._slopes[code][i - 1] * (x - xs[i - 1])

    def step_speed(self, x: float) -> complex:
        """Prediction at speed x (rpm) (NaN: NaN, and the recent speeds are kept); complex for a
        vector curve, else real."""
        if x != x:
            return math.nan
        code = STEADY
        past = self._past
        if past is not None:
            if past:
                change = x - past[0]
                code = RISING if change > self._deadband else FALLING if change < -self._deadband else STEADY
            past.append(x)
        c = self._lookup(x, code)
        if self.anchor is None:
            return c
        if self._influence:
            return c + self._lookup(x, GAINS) * self._shift
        return c + self._gain * c + self._shift


def _cmul(a: np.ndarray, b: complex) -> np.ndarray:
    """a * b (K,) complex as CPython multiplies complex numbers (``_Py_c_prod``)."""
    return (a.real * b.real - a.imag * b.imag) + 1j * (a.real * b.imag + a.imag * b.real)


def _interp(ys: np.ndarray, slopes: np.ndarray, xs: np.ndarray, i: np.ndarray, j: np.ndarray,
            x: np.ndarray) -> np.ndarray:
    """``CurveRuntime._lookup`` vectorised (K,): i = bisect_right(xs, x), j = i - 1 clipped to a
    segment; a complex slope times a real offset as CPython does it."""
    if slopes.size == 0:
        return np.full(x.size, ys[0], complex)
    sl, dx = slopes[j], x - xs[j]
    out = ys[j] + ((sl.real * dx - sl.imag * 0.0) + 1j * (sl.real * 0.0 + sl.imag * dx))
    out = np.where(i == 0, ys[0], out)
    return np.where(i == xs.size, ys[-1], out)


def _mean(values: list[complex]) -> complex:
    """Exact-sum mean of real or complex values (real stays real)."""
    re = math.fsum(v.real for v in values) / len(values)
    if all(isinstance(v, float) for v in values):
        return re
    return complex(re, math.fsum(v.imag for v in values) / len(values))
