"""Where a planned profile leaves what the model knows (``node.training.prediction``).

Two ways, each a mark per predicted sample (``plan_marks``; the prediction CSV's ``outside``
column, ``MARK_WORDS``):

* ``BEYOND``: the switch speed is beyond the speeds the training runs went through
  (:class:`SpeedRange`): above their highest, or between the engine's off level and their
  lowest. An OC model there holds its inputs at its envelope's edge (the node's fallback);
  where no OC is in force nothing is predicted.
* ``NO_OC``: the plan holds a speed (a plateau: the speed within a quarter of the schedule's
  tolerance band for the OC detector's settle time) with the engine running, and the node
  is steady in no OC anywhere on that plateau (a hold in the start from light-off, or between
  two OCs' plateaus): nothing is predicted there, a transition's model being no model of a
  hold.

Ramps (the start's, those between OCs, the rundown) are transitions by design and are not
marked. ``reach_note`` says in one line which samples are marked, or that the node was steady in
no OC in the whole plan.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from node.contract import FS
from node.models.bundle import Bundle, Model, as_model
from node.runtime.runcurve import hold_last
from node.training.runs import Run

INSIDE, BEYOND, NO_OC = 0, 1, 2  # a sample's mark (``plan_marks``)
MARK_WORDS = {INSIDE: "", BEYOND: "speed", NO_OC: "no_oc"}  # as the prediction CSV writes them
HELD_BAND = 0.25  # a plateau: the speed within this share of the schedule's tolerance band
SPANS_SHOWN = 4  # time spans a note names before "and N more"


@dataclass(frozen=True)
class SpeedRange:
    """The switch speeds the training runs went through: low, high rpm; source: what they are.

    >>> r = SpeedRange(18.0, 9814.0, "4 training runs")
    >>> r.beyond(np.array([0.0, 300.0, 5000.0, 10500.0]), off=490.0).tolist()
    [False, False, False, True]
    >>> r.describe()
    '18-9,814 rpm (4 training runs)'
    """

    low: float
    high: float
    source: str

    @classmethod
    def fit(cls, runs: Sequence[Run], switch: str, source: str) -> SpeedRange | None:
        """The range of ``switch`` over ``runs`` (None: no finite speed in them)."""
        speeds = [np.asarray(r.column(switch), float) for r in runs if switch in r.channels]
        s = np.concatenate(speeds) if speeds else np.zeros(0)
        s = s[np.isfinite(s)]
        if not s.size:
            return None
        return cls(float(s.min()), float(s.max()), source)

    @classmethod
    def from_model(cls, model: Bundle | Model) -> SpeedRange | None:
        """Without training runs: from standstill up to the highest switch speed the OC models'
        envelopes hold (None: no envelope takes the switch speed)."""
        m = as_model(model)
        switch = m.schedule.switch
        highs = [float(r.envelope.high[r.envelope.inputs.index(switch)])
                 for b in m.bundles for name in m.schedule.names
                 if (r := b.oc(name)) is not None and r.envelope is not None and switch in r.envelope.inputs]
        if not highs:
            return None
        return cls(0.0, max(highs), "the OC models' envelopes, from standstill")

    def beyond(self, speed: np.ndarray, off: float) -> np.ndarray:
        """(K,) bool: ``speed`` (K,) rpm above the range, or running (above ``off``) below it."""
        s = np.asarray(speed, float)
        with np.errstate(invalid="ignore"):
            return (s > self.high) | ((s > off) & (s < self.low))

    def describe(self) -> str:
        return f"{self.low:,.0f}-{self.high:,.0f} rpm ({self.source})"


def plateaus(speed: np.ndarray, tolerance: float, n: int) -> list[tuple[int, int]]:
    """The (start, stop) index pairs of the plateaus of ``speed`` (K,) rpm: the stretches of ``n``
    samples or more within ``HELD_BAND`` of the relative ``tolerance`` band (each of its windows
    of ``n`` samples is; two plateaus may touch where the speed steps from one to the next).

    >>> plateaus(np.r_[np.linspace(0.0, 900.0, 10), np.full(5, 1000.0), np.full(5, 2000.0)], 0.02, 3)
    [(10, 15), (15, 20)]
    """
    s = hold_last(np.asarray(speed, float))
    if s.size < n or n < 1:
        return []
    windows = np.lib.stride_tricks.sliding_window_view(np.nan_to_num(s), n)  # (K - n + 1, n)
    spread = windows.max(axis=1) - windows.min(axis=1)
    ok = np.isfinite(s[n - 1:]) & (spread <= HELD_BAND * tolerance * np.abs(s[n - 1:]))
    return [(lo, hi - 1 + n) for lo, hi in _spans(ok)]  # the windows starting in lo..hi-1


def _spans(mask: np.ndarray) -> list[tuple[int, int]]:
    """The (start, stop) index pairs of the True stretches of ``mask`` (K,)."""
    edges = np.diff(np.r_[0, mask.astype(np.int8), 0])
    return list(zip(np.flatnonzero(edges == 1).tolist(), np.flatnonzero(edges == -1).tolist()))


def plan_marks(speed: np.ndarray, steady: np.ndarray, run: np.ndarray, speeds: SpeedRange | None,
               tolerance: float, off: float, settle_s: float) -> np.ndarray:
    """(K,) int8 marks of predicted samples: ``BEYOND`` where ``speeds`` (None: not known, no
    such mark) says the switch ``speed`` (K,) rpm is beyond the training runs'; else ``NO_OC``
    on each plateau (``plateaus``, over ``settle_s``, in each engine ``run`` (K,)) above ``off`` rpm
    where the node was steady in an OC (``steady`` (K,) bool) on no sample; else ``INSIDE``."""
    s = np.asarray(speed, float)
    marks = np.zeros(s.size, dtype=np.int8)
    n = max(1, int(round(settle_s * FS)))
    for r in np.unique(run):
        mine = np.flatnonzero(run == r)
        for lo, hi in plateaus(s[mine], tolerance, n):
            at = mine[lo:hi]
            if not steady[at].any() and np.nanmedian(s[at]) > off:
                marks[at] = NO_OC
    if speeds is not None:
        marks[speeds.beyond(s, off)] = BEYOND
    return marks


def _times(t: np.ndarray, mask: np.ndarray) -> str:
    """The time spans of ``mask`` (K,) over ``t`` (K,) s, e.g. "t 105.0-165.0 s, 170.0-230.0 s"."""
    spans = _spans(mask)
    words = [f"{t[lo]:.1f}-{t[hi - 1]:.1f}" for lo, hi in spans[:SPANS_SHOWN]]
    more = f" and {len(spans) - SPANS_SHOWN} more" if len(spans) > SPANS_SHOWN else ""
    return f"t {', '.join(words)} s{more}"


def reach_note(t: np.ndarray, marks: np.ndarray, predicted: np.ndarray, steady: np.ndarray,
               speeds: SpeedRange | None, switch: str) -> str | None:
    """One line on where a plan leaves what the model knows (None: nowhere): how many samples
    are marked (``plan_marks``; t (K,) s, predicted (K, n)) as what and when, and whether the
    node was steady in no OC (``steady`` (K,) bool) in the whole plan; ``speeds`` and ``switch``
    name the range."""
    parts = []
    beyond = marks == BEYOND
    if beyond.any() and speeds is not None:
        n_pred = int(np.isfinite(predicted[beyond]).any(axis=1).sum())
        parts.append(f"'{MARK_WORDS[BEYOND]}': {int(beyond.sum()):,} with {switch} beyond the training runs' "
                     f"{speeds.describe()} at {_times(t, beyond)}, {n_pred:,} of them predicted with the "
                     "inputs held at the envelope's edge, the rest blank (no OC)")
    none = marks == NO_OC
    if none.any():
        parts.append(f"'{MARK_WORDS[NO_OC]}': {int(none.sum()):,} held at a {switch} the schedule has no OC "
                     f"for at {_times(t, none)}, blank")
    head = ""
    if parts:
        head = (f"the plan leaves what the model knows on {int((marks != INSIDE).sum()):,} of {t.size:,} "
                f"samples (column outside): {'; '.join(parts)}")
    if not steady.any():
        lost = ("the node found no OC of the schedule anywhere in the plan: nothing is predicted (does it "
                "hold each plateau for some seconds, within the schedule's tolerance?)")
        head = f"{head}; {lost}" if head else lost
    return head or None


def finite_speeds(speed: np.ndarray) -> str | None:
    """Why a planned switch speed (K,) rpm cannot be predicted (None: every value a finite
    number >= 0): the first bad value."""
    s = np.asarray(speed, float)
    bad = np.flatnonzero(~np.isfinite(s) | (s < 0))
    if not bad.size:
        return None
    v = float(s[bad[0]])
    what = "not a finite number" if not math.isfinite(v) else "negative"
    return f"{v:g} rpm is {what} (a planned speed is a number >= 0)"
