"""Which class each OC model method is, for training (``fit_oc_model``) and for the bundle
loader (``model_from_arrays``): the single kinds (``node.models.single_kinds``) and the average
of them (``node.models.average``)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from node.models.average import AverageModel
from node.models.ocmodel import Method, OCModel, OCModelKind, Trajectory
from node.models.single_kinds import SINGLE_KINDS

KINDS: dict[Method, OCModelKind] = {**SINGLE_KINDS, Method.AVERAGE: AverageModel}


def fit_oc_model(method: str, params: dict, trajs: Sequence[Trajectory]) -> OCModel:
    """Fit one OC's model of ``method`` on its trajectories."""
    meth = Method(method)
    return KINDS[meth].fit(meth, params, trajs)


def model_from_arrays(method: str, params: dict, arrays: Mapping[str, np.ndarray],
                      repaired: int = 0) -> OCModel:
    """A model as a bundle stored it (``model.arrays()``)."""
    meth = Method(method)
    return KINDS[meth].from_arrays(meth, params, arrays, repaired)
