"""From recorded runs to per-OC training segments (eq. 5.22: an OC's trajectories
are its segments in every training run).

A segment is the samples of one run that the causal OC detector assigns to one
OC (its transition, then its plateau; the first OC's transition from light-off)
or to the rundown (index ``Schedule.rundown``), plus the index where it starts, so
the samples before it serve as the history that seeds the model.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from node.contract import Phase, phase_channel
from node.contract.errors import OrdervibError
from node.contract.schedule import Schedule
from node.contract.vector import order_vectors
from node.models.config import RuntimeConfig
from node.runtime.history import add_history
from node.runtime.ocdetect import OCDetector
from node.runtime.runcurve import hold_last
from node.training.runs import Run


@dataclass(frozen=True)
class Segment:
    """Samples [start, stop) of run ``run`` belong to OC ``oc`` (schedule index; the rundown's,
    ``Schedule.rundown``; with labels by model, the start's, ``Schedule.start``)."""

    run: int
    oc: int
    start: int
    stop: int
    steady_start: int  # first steady sample (== stop if the plateau was never reached)

    @property
    def length(self) -> int:
        return self.stop - self.start


def fill_gaps(X: np.ndarray) -> np.ndarray:
    """Hold the last finite value of each column over NaN (the first finite value before it).

    X (K, c) -> (K, c); a column with no finite value stays NaN.
    """
    out = np.array(X, dtype=float, copy=True)
    for j in range(out.shape[1]):
        col = out[:, j]
        ok = np.isfinite(col)
        if ok.all() or not ok.any():
            continue
        idx = np.where(ok, np.arange(col.size), 0)
        np.maximum.accumulate(idx, out=idx)
        idx[: int(np.argmax(ok))] = int(np.argmax(ok))
        out[:, j] = col[idx]
    return out


Labels = tuple[np.ndarray, np.ndarray]  # a run's (K,) OC index per sample (-1: none), (K,) Phase code


def label_runs(runs: list[Run], schedule: Schedule, models: bool = False) -> list[Labels]:
    """Every run labelled by the causal OC detector (default settings, a fresh one per run), as
    the node labels it: once per training, for the segments, run_curve and the checks alike.
    models: by the model in force (``OCDetector.segment``: the start's apart from the first OC's,
    as training and the node's models cut them), not the OC."""
    out: list[Labels] = []
    for r, run in enumerate(runs):
        if schedule.switch not in run.channels:
            raise OrdervibError(f"run {r} has no {schedule.switch!r} channel, needed to find the OCs")
        out.append(OCDetector(schedule).label(run.column(schedule.switch), models))
    return out


def segment_runs(runs: list[Run], schedule: Schedule, min_samples: int = 40,
                 labels: list[Labels] | None = None) -> list[Segment]:
    """Cut every run into OC segments by its labels (``label_runs``; None: labelled here).

    Segments shorter than ``min_samples`` (1 s at 40 Hz) are dropped.
    """
    labels = label_runs(runs, schedule) if labels is None else labels
    segs: list[Segment] = []
    for r, (oc, ph) in enumerate(labels):
        k = 0
        K = len(oc)
        while k < K:
            j = k
            while j < K and oc[j] == oc[k]:
                j += 1
            if oc[k] >= 0 and j - k >= min_samples:
                steady = np.flatnonzero(ph[k:j] == Phase.STEADY.code)
                segs.append(Segment(r, int(oc[k]), k, j, k + int(steady[0]) if steady.size else j))
            k = j
    return segs


@dataclass
class RunArrays:
    """A run's target (K,) and inputs (K, m) with gaps held, plus its sample mask."""

    y: np.ndarray
    U: np.ndarray
    valid: np.ndarray  # (K,) target and every input were measured


def run_arrays(run: Run, target: str, inputs: list[str]) -> RunArrays:
    """Target and inputs of a run; a missing channel is an OrdervibError naming it."""
    missing = [c for c in [target, *inputs] if c not in run.channels]
    if missing:
        raise OrdervibError(f"channel(s) {missing} not in the recording (has {list(run.channels)})")
    raw = np.column_stack([run.column(c) for c in [target, *inputs]])
    valid = np.all(np.isfinite(raw), axis=1)
    filled = fill_gaps(raw)
    return RunArrays(filled[:, 0], filled[:, 1:], valid)


def target_vectors(run: Run, target: str) -> np.ndarray | None:
    """The target order's 1x vectors (K,) complex, amplitude and phase each held over gaps as
    the node holds them (its last value; NaN before the first: a run's first samples often have
    no phase); None without phase."""
    ph = phase_channel(target)
    if ph not in run.channels or target not in run.channels:
        return None
    return order_vectors(hold_last(run.column(target)), hold_last(run.column(ph)))


def first_seen(run: Run, channels: Sequence[str]) -> int:
    """The first sample by which every one of ``channels`` has been measured (``len(run.t)``:
    never). The node seeds a model from the measured past from there on (its rows before hold
    a channel never seen): what matters for a segment near the run's start, as the first OC's
    from light-off."""
    k = 0
    for c in channels:
        ok = np.isfinite(run.column(c))
        if not ok.any():
            return len(run.t)
        k = max(k, int(np.argmax(ok)))
    return k


def time_order(runs: list[Run]) -> list[int]:
    """Indices of ``runs`` by their first sample's time (the order one engine ran them)."""
    return sorted(range(len(runs)), key=lambda i: float(runs[i].t[0]) if len(runs[i].t) else 0.0)


def with_history(runs: list[Run], schedule: Schedule, config: RuntimeConfig) -> list[Run]:
    """``runs`` with the engine-history channels (``node.runtime.history``) appended, derived
    through them in time order as the node derives them (one engine; the first run's past
    unknown: a cold engine). Returned in the order given."""
    order = time_order(runs)
    on_speed = OCDetector(schedule, config).off_level
    done = add_history([runs[i] for i in order], schedule.switch, on_speed, config.history_cooling)
    out: list[Run] = list(runs)
    for i, r in zip(order, done):
        out[i] = r
    return out
