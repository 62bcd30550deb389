"""The training runs' peaks per segment that the verdict's forecast conditions on
(``node.models.forecast.PeakTable``), measured as the node measures a run: each run stepped
through the node's own ``RunVerdict``, with the limit in force at each sample by the one rule
(``limit_in_force``), the segments by the node's OC detector (``label_runs``)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from node.contract.schedule import Schedule, limit_in_force
from node.models.forecast import PeakTable
from node.runtime.runcurve import hold_last
from node.runtime.verdict import RunVerdict
from node.training.dataset import Labels, label_runs
from node.training.runs import Run


def peak_table(runs: Sequence[Run], schedule: Schedule, target: str,
               labels: Sequence[Labels] | None = None) -> PeakTable:
    """Each run's peak of ``target`` and peak over its limit per segment (``Schedule.segments``);
    labels: each run's labels by model (``label_runs(models=True)``; None: labelled here)."""
    labels = label_runs(list(runs), schedule, models=True) if labels is None else labels
    segments = schedule.segments
    by_model = (*segments, segments[0])  # (the start's model is the first OC's segment)
    limits = schedule.limits_of(target)
    peaks, ratios = [], []
    for run, (codes, _) in zip(runs, labels, strict=True):
        verdict = RunVerdict(target, segments)
        speed = hold_last(np.asarray(run.column(schedule.switch), float)).tolist()
        y = np.asarray(run.column(target), float).tolist()
        for t, code, s, m in zip(run.t.tolist(), codes.tolist(), speed, y):
            oc = by_model[code] if code >= 0 else None
            verdict.step(t, oc, s, m, limit_in_force(limits, s, oc))
        peaks.append(verdict.peaks)  # (never ended: a run that stopped and started again, both parts')
        ratios.append(verdict.ratios)
    shape = (len(peaks), len(segments))
    return PeakTable(segments, np.array(peaks, dtype=float).reshape(shape),
                     np.array(ratios, dtype=float).reshape(shape))
