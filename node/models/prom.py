"""The parametric OC model (``prom``, dissertation section 6.4): one WDMD per training segment
of the OC, each at its run's engine-history parameter value at the switch, interpolated in
pole-residue form (:class:`node.sysid.ParametricROM`) to the current run's value when the OC
starts.

Inputs (``Trajectory.U`` columns, the node's ``inputs`` of the OC): the switch speed, then the
history parameter(s) (``params["param"]``: channels of ``node.runtime.history``, one or
several joined by commas; :func:`param_channels`). The model is driven by the speed in krpm
(``SPEED_SCALING``) and the constant 1; the parameters are read once, at the switch (the last sample before
the OC), and pick the model. Where one is unknown (no past, NaN) the samples' models are
weighted equally. The state is fitted on the last
``params["seed"]`` samples of measured past around the model's equilibrium there.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
from scipy.signal import lfilter

from node.contract import FS
from node.models.ocmodel import InputScaling, Method, Trajectory, lifted_pair, stable_fit, stepper_matrix
from node.sysid import WDMD, ParametricROM, StateSpace
from node.sysid.memo import ContentMemo
from node.sysid.observer import estimate_state

# Matching tolerance: the per-run models of one quasi-static OC share no physical modes (their
# real poles scatter across runs at one level); ``ParametricROM``'s default 0.5 drops every
# mode, so modes are paired by the assignment whatever it costs. (study: docs/tuning.md#match_tol)
MATCH_TOL = 10.0


def _rom(params: Mapping) -> ParametricROM:
    """The ROM of a model's ``params`` (weights, pairs, real, scheme), without a base estimator:
    its library is identified here (``_segment_model``) and handed over (``fit_models``)."""
    return ParametricROM(None, n_pairs=int(params.get("pairs", 0)), n_real=int(params.get("real", 1)),
                         scheme=str(params.get("scheme", "direct")),
                         weights=str(params.get("weights", "regress")), tol=MATCH_TOL, static=True, clip=True,
                         verbose=False,  # a mode without a match drops a CV candidate: no warning
                         # the matcher these models were measured with (docs/parametric.md, Table 6.1)
                         match="assignment", fallback="drop")


def _speed_only(t: Trajectory) -> Trajectory:
    return Trajectory(t.y, t.U[:, :1], t.start, t.z)


# The speed's standardisation, the same for every model: the library's models must share their
# input coordinates (their B and D are interpolated), and a fixed one lets a segment's model be
# fitted once for every cross-validation fold it is in (``_segment_model``).
SPEED_SCALING = InputScaling(np.zeros(1), np.full(1, 1000.0))  # rpm -> krpm
_SEGMENT_MODELS: ContentMemo[StateSpace] = ContentMemo(256)  # a few kB each


def _segment_model(levels: int, rcond: float, t: Trajectory) -> StateSpace:
    """The WDMD of one OC segment (the lifting warmed on its past), memoised on its content:
    leave-one-run-out CV fits the same segment's model in every fold but one."""
    base = WDMD(levels=levels, rcond=rcond, dt=1.0 / FS, seed_window=0)
    need = base.memory()
    y, U = lifted_pair(_speed_only(t), SPEED_SCALING, need)

    def fit() -> StateSpace:
        with np.errstate(all="ignore"):  # an unstable pole's gain would swamp the library's
            return stable_fit(base, [y], [U], need)[0]

    return _SEGMENT_MODELS.get([np.array([levels, rcond, need], float), y, U], fit)


def _free_run(ss: StateSpace, U: np.ndarray, x0: np.ndarray) -> np.ndarray:
    """``ss.simulate(U, x0)[:, 0]``; a diagonal A (real modes only, as the default candidates
    keep) as one first-order recursion per mode in C (scipy's lfilter: the CV runs thousands)."""
    A = ss.A
    if np.count_nonzero(A - np.diag(np.diag(A))):
        return ss.simulate(U, x0)[:, 0]
    BU = U @ ss.B.T
    X = np.empty((U.shape[0] + 1, ss.n_states))
    X[0] = x0
    for i, a in enumerate(np.diag(A)):  # X[k + 1] = a X[k] + BU[k]
        X[1:, i] = lfilter([1.0], [1.0, -a], BU[:, i], zi=[a * x0[i]])[0]
    return (X[:-1] @ ss.C.T + U @ ss.D.T)[:, 0]


def param_channels(params: Mapping) -> list[str]:
    """The history channels a parametric model is parametrised by (its inputs after the speed).

    >>> param_channels({"param": "hist_thermal,hist_energy"})
    ['hist_thermal', 'hist_energy']
    """
    return str(params["param"]).split(",")


def _switch_values(U: np.ndarray, start: int) -> np.ndarray:
    """The parameters at the switch (q,): the inputs after the speed at the last sample before
    ``start`` (NaN: unknown, no past)."""
    return np.asarray(U[start - 1, 1:], float) if start > 0 else np.full(U.shape[1] - 1, math.nan)


@dataclass(frozen=True, eq=False)
class ParametricOCModel:
    """A library of per-segment WDMD models interpolated to the run's history parameter.

    Attributes:
        params: levels (WDMD), param (the history channel(s)), seed (samples of past the state
            is fitted on), and the ROM's weights, pairs, real, scheme.
        scaling: the speed's scaling (one column; ``SPEED_SCALING``, the same for every model).
        rom: the fitted (or restored) :class:`ParametricROM` over the segments.

    Two first-order systems y[k+1] = a y[k] + 0.1 u[k] at parameter 0 (a = 0.80) and 1
    (a = 0.90), and a third at 2 (a = 0.95): the model at 1 is the library's model there.

    >>> rng = np.random.default_rng(1)
    >>> def traj(a, p):
    ...     u = 1000.0 + 50.0 * rng.standard_normal(600)
    ...     y = np.zeros(600)
    ...     for k in range(599):
    ...         y[k + 1] = a * y[k] + 0.1 * (u[k] - 1000.0) / 50.0
    ...     return Trajectory(y, np.column_stack([u, np.full(600, p)]), start=100)
    >>> ts = [traj(0.80, 0.0), traj(0.90, 1.0), traj(0.95, 2.0)]
    >>> m = ParametricOCModel.fit(Method.PROM, {"levels": 1, "param": "hist_thermal",
    ...                           "weights": "linear"}, ts)
    >>> round(float(m.at(1.0).poles()[0].real), 3)
    0.9
    """

    params: dict
    scaling: InputScaling
    rom: ParametricROM = field(repr=False)
    method: ClassVar[Method] = Method.PROM
    repaired: ClassVar[int] = 0

    @property
    def n_states(self) -> int:
        return int(self.rom.poles_.shape[1] + self.rom._n_pairs_kept)

    @classmethod
    def fit(cls, method: Method, params: dict, trajs: Sequence[Trajectory]) -> ParametricOCModel:
        """One WDMD per trajectory (its OC segment, the lifting warmed on its past) at the
        trajectory's parameter value at the switch; the ROM over them (ValueError when the
        values repeat for interpolating weights, or no mode matches)."""
        if len(trajs) < 2:
            raise ValueError("a parametric model needs at least 2 segments")
        values = np.array([_switch_values(t.U, t.start) for t in trajs])
        if not np.isfinite(values).all():
            raise ValueError("a parameter is unknown at some segment's switch")
        rom = _rom(params)
        if rom.weights in ("linear", "lagrange") and np.unique(values, axis=0).shape[0] < len(values):
            raise ValueError("repeated parameter values: no interpolation through them")
        models = [_segment_model(int(params["levels"]), float(params.get("rcond", 1e-8)), t) for t in trajs]
        with np.errstate(all="ignore"):
            rom.fit_models(models, values)
        return cls(dict(params), SPEED_SCALING, rom)

    def at(self, value: float | Sequence[float] | np.ndarray) -> StateSpace:
        """The state space at parameter value(s) (q,) (inputs: standardised speed, 1)."""
        x = np.asarray(value, float).reshape(-1)
        w = self.rom.weights_at(x) if np.isfinite(x).all() else \
            np.full(len(self.rom.params_), 1.0 / len(self.rom.params_))
        return self.rom.at_weights(w).model_

    def seed(self, ss: StateSpace, y_hist: np.ndarray, Un_hist: np.ndarray) -> np.ndarray:
        """State after the measured past y (K1,), standardised inputs (K1, 2): least squares over
        its last ``seed`` samples around the equilibrium of their first input (zero: no past)."""
        n = ss.n_states
        if len(y_hist) == 0:
            return np.zeros(n)
        W = min(int(self.params.get("seed", 10)), len(y_hist))
        x_eq = np.linalg.solve(np.eye(n) - ss.A, ss.B @ Un_hist[-W])
        return estimate_state(ss, np.asarray(y_hist, float)[-W:, None], Un_hist[-W:], x_eq, rcond=1e-4)

    def predict(self, traj: Trajectory) -> np.ndarray:
        """Free run over the OC samples of ``traj`` of the model at its parameter value: (K_seg,)."""
        ss = self.at(_switch_values(traj.U, traj.start))
        Un = self.scaling.apply(traj.U[:, :1])
        x0 = self.seed(ss, traj.y[:traj.start], Un[:traj.start])
        return _free_run(ss, Un[traj.start:], x0)

    def runtime(self) -> ParametricRuntime:
        return ParametricRuntime(self)

    def arrays(self) -> dict[str, np.ndarray]:
        return {**self.scaling.arrays(), **self.rom.to_arrays()}

    @classmethod
    def from_arrays(cls, method: Method, params: dict, arrays: Mapping[str, np.ndarray],
                    repaired: int = 0) -> ParametricOCModel:
        settings = _rom(params).get_params(deep=False)
        del settings["base_estimator"]
        rom = ParametricROM.from_arrays(arrays, **settings)
        return cls(dict(params), InputScaling.from_arrays(arrays), rom)


class ParametricRuntime:
    """Online stepper of a :class:`ParametricOCModel`: ``start`` interpolates the model at the
    parameter's value at the switch and seeds it; ``step`` is one matrix-vector product (the
    speed's scaling folded in; the parameters are not read again). Memory: z (n + 2,)."""

    def __init__(self, model: ParametricOCModel) -> None:
        self._model = model
        self._G = np.zeros((1, 2))
        self._z = np.zeros(2)
        self._z[-1] = 1.0
        self._n = 0

    def start(self, y_hist: np.ndarray, U_hist: np.ndarray) -> None:
        """Seed from the measured past: y_hist (K1,), U_hist (K1, 1 + q) (K1 may be 0)."""
        m = self._model
        U_hist = np.asarray(U_hist, float).reshape(len(y_hist), -1) if len(y_hist) else \
            np.zeros((0, 1 + m.rom.params_.shape[1]))
        ss = m.at(_switch_values(U_hist, len(U_hist)))
        Un = m.scaling.apply(U_hist[:, :1])
        x0 = m.seed(ss, y_hist, Un)
        n = ss.n_states
        self._G = stepper_matrix(ss, m.scaling)
        self._z = np.zeros(n + 2)
        self._z[:n] = x0
        self._z[-1] = 1.0
        self._n = n

    def step(self, u: Sequence[float] | np.ndarray) -> float:
        """Prediction for this sample from its raw inputs u (1 + q,): the speed, then the
        parameters (read at the switch only); advances the state."""
        z, n = self._z, self._n
        z[n] = u[0]
        out = self._G @ z
        z[:n] = out[1:]
        return float(out[0])
