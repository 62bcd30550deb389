"""A planned profile's prediction against the acceptance limits (the schedule's ``[[limit]]``).

At each sample the limit in force is the node's (``limit_in_force``: by the sample's switch
speed and the OC the node was in). The probability that a sample exceeds it reads the
prediction's interval as a normal: centred on the prediction, its upper end ``hi`` the normal's
upper quantile of the central ``level`` interval (90 %: 1.645 standard deviations above), so
that ``p_exceed`` = P(amplitude > limit) is 0.5 at the prediction and 0.05 at ``hi``. (The upper
end, not the width: the interval's lower end is cut at 0, its upper one at the training runs'
bound, where the amplitude does not go.) A segment's (an OC the plan reaches, the engine in it)
``p_exceed`` is the largest of its samples': the segment's samples are taken as erring
together (one level error, as a run's level moves its whole plateau), not as independent tries.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.special import ndtr, ndtri

from node.contract.schedule import Limit, Schedule, limit_in_force
from node.training.prediction import Prediction

LIMIT_RULE = ("p_exceed: the probability that the amplitude exceeds the limit in force, read from the "
              "prediction's interval as a normal about the prediction with the interval's upper end its "
              "95th percentile (0.05 at the upper end); an OC's p_exceed is its samples' largest (they "
              "err together)")


def plan_limits(given: Schedule | None, model_schedule: Schedule, targets: Sequence[str]
                ) -> tuple[Limit, ...]:
    """The limits a plan is held to: those of the schedule ``given`` as the plan when it has any,
    else the model's schedule's; a limit on none of ``targets`` is a one-line OrdervibError."""
    chosen = given if given is not None and given.limits else model_schedule
    chosen.check_targets(targets)
    return chosen.limits


def limits_along(pred: Prediction, limits: Sequence[Limit]) -> np.ndarray:
    """The limit in force at each sample per target (K, n), the target's unit; NaN: none."""
    out = np.full(pred.predicted.shape, np.nan)
    speed = pred.speed.tolist()
    names = [pred.oc_names[i] if i >= 0 else None for i in pred.oc.tolist()]
    for j, tg in enumerate(pred.targets):
        mine = tuple(lim for lim in limits if lim.target == tg)
        if mine:
            out[:, j] = [math.nan if (v := limit_in_force(mine, s, oc)) is None else v
                         for s, oc in zip(speed, names)]
    return out


def exceed_probability(predicted: np.ndarray, hi: np.ndarray, limit: np.ndarray, level: float) -> np.ndarray:
    """P(amplitude > limit) per sample, the amplitude normal about ``predicted`` with ``hi`` the
    upper end of its central ``level`` interval (none above the prediction: 0 or 1); NaN where
    the limit, the prediction or ``hi`` is NaN.

    >>> p = exceed_probability(np.array([5.0, 5.0, 5.0, 5.0]), np.array([6.0, 6.0, 6.0, 5.0]),
    ...                        np.array([5.0, 6.0, np.nan, 4.0]), 0.9)
    >>> [round(float(x), 3) for x in p[[0, 1, 3]]], bool(np.isnan(p[2]))
    ([0.5, 0.05, 1.0], True)
    """
    z = float(ndtri(0.5 + 0.5 * level))
    sd = (hi - predicted) / z
    with np.errstate(divide="ignore", invalid="ignore"):
        p = np.where(sd > 0, ndtr((predicted - limit) / np.where(sd > 0, sd, 1.0)),
                     (predicted > limit).astype(float))
    bad = ~(np.isfinite(limit) & np.isfinite(predicted) & np.isfinite(hi))
    return np.where(bad, np.nan, p)


@dataclass(frozen=True)
class SegmentRisk:
    """One target in one OC the plan reaches: its predicted peak (mm/s) with the interval at that
    sample, the smallest limit in force there (NaN: none) and ``p_exceed`` (NaN: no limit)."""

    oc: str
    target: str
    samples: int
    peak: float
    lo: float
    hi: float
    limit: float
    p_exceed: float


def segment_risks(pred: Prediction, limit: np.ndarray) -> list[SegmentRisk]:
    """Per OC the plan reaches (in the schedule's order) and target: ``SegmentRisk``; limit: the
    limit in force per sample (``limits_along``)."""
    p = exceed_probability(pred.predicted, pred.hi, limit, pred.level)
    out = []
    for i, name in enumerate(pred.oc_names):
        mine = np.flatnonzero(pred.oc == i)
        if not mine.size:
            continue
        for j, tg in enumerate(pred.targets):
            y = pred.predicted[mine, j]
            peak = lo = hi = math.nan
            if np.isfinite(y).any():
                k = mine[int(np.nanargmax(y))]
                peak, lo, hi = float(pred.predicted[k, j]), float(pred.lo[k, j]), float(pred.hi[k, j])
            lim = limit[mine, j]
            top = float(np.nanmax(p[mine, j])) if np.isfinite(p[mine, j]).any() else math.nan
            out.append(SegmentRisk(name, tg, int(mine.size), peak, lo, hi,
                                   float(np.nanmin(lim)) if np.isfinite(lim).any() else math.nan, top))
    return out
