"""Never knowingly worse than the curve: a causal guard on an OC model's prediction.

An OC model is chosen by the training runs' cross-validation; on a new engine it may fit an
OC worse than the plain characteristic curve (the training runs' mean amplitude at the same
switch speed), which a vibration engineer would have used instead. ``CurveGuard`` compares,
within one OC visit and from the samples measured so far only, the model's and the curve's
squared errors: once it has compared ``wait`` samples, each new sample is predicted by the
curve while the model's sum of squared errors so far exceeds ``1 + margin`` times the
curve's, and by the model again when the model's falls below the curve's over ``1 + margin``
(the hysteresis keeps it from switching back and forth at every sample). The decision for a
sample uses the errors up to the one before it: causal, the same live and offline.

Chosen on development engines (``bench generalise``'s dev set) among a
decision once after a few seconds, a blend weighted by the errors and this switch: the switch
with a 5 s wait gained most there, a margin of 0 to 0.5 all alike.

>>> flat = FleetCurve(np.array([0.0, 9000.0]), np.array([1.0, 1.0]))  # 1.0 at every speed
>>> g = CurveGuard(flat, wait=2, margin=0.1)
>>> [g.step(1.0, 1.5, 4000.0)[0] for _ in range(3)]  # the model errs 0.5 a sample, the curve 0
[1.5, 1.5, 1.0]
>>> g.step(1.0, 1.5, 4000.0), g.using_curve
((1.0, True), True)
>>> g.reset(); g.step(1.0, 1.5, 4000.0)  # a new OC visit: the model again
(1.5, False)
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from node.contract import FS
from node.models.baseline import FleetCurve
from node.models.bundle import Bundle, Model, as_model
from node.models.config import RuntimeConfig

CURVE = "@curve"  # a model id's suffix where the node predicted with the characteristic curve


class CurveGuard:
    """Per OC visit: the model's or the curve's prediction, whichever erred less so far.

    Args:
        curve: the characteristic curve (the bundle's).
        wait: samples compared (both errors finite) before the curve may take over (>= 1).
        margin: the hysteresis (>= 0): to the curve beyond ``1 + margin`` times its error,
            back to the model below ``1 / (1 + margin)`` times it.

    Stateful, O(1) memory; ``reset`` at each OC switch.
    """

    __slots__ = ("curve", "wait", "_up", "_down", "_n", "_em", "_ec", "using_curve")

    def __init__(self, curve: FleetCurve, wait: int, margin: float) -> None:
        if wait < 1 or not (margin >= 0 and math.isfinite(margin)):
            raise ValueError(f"a curve guard needs wait >= 1 and a finite margin >= 0, got {wait}, {margin}")
        self.curve = curve.at
        self.wait = int(wait)
        self._up = 1.0 + margin
        self._down = 1.0 / (1.0 + margin)
        self.reset()

    def reset(self) -> None:
        """A new OC visit: nothing compared yet, the model in force."""
        self._n = 0
        self._em = 0.0
        self._ec = 0.0
        self.using_curve = False

    def step(self, measured: float, model: float, speed: float) -> tuple[float, bool]:
        """This sample's prediction and whether it is the curve's (at the switch ``speed``);
        then this sample's errors are added (when the measured value and both predictions are
        finite). A non-finite model prediction is passed through and changes nothing."""
        if model - model != 0.0:
            return model, False
        curve = self.curve(speed)
        use = self.using_curve
        out = curve if use and curve - curve == 0.0 else model
        if measured - measured == 0.0 and curve - curve == 0.0:
            dm, dc = measured - model, measured - curve
            self._em += dm * dm
            self._ec += dc * dc
            self._n += 1
            if self._n >= self.wait:
                if not use and self._em > self._up * self._ec:
                    self.using_curve = True
                elif use and self._em < self._down * self._ec:
                    self.using_curve = False
        return out, use and curve - curve == 0.0


def guard_segment(guard: CurveGuard, measured: np.ndarray, model: np.ndarray,
                  speed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``CurveGuard.step`` over one OC visit, as the node steps it (the guard reset first):
    measured, model, speed (K,) -> the guarded prediction (K,) and where it is the curve's (K,)."""
    guard.reset()
    out = np.empty(len(model))
    used = np.zeros(len(model), dtype=bool)
    for k, (y, p, c) in enumerate(zip(np.asarray(measured, float).tolist(),
                                      np.asarray(model, float).tolist(),
                                      np.asarray(speed, float).tolist())):
        out[k], used[k] = guard.step(y, p, c)
    return out, used


def guard_of(curve: tuple[np.ndarray, np.ndarray] | None, config: RuntimeConfig) -> CurveGuard | None:
    """The guard a bundle's settings ask for: None when off (``guard_wait_s`` 0) or when the
    bundle has no characteristic curve (``Bundle.curve``: speeds, means)."""
    if config.guard_wait_s <= 0 or curve is None:
        return None
    return CurveGuard(FleetCurve(*curve), max(1, round(config.guard_wait_s * FS)), config.guard_margin)


def unguarded(model: Bundle | Model) -> Model:
    """``model`` with the curve guard off in every target: for a prediction that measures
    nothing (``ordervib predict``), where the guard has no errors to compare."""
    m = as_model(model)
    return Model(tuple(dataclasses.replace(b, config=dataclasses.replace(b.config, guard_wait_s=0.0))
                       for b in m.bundles))
