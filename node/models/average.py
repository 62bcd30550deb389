"""The average of an OC's best models (``average``): their mean prediction.

Where an OC's model is a characteristic curve, training also tries the mean of its best
candidates, the CV-best curves and the grid's CV-best model (a WDMD), and keeps the mean when
its CV eps (the members' CV predictions averaged) is lower (``node.training.train``). Models
of different kinds err differently on a new run: the fleet curve by the run's own level, an
anchored curve by its anchor's noise, a vector curve where the phase is noisy, a dynamic
model where its free run drifts; their mean errs less than the best of them (study:
docs/tuning.md#curve_average).

Members may be of any single kind (``node.models.single_kinds``: not an average), predict the
amplitude or the order's 1x vector (a vector curve) and read different inputs: the model's
inputs are their union (``params["inputs"]``), each member reads its own columns; the runtime's
``start`` takes the measured amplitudes and, when a member needs them, the 1x vectors.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import ClassVar, TypeVar

import numpy as np

from node.contract.vector import NAN_VECTOR
from node.models.curve import CurveModel, CurveRuntime
from node.models.ocmodel import Method, OCModel, OCRuntime, Trajectory
from node.models.single_kinds import fit_single_model, single_model_from_arrays


def average_params(members: Sequence[tuple[str, dict, Sequence[str]]]) -> dict:
    """An average's params from its members' (method, params, inputs): the members and the
    union of their inputs (in the order first met), which is the model's input order.

    >>> p = average_params([("curve", {"variant": "fleet"}, ["nB"]), ("wdmd", {"levels": 2}, ["tA", "nB"])])
    >>> p["inputs"], member_label(p)
    (['nB', 'tA'], 'fleet+wdmd')
    """
    inputs: list[str] = []
    for _, _, ins in members:
        inputs += [c for c in ins if c not in inputs]
    return {"members": [{"method": str(Method(m)), "params": dict(p), "inputs": list(ins)}
                        for m, p, ins in members], "inputs": inputs}


def _method(member: Mapping) -> Method:
    return Method(member.get("method", Method.CURVE))


def member_name(member: Mapping) -> str:
    """One member's short name for tables: a curve's variant, else its method."""
    return str(member["params"].get("variant", "fleet")) if _method(member) is Method.CURVE \
        else str(_method(member))


def member_label(params: Mapping) -> str:
    """A short name of an average's members for tables: their ``member_name`` joined by '+'."""
    return "+".join(member_name(m) for m in params.get("members", []))


def predicts_vector(model: object) -> bool:
    """Whether an OC model predicts the order's 1x vector (a vector or influence curve, or an
    average with one among its members): its runtime is seeded with the measured vectors."""
    if isinstance(model, AverageModel):
        return model.on_vector
    return isinstance(model, CurveModel) and model.variant.on_vector


_Pred = TypeVar("_Pred", float, np.ndarray)


def mean_in_order(predictions: Sequence[_Pred]) -> _Pred:
    """(p_0 + p_1 + ...) / k, summed in this order: an average's prediction from its members'
    ((K,) each, or one sample's floats: the stepper's; training's averaged CV pairs use it too:
    the same numbers to the last bit).

    >>> mean_in_order([np.array([1.0, 2.0]), np.array([3.0, 6.0])]), mean_in_order([1.0, 2.0])
    (array([2., 4.]), 1.5)
    """
    total = predictions[0]
    for p in predictions[1:]:
        total = total + p
    return total / len(predictions)


def _columns(params: Mapping) -> list[list[int]]:
    """Each member's columns of the model's inputs."""
    inputs = list(params["inputs"])
    try:
        return [[inputs.index(c) for c in m["inputs"]] for m in params["members"]]
    except ValueError:
        raise ValueError("an average's member reads an input the average does not hold") from None


def _member_traj(t: Trajectory, cols: list[int]) -> Trajectory:
    return Trajectory(t.y, t.U[:, cols], t.start, t.z)


@dataclass(frozen=True, eq=False)
class AverageModel:
    """The mean prediction of several OC models (``average``).

    Attributes:
        params: ``members``, each ``{"method": its kind, "params": its params, "inputs": its
            channels}``, and ``inputs``, their union: the model's input columns
            (``average_params``).
        members: the member models, in order; the prediction is
            (p_0 + p_1 + ... ) / k, summed in this order (the stepper sums alike: the same
            numbers to the last bit).
        repaired: the members' unstable poles moved inside the unit circle.

    Two curves, one 1 too high and one 1 too low, average to the law:

    >>> speed = np.arange(1010.0, 2000.0, 20.0)
    >>> traj = Trajectory(speed / 1000.0, speed[:, None], start=0)
    >>> lo, hi = (Trajectory(speed / 1000.0 + d, speed[:, None], start=0) for d in (-1.0, 1.0))
    >>> a = CurveModel.fit(Method.CURVE, {"variant": "fleet", "bin": 20.0}, [lo])
    >>> b = CurveModel.fit(Method.CURVE, {"variant": "fleet", "bin": 20.0}, [hi])
    >>> m = AverageModel(average_params([("curve", a.params, ["nB"]), ("curve", b.params, ["nB"])]), (a, b))
    >>> rt = m.runtime()
    >>> rt.start(np.zeros(0), np.zeros((0, 1)))
    >>> p = rt.step([1490.0])  # the stepper and predict: the same number to the last bit
    >>> round(p, 12), p == float(m.predict(traj)[24])
    (1.49, True)
    """

    params: dict
    members: tuple[OCModel, ...]
    repaired: int = 0
    method: ClassVar[Method] = Method.AVERAGE
    columns: list[list[int]] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "members", tuple(self.members))
        if len(self.members) != len(self.params.get("members", ())) or not self.members:
            raise ValueError("an average needs its members' models, one per member")
        if any(isinstance(m, AverageModel) for m in self.members):
            raise ValueError("an average's member cannot be an average")
        object.__setattr__(self, "columns", _columns(self.params))

    @property
    def n_states(self) -> int:
        return sum(m.n_states for m in self.members)

    @classmethod
    def fit(cls, method: Method, params: dict, trajs: Sequence[Trajectory]) -> AverageModel:
        """Each member fitted on the trajectories' columns of its inputs."""
        cols = _columns(params)
        members = tuple(fit_single_model(_method(m), dict(m["params"]), [_member_traj(t, c) for t in trajs])
                        for m, c in zip(params["members"], cols))
        return cls(dict(params), members, sum(m.repaired for m in members))

    def predict(self, traj: Trajectory) -> np.ndarray:
        """The members' predictions over the OC samples of ``traj``, averaged: (K_seg,)."""
        return mean_in_order([m.predict(_member_traj(traj, c)) for m, c in zip(self.members, self.columns)])

    @property
    def on_vector(self) -> bool:
        """Whether a member predicts the 1x vector (its runtime's ``start`` then needs them)."""
        return any(predicts_vector(m) for m in self.members)

    def runtime(self) -> AverageRuntime:
        return AverageRuntime(self)

    def arrays(self) -> dict[str, np.ndarray]:
        return {f"m{i}/{k}": v for i, m in enumerate(self.members) for k, v in m.arrays().items()}

    @classmethod
    def from_arrays(cls, method: Method, params: dict, arrays: Mapping[str, np.ndarray],
                    repaired: int = 0) -> AverageModel:
        members = []
        for i, m in enumerate(params["members"]):
            mine = {k.split("/", 1)[1]: v for k, v in arrays.items() if k.split("/", 1)[0] == f"m{i}"}
            members.append(single_model_from_arrays(_method(m), dict(m["params"]), mine))
        return cls(dict(params), tuple(members), repaired)


class AverageRuntime:
    """Online stepper of an :class:`AverageModel`: each member's stepper, averaged.

    ``start(y_hist, U_hist, z_hist)``: the measured amplitudes (K1,), the inputs (K1, m) and,
    for members of the 1x vector, the measured vectors (K1,) complex (None: unknown, those
    members start without their anchor, as in training without the phase). ``vector``: the
    predicted 1x vector, the predicted amplitude in the direction of the vector members' mean
    vector (NaN without such members).
    """

    def __init__(self, model: AverageModel) -> None:
        self._rts: list[OCRuntime] = [m.runtime() for m in model.members]
        self._cols = model.columns
        self._vec = [predicts_vector(m) for m in model.members]
        self._vec_rts = [rt for rt, v in zip(self._rts, self._vec) if v and isinstance(rt, CurveRuntime)]
        self.vector: complex = NAN_VECTOR

    def start(self, y_hist: np.ndarray, U_hist: np.ndarray, z_hist: np.ndarray | None = None) -> None:
        """Seed every member from the measured past (see the class)."""
        U_hist = np.asarray(U_hist, float)
        if z_hist is None:
            z_hist = np.full(len(y_hist), NAN_VECTOR)
        for rt, cols, vec in zip(self._rts, self._cols, self._vec):
            rt.start(z_hist if vec else y_hist, U_hist[:, cols])

    def step(self, u: Sequence[float] | np.ndarray) -> float:
        """The members' mean prediction for this sample from its raw inputs u (m,)."""
        pred = mean_in_order([rt.step([u[c] for c in cols]) for rt, cols in zip(self._rts, self._cols)])
        self.vector = NAN_VECTOR
        if self._vec_rts:
            direction = sum((rt.vector for rt in self._vec_rts), 0j)
            if direction == direction and direction != 0 and math.isfinite(pred):
                self.vector = pred * direction / abs(direction)
        return pred
