"""Which class each single OC model method is (every method but ``average``), for the members
of an average (``node.models.average``) and for ``node.models.kinds``, which adds the average."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from node.models.curve import CurveModel
from node.models.ocmodel import (
    Method,
    OCModel,
    OCModelKind,
    RegressionModel,
    StateSpaceModel,
    Trajectory,
)
from node.models.prom import ParametricOCModel

SINGLE_KINDS: dict[Method, OCModelKind] = {
    Method.WDMD: StateSpaceModel, Method.DELAY_DMD: StateSpaceModel, Method.LASSO: RegressionModel,
    Method.CURVE: CurveModel, Method.PROM: ParametricOCModel,
}


def _single(method: str) -> tuple[Method, OCModelKind]:
    """The method and its class; ValueError for an average (an average's member cannot be one)."""
    meth = Method(method)
    if meth is Method.AVERAGE:
        raise ValueError("an average's member cannot be an average")
    return meth, SINGLE_KINDS[meth]


def fit_single_model(method: str, params: dict, trajs: Sequence[Trajectory]) -> OCModel:
    """Fit one single model of ``method`` on its trajectories."""
    meth, kind = _single(method)
    return kind.fit(meth, params, trajs)


def single_model_from_arrays(method: str, params: dict, arrays: Mapping[str, np.ndarray],
                             repaired: int = 0) -> OCModel:
    """A single model as a bundle stored it (``model.arrays()``)."""
    meth, kind = _single(method)
    return kind.from_arrays(meth, params, arrays, repaired)
