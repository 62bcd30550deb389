"""The expected tracked orders for a planned run (the toolbox's prediction, appendix A.2.4-A.2.5).

What an engineer asks before a pass-off: given this speed profile and this engine history
(how long the engine stood, what it ran before), what amplitude should each order show? And,
for a run already made, how close was that expectation?

Design:

* The numbers are the node's own: the profile is put on the 40 Hz grid and fed, sample by
  sample, through ``NodeCore`` (``handle_aligned``): the same OC detector, model switching,
  seeding and derived inputs (engine history, run curve) as live; no model is re-implemented.
* Inputs the profile does not carry (the other shafts' speeds, the temperatures, the
  pressures) are filled from training runs (:class:`InputFill`) as functions of the planned
  speed and the OC, never of the time alone: in each OC, the training runs' mean of the
  channel at the planned switch speed over that OC's samples, plus on the plateau their mean
  drift by second since its start; outside every OC, their mean at the speed over all
  samples. ``Prediction.filled_how`` says how. A recorded run's own inputs are used as
  recorded.
* The target is never measured. The node, finding no measured past at an OC switch, starts
  the OC's model from rest: a state-space model from state 0 (it then predicts its own
  transient from zero, not the engine), an anchored or vector curve without its anchor (the
  fleet curve). A prediction of a whole profile is therefore chained (``seed="chain"``, the
  default): the target the node is fed at each sample is the prediction of the sample before,
  or the fleet characteristic curve at the speed (``Bundle.curve``) where no model predicted
  (before the first OC, an OC without a model); so each OC's model is seeded from the
  prediction of the OC before it, the first from the fleet level. A model of the 1x vector
  has no phase to anchor on (none is measured, and a predicted one would only be the runs'
  mean vector again): it predicts the runs' mean vector, whose modulus is well below their
  mean amplitude where their phases differ, so chained, its amplitude is the training runs'
  mean amplitude in that OC at the speed (the mean modulus, ``levels``: ``InputFill`` of the
  targets, with its plateau drift; without training runs, the fleet curve ``Bundle.curve``);
  ``Prediction.bounded`` says ``MEAN_MODULUS``.
  ``seed="absent"`` is the node with the target missing, exactly.
* The engine history (appendix A.2.5): the ``hist_*`` inputs are derived by the node's own
  ``HistoryTracker`` from the profile's speed and slow temperatures, starting from a stated
  ``EngineState`` (:func:`stated_history`: the hours the engine stood before the profile and
  the energy it carried; or the history of recorded runs, :func:`history_after`);
  ``Prediction.history`` holds the four channels over the profile (figure A.5).
* Within physics (:class:`AmplitudeBound`): a predicted amplitude is never negative (raised
  to 0; a model of the 1x vector: its modulus) nor above 1.5 x the largest the training runs
  measured in that OC within 100 rpm of the speed; the chain feeds on the bounded value, and
  ``Prediction.bounded`` says where a bound acted (``bound_notes``).
* Every predicted sample carries a 90 % interval for a new run (:class:`IntervalWidths`):
  from the chained prediction's residual on the training runs, split into each run's level
  and a within-run part (a new run is a new level: the Student-t prediction interval of a
  new group over their number, centred on the chain's mean bias there), at least the OC
  model's CV residual sigma's.

No files are written here: ``read_profile`` reads and validates a profile CSV, ``write_csv``
writes rows to an open text stream; the command is ``node.cli.predict``.
"""

from __future__ import annotations

import csv
import dataclasses
import logging
import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal, TextIO

import numpy as np

from node.contract import FS, RUN_GAP, monitor_key, phase_channel
from node.contract.errors import OrdervibError
from node.contract.schedule import Schedule
from node.models.baseline import bin_sums
from node.models.bundle import Bundle, Model, as_model
from node.models.envelope import OUTSIDE
from node.runtime.align import AlignedSample
from node.runtime.core import NodeCore
from node.runtime.guard import unguarded
from node.runtime.history import (
    HISTORY_CHANNELS,
    SLOW_TEMPERATURES,
    EngineState,
    HistoryTracker,
    history_columns,
    state_after,
)
from node.runtime.ocdetect import OCDetector
from node.runtime.pipeline import MonitorPipeline
from node.runtime.runcurve import hold_last
from node.sysid.metrics import pooled_eps
from node.training.dataset import Segment, segment_runs, time_order
from node.training.runs import Run

log = logging.getLogger(__name__)

Seed = Literal["chain", "absent"]
_BED = "plan"  # the synthetic stream's bed name
_NAN = math.nan


# -- profiles ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class Profile:
    """A planned (or recorded) profile: t (K,) s, strictly increasing; data (K, c) finite, one
    column per channel (the switch speed, rpm, and any other sensor channel). Breakpoints
    need not be on the 40 Hz grid: ``runs`` interpolates them linearly (a plateau is two
    rows); a step in t of ``RUN_GAP`` or more between two rows where the switch speed
    (``switch``; the first column when empty) is at or below ``runs``' ``off`` starts a new
    engine run (the engine stood in between)."""

    t: np.ndarray
    data: np.ndarray
    channels: tuple[str, ...]
    switch: str = ""

    def runs(self, off: float = 0.0) -> list[Run]:
        """The profile on the 40 Hz grid, one ``Run`` per engine run (``off``: the speed, rpm,
        at or below which the engine stands; the OC detector's off level).

        >>> p = Profile(np.array([0.0, 1.0]), np.array([[0.0], [4000.0]]), ("nB",))
        >>> r = p.runs()[0]; r.t.size, float(r.column("nB")[20])
        (41, 2000.0)
        """
        speed = self.data[:, self.channels.index(self.switch) if self.switch in self.channels else 0]
        stood = (speed[:-1] <= off) & (speed[1:] <= off)
        cut = np.flatnonzero((np.diff(self.t) >= RUN_GAP) & stood) + 1
        out: list[Run] = []
        for lo, hi in zip(np.r_[0, cut], np.r_[cut, self.t.size]):
            t = self.t[lo:hi]
            n = int(math.floor((t[-1] - t[0]) * FS + 1e-9)) + 1
            grid = t[0] + np.arange(n) / FS
            data = np.column_stack([np.interp(grid, t, col) for col in self.data[lo:hi].T])
            out.append(Run(grid, data, self.channels, _BED, None if not out else float(t[0] - out[-1].t[-1])))
        return out


def read_profile(path: str, switch: str) -> Profile:
    """A profile CSV: a header with ``t`` (s) and the switch channel (rpm), optionally any other
    channels, then one row of numbers per breakpoint. Every problem is a one-line
    OrdervibError naming the file (and line): unreadable, no header, a missing column, a
    repeated one, an empty cell, NaN or a non-number, a time that does not increase, fewer
    than two rows."""
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:  # (a spreadsheet's byte-order mark)
            rows = list(csv.reader(f))
    except FileNotFoundError:
        raise OrdervibError(f"profile {path}: not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise OrdervibError(f"profile {path}: cannot be read ({exc})") from None
    rows = [r for r in rows if r and any(c.strip() for c in r)]
    if not rows:
        raise OrdervibError(f"profile {path}: empty (needs a header with t and {switch})")
    header = [c.strip() for c in rows[0]]
    dup = sorted({c for c in header if header.count(c) > 1})
    if dup:
        raise OrdervibError(f"profile {path}: column(s) {', '.join(dup)} repeated")
    for need in ("t", switch):
        if need not in header:
            raise OrdervibError(f"profile {path}: no column {need!r} (has {', '.join(header)}); "
                                f"a profile needs t (s) and {switch} (rpm)")
    values = np.empty((len(rows) - 1, len(header)))
    for i, row in enumerate(rows[1:]):
        line = i + 2
        if len(row) != len(header):
            raise OrdervibError(f"profile {path} line {line}: {len(row)} values for {len(header)} columns")
        for j, cell in enumerate(row):
            try:
                v = float(cell)
            except ValueError:
                raise OrdervibError(f"profile {path} line {line}: {header[j]} {cell.strip()!r} "
                                    "is not a number") from None
            if not math.isfinite(v):
                raise OrdervibError(f"profile {path} line {line}: {header[j]} is {cell.strip()} "
                                    "(every value must be a finite number)")
            values[i, j] = v
    if values.shape[0] < 2:
        raise OrdervibError(f"profile {path}: {values.shape[0]} row(s), needs at least two")
    t = values[:, header.index("t")]
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        k = int(bad[0]) + 1
        raise OrdervibError(f"profile {path} line {k + 2}: time {t[k]:g} s does not increase "
                            f"(the row before has {t[k - 1]:g} s)")
    cols = [j for j, c in enumerate(header) if c != "t"]
    return Profile(t, values[:, cols], tuple(header[j] for j in cols), switch)


def schedule_profile(schedule: Schedule, plateau_s: float = 60.0, ramp_rpm_s: float = 250.0,
                     idle_s: float = 10.0) -> Profile:
    """A profile through the schedule's plateaus in order: from standstill, each OC's speed
    reached at ``ramp_rpm_s`` and held ``plateau_s``, then down to standstill; ``idle_s`` of
    standstill before and after. The node's OC detector finds the first OC once the speed
    has held ``detector_settle_s`` (5 s): shorter plateaus are not found.

    >>> from node.contract.schedule import OperatingCondition
    >>> p = schedule_profile(Schedule((OperatingCondition("A", 1000.0),)), 5.0, 500.0, 1.0)
    >>> p.t.tolist(), p.data[:, 0].tolist()
    ([0.0, 1.0, 3.0, 8.0, 10.0, 11.0], [0.0, 0.0, 1000.0, 1000.0, 0.0, 0.0])
    """
    if not (plateau_s > 0 and ramp_rpm_s > 0 and idle_s >= 0):
        raise OrdervibError("plateau and ramp must be positive, idle >= 0")
    t, v = [0.0], [0.0]
    if idle_s:
        t.append(idle_s)
        v.append(0.0)
    for s in [oc.speed for oc in schedule.ocs] + [0.0]:
        t.append(t[-1] + abs(s - v[-1]) / ramp_rpm_s)
        v.append(s)
        if s:
            t.append(t[-1] + plateau_s)
            v.append(s)
    if idle_s:
        t.append(t[-1] + idle_s)
        v.append(0.0)
    keep = np.r_[True, np.diff(t) > 0]
    return Profile(np.array(t)[keep], np.array(v)[keep, None], (schedule.switch,), schedule.switch)


# -- filling inputs the profile lacks ------------------------------------------------------------
FILL_BIN_RPM = 50.0  # speed bins of the fill's curves, rpm
FILL_MIN_SAMPLES = 10  # training samples a bin of an OC's own curve needs (a quarter second)


def _binned(speed: np.ndarray, x: np.ndarray, min_samples: int) -> tuple[np.ndarray, np.ndarray] | None:
    """Mean of x per FILL_BIN_RPM bin of speed over bins holding ``min_samples`` or more finite
    pairs: (centres (B,) rpm, means (B,)); None when no bin does. speed, x: (K,)."""
    ok = np.isfinite(speed) & np.isfinite(x)
    if not ok.any():
        return None
    bins, sums, counts = bin_sums(speed[ok], x[ok], FILL_BIN_RPM)
    keep = counts >= min_samples
    if not keep.any():
        return None
    return (bins[keep] + 0.5) * FILL_BIN_RPM, sums[keep] / counts[keep]


def _along(speed: np.ndarray, own: tuple[np.ndarray, np.ndarray],
           whole: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """An OC's curve at ``speed`` (K,) rpm: interpolated within the speeds its training samples
    reached; beyond them, its value at the nearest such speed moved along the all-runs curve
    ``whole`` (so that it still follows the speed). Returns (values (K,), within (K,) bool)."""
    centres, means = own
    out = np.interp(speed, centres, means)
    lo, hi = float(centres[0]), float(centres[-1])
    below, above = speed < lo, speed > hi
    if below.any():
        out[below] += np.interp(speed[below], *whole) - float(np.interp(lo, *whole))
    if above.any():
        out[above] += np.interp(speed[above], *whole) - float(np.interp(hi, *whole))
    return out, ~(below | above)


@dataclass
class InputFill:
    """Channels a profile lacks, as the training runs had them at the planned speed and OC.

    A filled channel follows the plan's switch speed, never the time alone: inside an OC (as
    ``segment_runs`` cuts the profile), the OC's own curve of the channel against the switch
    speed (the training runs' mean in FILL_BIN_RPM bins over that OC's segments, interpolated;
    beyond the speeds they reached, moved along the all-runs curve), plus, on the plateau, the
    training runs' mean deviation from that curve at each whole second since the plateau's
    start (the thermal drift a plateau brings; held beyond the longest); outside every OC, the
    all-runs curve.

    speed_curves: per channel, its curve over every training sample (centres (B,) rpm, means
    (B,)); oc_curves: per channel, per OC index, the curve over that OC's segments; drifts: per
    channel, per OC index, the mean deviation (L,) at each second since the plateau's start;
    runs: the training runs it was learned from; source: where they came from (for the notes).
    """

    switch: str
    speed_curves: dict[str, tuple[np.ndarray, np.ndarray]]
    oc_curves: dict[str, dict[int, tuple[np.ndarray, np.ndarray]]] = dataclasses.field(default_factory=dict)
    drifts: dict[str, dict[int, np.ndarray]] = dataclasses.field(default_factory=dict)
    runs: int = 0
    source: str = "training runs"

    @property
    def channels(self) -> tuple[str, ...]:
        return tuple(self.speed_curves)

    @classmethod
    def fit(cls, runs: list[Run], schedule: Schedule, channels: Sequence[str],
            source: str = "training runs") -> InputFill:
        """From training runs holding the switch and ``channels`` (those some run lacks are left
        out: ``channels`` tells what was learned); ``source`` names them in the notes."""
        sw = schedule.switch
        have = [c for c in channels if c != sw and all(c in r.channels for r in runs)]
        segs = segment_runs(runs, schedule, min_samples=1)
        speeds = [hold_last(np.asarray(r.column(sw), float)) for r in runs]
        curves: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        oc_curves: dict[str, dict[int, tuple[np.ndarray, np.ndarray]]] = {}
        drifts: dict[str, dict[int, np.ndarray]] = {}
        by_oc: dict[int, list[Segment]] = {}
        for s in segs:
            by_oc.setdefault(s.oc, []).append(s)
        for c in have:
            vals = [np.asarray(r.column(c), float) for r in runs]
            whole = _binned(np.concatenate(speeds), np.concatenate(vals), 1)
            if whole is None:
                continue
            curves[c] = whole
            oc_curves[c], drifts[c] = {}, {}
            for oc, mine in by_oc.items():
                own = _binned(np.concatenate([speeds[s.run][s.start:s.stop] for s in mine]),
                              np.concatenate([vals[s.run][s.start:s.stop] for s in mine]), FILL_MIN_SAMPLES)
                if own is None:
                    continue
                oc_curves[c][oc] = own
                parts = []
                for s in mine:
                    if s.steady_start >= s.stop:
                        continue
                    sl = slice(s.steady_start, s.stop)
                    dev = vals[s.run][sl] - _along(speeds[s.run][sl], own, whole)[0]
                    parts.append(_per_second(dev))
                if parts:
                    drifts[c][oc] = _mean_track(parts)
        return cls(sw, curves, oc_curves, drifts, len(runs), source)

    def fill(self, run: Run, schedule: Schedule, channel: str) -> np.ndarray:
        """The channel over a run (K,) from its switch speed and OCs (as segment_runs cuts them)."""
        return self.fill_parts(run, schedule, channel)[0]

    def fill_parts(self, run: Run, schedule: Schedule, channel: str,
                   segments: list[Segment] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``fill`` and where each sample came from: (values (K,), own (K,) bool: from its OC's
        own curve within the speeds that OC's training samples reached). segments: the run's
        (``segment_runs([run], schedule, min_samples=1)``; None: cut here)."""
        speed = np.nan_to_num(hold_last(np.asarray(run.column(self.switch), float)), nan=0.0)
        whole = self.speed_curves[channel]
        out = np.interp(speed, *whole)
        own = np.zeros(speed.size, dtype=bool)
        segs = segment_runs([run], schedule, min_samples=1) if segments is None else segments
        for s in segs:
            curve = self.oc_curves.get(channel, {}).get(s.oc)
            if curve is None:
                continue
            sl = slice(s.start, s.stop)
            out[sl], own[sl] = _along(speed[sl], curve, whole)
            drift = self.drifts.get(channel, {}).get(s.oc)
            if drift is not None and drift.size and s.steady_start < s.stop:
                sec = np.minimum(np.arange(s.stop - s.steady_start) // int(FS), drift.size - 1)
                out[s.steady_start:s.stop] += drift[sec]
        return out, own

    def describe(self, channel: str) -> str:
        """How ``channel`` is filled, in a line (for the CSV's notes and the plot)."""
        return (f"from the {self.runs} {self.source}: in each OC, their mean at the planned {self.switch} "
                f"({FILL_BIN_RPM:g} rpm bins of that OC's samples) plus their mean drift on the plateau "
                f"by second since its start; outside the OCs, their mean at {self.switch} over all samples")


def _per_second(x: np.ndarray) -> np.ndarray:
    """Mean of x (K,) over each whole second (40 samples), NaN-aware: (ceil(K / 40),)."""
    sec = np.arange(x.size) // int(FS)
    ok = np.isfinite(x)
    n = np.bincount(sec[ok], minlength=int(sec[-1]) + 1)
    tot = np.bincount(sec[ok], weights=x[ok], minlength=int(sec[-1]) + 1)
    return np.where(n > 0, tot / np.maximum(n, 1), np.nan)


def _mean_track(parts: list[np.ndarray]) -> np.ndarray:
    """Mean over segments of per-second means (each (L_i,)), NaN-aware; held over gaps."""
    L = max(p.size for p in parts)
    stack = np.full((len(parts), L), np.nan)
    for i, p in enumerate(parts):
        stack[i, :p.size] = p
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a second no segment reached
        mean = np.nanmean(stack, axis=0)
    held = hold_last(mean)
    first = np.flatnonzero(np.isfinite(held))
    if first.size:
        held[: first[0]] = held[first[0]]
    return held


# -- the engine's history ------------------------------------------------------------------------
def stated_history(start_t: float, shutdown_h: float | None = None, energy: float | None = None,
                   before: EngineState | None = None) -> EngineState:
    """The engine's history before a run starting at ``start_t`` (s): ``before`` (default
    unknown: a cold engine) with the engine last run ``shutdown_h`` hours before (None: as
    ``before`` says) carrying ``energy`` rpm min at that time (None: as ``before`` says).

    >>> stated_history(7200.0, 1.5, 1000.0)
    EngineState(last_on_t=1800.0, energy=1000.0, shutdown_h=24.0, thermal=None, rate=0.0)
    """
    st = dataclasses.replace(before) if before is not None else EngineState()
    if shutdown_h is not None:
        if not (math.isfinite(shutdown_h) and shutdown_h >= 0):
            raise OrdervibError(f"a shutdown time must be a number of hours >= 0, got {shutdown_h}")
        st.last_on_t = float(start_t) - 3600.0 * float(shutdown_h)
    if energy is not None:
        if not (math.isfinite(energy) and energy >= 0):
            raise OrdervibError(f"the energy carried must be >= 0 rpm min, got {energy}")
        st.energy = float(energy)
    return st


def history_after(runs: list[Run], model: Bundle | Model, state: EngineState | None = None) -> EngineState:
    """The engine history at the end of recorded ``runs`` (one engine's; taken in time order),
    as the node derives it (e.g. a held-out run's history: that of the training runs)."""
    m = as_model(model)
    on = OCDetector(m.schedule, m.config).off_level
    ordered = [runs[i] for i in time_order(runs)]
    return state_after(ordered, m.schedule.switch, on, m.config.history_cooling, state)


# -- predictions within physics: the bounds and the interval ----------------------------------------
BOUND_FACTOR = 1.5  # the upper bound: this many times the training runs' largest amplitude ...
BOUND_WINDOW_RPM = 100.0  # ... in the same OC within this many rpm of the speed
BOUND_STEP_RPM = 5.0  # rpm: the resolution of the bound's speed window
INTERVAL_LEVEL = 0.90  # the interval's coverage for a new run
RAISED, MODULUS, CAPPED = 1, 2, 3  # how a sample was bounded (``Prediction.bounded``; 0: as predicted)
MEAN_MODULUS = 4  # a model of the 1x vector without a measured level: the fleet's mean amplitude instead


@dataclass(frozen=True)
class AmplitudeBound:
    """The upper bound of each target's predicted amplitude, from the training runs' measurements.

    The rule: ``factor`` x the largest amplitude the training runs measured in the same OC (as
    ``segment_runs`` cuts them) within ``window`` rpm of the speed (speeds taken in
    BOUND_STEP_RPM steps: rounded to 5 rpm, the window inclusive); where that OC's training
    samples never came that close, the largest of any training sample within the window;
    where none did, the OC's largest at any speed (an OC never trained: the largest of all).

    near (n, O + 1, S): the largest measured within the window of each BOUND_STEP_RPM speed step
    from 0 rpm (row O: of any OC; NaN: none there), mm/s; oc_top (n, O): each OC's largest,
    top (n,): the largest of all (NaN: never measured); runs: the training runs.
    """

    targets: tuple[str, ...]
    near: np.ndarray
    oc_top: np.ndarray
    top: np.ndarray
    factor: float = BOUND_FACTOR
    window: float = BOUND_WINDOW_RPM
    runs: int = 0

    @classmethod
    def fit(cls, runs: list[Run], schedule: Schedule, targets: Sequence[str], factor: float = BOUND_FACTOR,
            window: float = BOUND_WINDOW_RPM) -> AmplitudeBound:
        """From training runs (a target some run lacks is left out of those runs)."""
        sw, O = schedule.switch, len(schedule.names)
        speeds = [np.asarray(r.column(sw), float) for r in runs]
        labels = [np.full(len(r.t), O, dtype=np.int64) for r in runs]
        for s in segment_runs(runs, schedule):
            labels[s.run][s.start:s.stop] = s.oc
        w = int(round(window / BOUND_STEP_RPM))
        top_speed = max((float(np.nanmax(v)) for v in speeds if np.isfinite(v).any()), default=0.0)
        steps = int(max(top_speed, 0.0) // BOUND_STEP_RPM) + 2 + w
        near = np.full((len(targets), O + 1, steps), np.nan)
        for j, tg in enumerate(targets):
            raw = np.full((O + 1, steps), -np.inf)
            for r, run in enumerate(runs):
                if tg not in run.channels:
                    continue
                y = np.asarray(run.column(tg), float)
                ok = np.isfinite(y) & np.isfinite(speeds[r])  # a sample at an unknown speed is at none
                idx = np.clip((speeds[r][ok] / BOUND_STEP_RPM).round().astype(np.int64), 0, steps - 1)
                np.maximum.at(raw, (labels[r][ok], idx), y[ok])
                np.maximum.at(raw[O], idx, y[ok])
            padded = np.pad(raw, ((0, 0), (w, w)), constant_values=-np.inf)
            mx = np.lib.stride_tricks.sliding_window_view(padded, 2 * w + 1, axis=1).max(axis=2)
            near[j] = np.where(np.isfinite(mx), mx, np.nan)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # an OC never measured: NaN
            oc_top = np.nanmax(near[:, :O], axis=2) if steps else np.full((len(targets), O), np.nan)
            top = np.nanmax(near[:, O], axis=1) if steps else np.full(len(targets), np.nan)
        return cls(tuple(targets), near, oc_top, top, factor, window, len(runs))

    def limits(self, target: str, oc: int, speed: np.ndarray) -> np.ndarray:
        """The bound (K,) mm/s of ``target`` in OC ``oc`` (-1: outside every OC) at ``speed`` (K,)
        rpm, by the rule (NaN: the training runs never measured the target)."""
        j = self.targets.index(target)
        O = self.oc_top.shape[1]
        steps = self.near.shape[2]
        idx = (np.clip(np.nan_to_num(speed, nan=0.0), 0.0, None) / BOUND_STEP_RPM).round().astype(np.int64)
        beyond = idx >= steps  # faster than any training sample by more than the window
        idx = np.minimum(idx, steps - 1)
        mine = np.where(beyond, np.nan, self.near[j, oc if 0 <= oc < O else O, idx])
        anyone = np.where(beyond, np.nan, self.near[j, O, idx])
        last = self.oc_top[j, oc] if 0 <= oc < O and np.isfinite(self.oc_top[j, oc]) else self.top[j]
        return self.factor * np.where(np.isfinite(mine), mine, np.where(np.isfinite(anyone), anyone, last))

    def describe(self) -> str:
        """The rule in a line (for the CSV's notes and the plot)."""
        return (f"amplitudes >= 0 (a model of the 1x vector: its modulus), and <= {self.factor:g} x the "
                f"largest that {self.runs} training runs measured in the same OC within "
                f"{self.window:g} rpm (speeds in {BOUND_STEP_RPM:g} rpm steps; none there: of any OC within "
                f"{self.window:g} rpm; none either: the OC's largest)")


@dataclass(frozen=True)
class IntervalWidths:
    """The interval of each target in each OC, mm/s: a prediction's interval is
    [max(0, pred + shift - half), min(pred + shift + half, the bound)], widened to hold pred.

    A plan's prediction starts each OC's model from the prediction before it, never from a
    measured level, so its error is mostly the run's own level (its imbalance, its bow), which
    a model seeded with the measured past (its cross-validation, ``Calibration.sigma``) never
    shows. ``fit`` measures it on the chained prediction of each training run from its own
    profile, as a one-way random-effects model with the run as the unit: each run's residual in
    the OC is its level m_r (its mean residual there) plus a within-run part. Over the n runs
    that reached the OC (a second or more each): ``shift`` the mean of the m_r (the chain's
    bias there), ``between`` their SD (n - 1 degrees of freedom), ``within`` the pooled SD about
    each run's own level. A new run's residual is then shift + its level + its within part,
    and the half-width is t_{(1+level)/2, n-1} sqrt(between^2 (1 + 1/n) + within^2) (the
    Student-t prediction interval of a new group; before: the RMS residual about the
    prediction, which counts a bias as spread and the runs' own mean as known), at least
    the same factor times the CV sigma. ``from_cv``: the CV sigma times the normal quantile
    alone, no shift (no training runs at hand; narrower than a plan's error).

    half, shift, cv_sigma, chain_rms, between, within (n targets, O): mm/s (NaN: none;
    chain_rms: the RMS residual, for the record); runs (n, O): the training runs that reached
    each OC (0 with ``from_cv``).
    """

    targets: tuple[str, ...]
    half: np.ndarray
    cv_sigma: np.ndarray
    chain_rms: np.ndarray
    runs: np.ndarray
    level: float = INTERVAL_LEVEL
    shift: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 0)))
    between: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 0)))
    within: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 0)))

    @staticmethod
    def _sigmas(model: Model) -> np.ndarray:
        names = model.schedule.names
        out = np.full((len(model.bundles), len(names)), np.nan)
        for j, b in enumerate(model.bundles):
            for o, name in enumerate(names):
                r = b.oc(name)
                if r is not None and r.calibration is not None and r.model is not None:
                    out[j, o] = r.calibration.sigma
        return out

    @classmethod
    def from_cv(cls, model: Bundle | Model, level: float = INTERVAL_LEVEL) -> IntervalWidths:
        """The OC models' CV residual sigma times the normal quantile of ``level``."""
        from scipy.stats import norm

        m = as_model(model)
        sig = cls._sigmas(m)
        z = float(norm.ppf(0.5 + level / 2.0))
        nan = np.full_like(sig, np.nan)
        return cls(tuple(m.targets), z * sig, sig, nan, np.zeros(sig.shape, np.int64), level,
                   np.zeros_like(sig), nan, nan)

    @classmethod
    def fit(cls, model: Bundle | Model, runs: list[Run], bound: AmplitudeBound | None = None,
            level: float = INTERVAL_LEVEL, levels: InputFill | None = None) -> IntervalWidths:
        """From the chained prediction of each training run (one engine's, each with the history
        the runs before it leave) against what it measured (see the class); ``levels`` as
        ``predict_runs`` takes them."""
        return cls.from_recorded(model, predict_recorded_runs(model, runs, bound=bound, levels=levels), level)

    @classmethod
    def from_recorded(cls, model: Bundle | Model, recs: Sequence[RecordedPrediction],
                      level: float = INTERVAL_LEVEL) -> IntervalWidths:
        """From recorded runs' chained predictions against what they measured (``fit``'s, of
        runs already predicted: ``predict_recorded_runs``)."""
        from scipy.stats import norm
        from scipy.stats import t as student

        m = as_model(model)
        sig = cls._sigmas(m)
        n, O = sig.shape
        levels: list[list[list[float]]] = [[[] for _ in range(O)] for _ in range(n)]
        ss_within, dof_within = np.zeros((n, O)), np.zeros((n, O))
        sq, count = np.zeros((n, O)), np.zeros((n, O))
        for rec in recs:
            p = rec.prediction
            for j in range(n):
                res = rec.measured[:, j] - p.predicted[:, j]
                ok = np.isfinite(res) & (p.oc >= 0)
                np.add.at(sq[j], p.oc[ok], res[ok] ** 2)
                np.add.at(count[j], p.oc[ok], 1)
                for o in np.unique(p.oc[ok]).tolist():
                    r = res[ok & (p.oc == o)]
                    if r.size < FS:  # a second or more
                        continue
                    levels[j][o].append(float(r.mean()))
                    ss_within[j, o] += float(np.sum((r - r.mean()) ** 2))
                    dof_within[j, o] += r.size - 1
        with np.errstate(invalid="ignore", divide="ignore"):
            rms = np.sqrt(sq / count)
            within = np.sqrt(ss_within / dof_within)
        reached = np.array([[len(levels[j][o]) for o in range(O)] for j in range(n)], np.int64).reshape(n, O)
        shift, between = np.zeros((n, O)), np.full((n, O), np.nan)
        for j in range(n):
            for o in range(O):
                if reached[j, o] >= 2:
                    shift[j, o] = float(np.mean(levels[j][o]))
                    between[j, o] = float(np.std(levels[j][o], ddof=1))
        few = reached < 2
        n_runs = np.maximum(reached, 2)
        factor = student.ppf(0.5 + level / 2.0, n_runs - 1)
        new_run = np.sqrt(between ** 2 * (1.0 + 1.0 / n_runs) + within ** 2)
        half = np.full((n, O), np.nan)
        half[~few] = (factor * np.fmax(new_run, sig))[~few]
        half[few] = float(norm.ppf(0.5 + level / 2.0)) * sig[few]
        shift[few] = 0.0
        return cls(tuple(m.targets), np.where(np.isfinite(sig), half, np.nan), sig, rms, reached, level,
                   np.where(np.isfinite(sig), shift, 0.0), between, within)

    def offsets(self) -> np.ndarray:
        """``shift`` (n, O), zeros where none was measured (a bundle of widths from before)."""
        return self.shift if self.shift.shape == self.half.shape else np.zeros(self.half.shape)

    def describe(self) -> str:
        """The rule in a line (for the CSV's notes and the plot)."""
        pct = f"{100 * self.level:g} %"
        if not self.runs.any():
            return (f"{pct} interval: prediction -/+ the normal quantile x the OC model's CV residual sigma "
                    "(no training runs at hand: narrower than a plan's error), at least 0")
        return (f"{pct} interval for a new run: the residuals of the chained prediction of the n training "
                "runs in that OC as run levels (each run's mean residual) plus a within-run part; centred on "
                "the prediction plus the runs' mean level, -/+ t_(n-1) x sqrt(SD of the run levels^2 "
                "(1 + 1/n) + within-run SD^2) (at least t_(n-1) x the OC model's CV residual sigma), widened "
                "to hold the prediction, at least 0, at most the bound")


# -- the prediction ---------------------------------------------------------------------------------
@dataclass
class Prediction:
    """The expected orders over a profile (on the 40 Hz grid).

    t (K,) s; run (K,) the engine run of each sample (0, 1, ...); inputs (K, c) the channels
    fed to the node (``channels``; those in ``filled`` came from ``InputFill``, each as
    ``filled_how`` says, ``filled_own`` the share of its samples from its OC's own curve);
    oc (K,) the OC index the node was in (-1: none); predicted (K, n)
    per target (``targets``), mm/s, within the bounds (NaN where no model predicted); raw
    (K, n) the node's own prediction before them; bounded (K, n) how each sample was bounded
    (0: as predicted, RAISED to 0, MODULUS of the 1x vector, CAPPED at the bound); upper (K, n)
    the bound, mm/s (NaN: none); lo, hi (K, n) the interval of ``level``, mm/s; history (K, 4) the
    engine-history channels (``HISTORY_CHANNELS``); engine: the stated history before;
    bound_rule, interval_rule: the rules in words; label: what it is; envelope (K, n) the node's
    ``envelope`` of each target's model at each sample (how far its inputs, the engine history
    among them, are from its training region: at most 1 inside, above 1 outside; NaN: no model
    or none known), as in the node's monitor messages.
    """

    t: np.ndarray
    run: np.ndarray
    switch: str
    channels: tuple[str, ...]
    inputs: np.ndarray
    filled: tuple[str, ...]
    oc: np.ndarray
    oc_names: tuple[str, ...]
    targets: tuple[str, ...]
    predicted: np.ndarray
    history: np.ndarray
    engine: EngineState
    raw: np.ndarray
    bounded: np.ndarray
    upper: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    filled_how: dict[str, str] = dataclasses.field(default_factory=dict)
    filled_own: dict[str, float] = dataclasses.field(default_factory=dict)
    bound_rule: str = ""
    interval_rule: str = ""
    label: str = ""
    level: float = INTERVAL_LEVEL
    envelope: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 0)))

    @property
    def speed(self) -> np.ndarray:
        return self.inputs[:, self.channels.index(self.switch)]

    def per_oc(self) -> list[tuple[str, int, np.ndarray]]:
        """(OC name, samples, mean predicted per target (n,)) of each OC the profile reaches."""
        out = []
        for j, name in enumerate(self.oc_names):
            mine = self.oc == j
            if mine.any():
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", RuntimeWarning)  # a target never predicted
                    out.append((name, int(mine.sum()), np.nanmean(self.predicted[mine], axis=0)))
        return out

    def bound_notes(self) -> list[str]:
        """Per target, where the bounds acted, in a line: the samples raised to 0, taken as the
        modulus and capped, each with the OCs (and for the cap the node's largest)."""
        out = []
        for j, tg in enumerate(self.targets):
            parts = []
            for code, what in ((RAISED, "raised to 0"), (MODULUS, "taken as the 1x vector's modulus"),
                               (MEAN_MODULUS, "a model of the 1x vector without a measured level: the "
                                              "fleet curve's mean amplitude at the speed"),
                               (CAPPED, "capped at the bound")):
                hit = self.bounded[:, j] == code
                if not hit.any():
                    continue
                ocs = np.bincount(self.oc[hit][self.oc[hit] >= 0], minlength=len(self.oc_names))
                where = ", ".join(f"{self.oc_names[o]} {int(c)}" for o, c in enumerate(ocs) if c)
                text = f"{what} on {int(hit.sum())} samples ({where})"
                if code == CAPPED:
                    k = int(np.flatnonzero(hit)[np.argmax(self.raw[hit, j])])
                    text += (f", the node's largest {self.raw[k, j]:.3g} mm/s at {self.speed[k]:,.0f} rpm "
                             f"against {self.upper[k, j]:.3g}")
                parts.append(text)
            out.append(f"{tg}: " + ("; ".join(parts) if parts else "within the bounds as predicted"))
        return out


    def outside(self) -> np.ndarray:
        """(K, n) bool: samples where a target's model was outside its training region
        (``envelope`` above 1: its inputs, the engine history among them, held at the edge)."""
        if self.envelope.shape != self.predicted.shape:
            return np.zeros(self.predicted.shape, dtype=bool)
        return np.nan_to_num(self.envelope, nan=0.0) > OUTSIDE

    def envelope_notes(self) -> list[str]:
        """Per target, where its model's inputs left the training region, in a line: the samples
        with ``envelope`` above 1 per OC, the largest and its time, and whether the history
        inputs were among the inputs outside."""
        out = []
        beyond = self.outside()
        for j, tg in enumerate(self.targets):
            hit = beyond[:, j]
            if not hit.any():
                known = self.envelope.shape == self.predicted.shape and np.isfinite(self.envelope[:, j]).any()
                out.append(f"{tg}: " + ("inside the training region (envelope <= 1)" if known else
                                        "no envelope known (a bundle from before, or no model)"))
                continue
            ocs = np.bincount(self.oc[hit][self.oc[hit] >= 0], minlength=len(self.oc_names))
            where = ", ".join(f"{self.oc_names[o]} {int(c)}" for o, c in enumerate(ocs) if c)
            k = int(np.flatnonzero(hit)[np.argmax(self.envelope[hit, j])])
            out.append(f"{tg}: OUTSIDE the training region (envelope > 1: the model held its inputs at the "
                       f"region's edge) on {int(hit.sum())} samples ({where}), the largest "
                       f"{self.envelope[k, j]:.3g} at t {self.t[k] - self.t[0]:.1f} s")
        return out


def takes_history(model: Bundle | Model) -> bool:
    """Whether some OC model takes an engine-history input (``HISTORY_CHANNELS``): only then can
    a stated history change the prediction."""
    return any(c in HISTORY_CHANNELS for b in as_model(model).bundles for c in b.inputs)


def _unmeasured(model: Bundle | Model) -> Model:
    """The model as a prediction runs it: no fleet transients (the targets are not measured,
    their transitions not analysed against the fleet; nor their own shafts' speeds awaited)."""
    m = as_model(model)
    if all(b.transients is None for b in m.bundles):
        return m
    return Model(tuple(dataclasses.replace(b, transients=None) for b in m.bundles))


def needed_channels(model: Bundle | Model) -> list[str]:
    """The sensor channels the node awaits for ``model``, but the targets and their phases."""
    m = _unmeasured(model)
    own = {c for b in m.bundles for c in (b.target, phase_channel(b.target))}
    pipes = [MonitorPipeline(b) for b in m.bundles]
    return sorted({c for p in pipes for c in p.sensor_channels} - own)


def predict_runs(model: Bundle | Model, runs: list[Run], engine: EngineState | None = None,
                 fill: InputFill | None = None, seed: Seed = "chain", label: str = "",
                 bound: AmplitudeBound | None = None, widths: IntervalWidths | None = None,
                 mean_modulus: bool = True, levels: InputFill | None = None) -> Prediction:
    """The node's prediction over ``runs`` (on the 40 Hz grid, in time order, one engine) with
    the targets unmeasured (see the module's design); ``engine``: the history before the
    first run. A channel the node needs that the runs lack and ``fill`` cannot give is a
    one-line OrdervibError.

    Every predicted amplitude is bounded below by 0 (a model of the 1x vector: its modulus)
    and above by ``bound`` (None: not above), and the bounded value is what the chain feeds
    on; its interval comes from ``widths`` (None: ``IntervalWidths.from_cv``). ``mean_modulus``
    false: a model of the 1x vector keeps the node's own modulus, its predicted phase fed back
    (as before the mean modulus, for comparison). ``levels``: the targets' mean amplitude in
    each OC at the speed, from training runs (``InputFill.fit`` of the targets), taken for
    the mean modulus and where no model predicted; None, or a target it lacks: the fleet
    curve (``Bundle.curve``, over every OC's samples)."""
    m = _unmeasured(model)
    sched = m.schedule
    need = needed_channels(m)
    slow = [c for c in SLOW_TEMPERATURES if c not in need]
    targets = tuple(m.targets)
    widths = widths if widths is not None else IntervalWidths.from_cv(m)
    uses_phase = [phase_channel(b.target) in MonitorPipeline(b).channels for b in m.bundles]
    fleet = [b.curve for b in m.bundles]
    core = NodeCore(unguarded(m), {_BED: engine} if engine is not None else None)  # nothing measured
    keys = {monitor_key(_BED, tg): j for j, tg in enumerate(targets)}
    history = HistoryTracker(OCDetector(sched, m.config).off_level, m.config.history_cooling, engine)
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("t", "run", "inputs", "oc", "pred", "raw", "code",
                                                          "upper", "hist", "env")}
    filled: dict[str, list[int]] = {}  # samples filled, of them from the OC's own curve
    for r, run in enumerate(runs):
        cols = []
        segs: list[Segment] | None = None
        for c in [*need, *slow]:
            if c in run.channels:
                cols.append(np.asarray(run.column(c), float))
            elif fill is not None and c in fill.channels:
                if segs is None:
                    segs = segment_runs([run], sched, min_samples=1)
                values, own = fill.fill_parts(run, sched, c, segs)
                cols.append(values)
                tally = filled.setdefault(c, [0, 0])
                tally[0] += values.size
                tally[1] += int(own.sum())
            elif c in need:
                raise OrdervibError(
                    f"the model takes {c!r}, which the profile does not hold: add it as a column, or "
                    "give the training recordings to fill it from (see ordervib predict --train)")
            else:
                cols.append(np.full(len(run.t), _NAN))
        X = np.column_stack(cols)
        t = np.asarray(run.t, float)
        means: np.ndarray | None = None
        if levels is not None and any(tg in levels.channels for tg in targets):
            if segs is None:
                segs = segment_runs([run], sched, min_samples=1)
            means = np.column_stack([levels.fill_parts(run, sched, tg, segs)[0] if tg in levels.channels
                                   else np.full(t.size, _NAN) for tg in targets])
        step = _step_node(core, keys, t, X, need, targets, uses_phase, fleet, seed, sched, bound,
                          mean_modulus, means)
        speed = hold_last(X[:, need.index(sched.switch)])
        slow_cols = np.column_stack([hold_last(X[:, [*need, *slow].index(c)]) for c in SLOW_TEMPERATURES])
        parts["hist"].append(history_columns(t, speed, slow_cols, history))
        parts["t"].append(t)
        parts["run"].append(np.full(t.size, r))
        parts["inputs"].append(X)
        for key, arr in zip(("pred", "raw", "code", "upper", "oc", "env"), step):
            parts[key].append(arr)
    cat = {k: np.concatenate(v) for k, v in parts.items()}
    pred, oc, upper = cat["pred"], cat["oc"], cat["upper"]
    lo, hi = _interval(pred, oc, upper, widths)
    how = {c: fill.describe(c) for c in sorted(filled)} if fill is not None else {}
    own_share = {c: filled[c][1] / max(filled[c][0], 1) for c in sorted(filled)}
    rule = bound.describe() if bound is not None else "amplitudes >= 0 (a model of the 1x vector: its " \
        "modulus); not bounded above (no training runs at hand)"
    return Prediction(cat["t"], cat["run"], sched.switch, (*need, *slow), cat["inputs"],
                      tuple(sorted(filled)), oc, sched.names, targets, pred, cat["hist"],
                      engine or EngineState(), cat["raw"], cat["code"], upper, lo, hi,
                      how, own_share, rule, widths.describe(), label, widths.level, cat["env"])


def _interval(pred: np.ndarray, oc: np.ndarray, upper: np.ndarray,
              widths: IntervalWidths) -> tuple[np.ndarray, np.ndarray]:
    """The interval (lo, hi) (K, n) mm/s of predictions ``pred`` (K, n) in OCs ``oc`` (K,) under
    the bound ``upper`` (K, n; NaN: none): pred + the OC's shift -/+ its half-width, lo at least 0
    and never above pred, hi at most the bound and never below pred."""
    half = np.full(pred.shape, _NAN)
    shift = np.zeros(pred.shape)
    inside = oc >= 0
    half[inside] = widths.half[:, oc[inside]].T
    shift[inside] = widths.offsets()[:, oc[inside]].T
    centre = pred + shift
    lo = np.minimum(np.maximum(centre - half, 0.0), pred)
    hi = np.where(np.isfinite(upper), np.minimum(centre + half, upper), centre + half)
    return lo, np.fmax(hi, pred)


def with_interval(p: Prediction, widths: IntervalWidths) -> Prediction:
    """``p`` with its interval from ``widths`` (e.g. widths learned from the very runs predicted)."""
    lo, hi = _interval(p.predicted, p.oc, p.upper, widths)
    return dataclasses.replace(p, lo=lo, hi=hi, interval_rule=widths.describe(), level=widths.level)


def _step_node(core: NodeCore, keys: dict[str, int], t: np.ndarray, X: np.ndarray, need: list[str],
               targets: tuple[str, ...], uses_phase: list[bool],
               fleet: list[tuple[np.ndarray, np.ndarray] | None], seed: Seed,
               sched: Schedule, bound: AmplitudeBound | None, mean_modulus: bool = True,
               own: np.ndarray | None = None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Feed one run through the node sample by sample: (predicted within the bounds (K, n), the
    node's own (K, n), how each was bounded (K, n), the bound (K, n), oc index (K,), the node's
    envelope (K, n)).

    Chained, a model of the 1x vector never has a measured level to anchor on (the target is
    never measured), so it predicts the runs' mean vector, whose modulus is below the mean
    modulus (the runs' phases differ): its amplitude is taken from the fleet curve at the
    speed instead (the mean amplitude, ``MEAN_MODULUS``; ``own`` (K, n): the training runs' mean
    in the OC at the speed, where finite), and no phase is fed back (``mean_modulus`` false:
    the node's own, its predicted phase fed back)."""
    K, n = t.size, len(targets)
    O = len(sched.names)
    pred = np.full((K, n), _NAN)
    raw = np.full((K, n), _NAN)
    code = np.zeros((K, n), dtype=np.int8)
    upper = np.full((K, n), _NAN)
    env = np.full((K, n), _NAN)
    oc = np.full(K, -1, dtype=np.int64)
    index = {name: j for j, name in enumerate(sched.names)}
    speed = X[:, need.index(sched.switch)]
    level = np.column_stack([np.interp(np.nan_to_num(speed), *f) if f is not None else np.full(K, _NAN)
                             for f in fleet])
    if own is not None:
        level = np.where(np.isfinite(own), own, level)
    # the bound of each target in each OC (row O: outside every OC) at each sample's speed
    caps = [np.vstack([bound.limits(tg, o, hold_last(speed)) for o in range(-1, O)])
            if bound is not None and tg in bound.targets else None for tg in targets]
    phases = [phase_channel(tg) for tg in targets]
    fed = [_NAN] * n
    fed_ph = [_NAN] * n
    rows = X.tolist()
    times = t.tolist()
    for k in range(K):
        vals = dict(zip(need, rows[k]))
        for j in range(n):
            vals[targets[j]] = fed[j]
            if uses_phase[j]:
                vals[phases[j]] = fed_ph[j]  # NaN with the mean modulus: never known (see above)
        for key, msg in core.handle_aligned(_BED, [AlignedSample(times[k], vals, new_run=k == 0)]):
            if key not in keys:
                continue
            j = keys[key]
            if msg["oc"] is not None:  # (the rundown, no plateau OC: -1, as outside every OC)
                oc[k] = index.get(msg["oc"], -1)
            p = msg["predicted"] if oc[k] >= 0 else None  # a plan's prediction: the OCs' (no interval else)
            ph = msg.get("predicted_phase")
            e = msg.get("envelope")
            if e is not None:
                env[k, j] = e
            v = _NAN
            if p is not None:
                raw[k, j] = v = p
                if ph is not None and mean_modulus and seed == "chain" and level[k, j] == level[k, j]:
                    v, code[k, j] = float(level[k, j]), MEAN_MODULUS  # no level: the mean modulus
                    if v < 0.0:  # (the runs' mean level regressed on speed can dip below 0)
                        v, code[k, j] = 0.0, RAISED
                elif v < 0.0:  # a model of the 1x vector: the amplitude is its modulus
                    v, code[k, j] = (-v, MODULUS) if ph is not None else (0.0, RAISED)
                cap = caps[j]
                if cap is not None:
                    u = upper[k, j] = cap[oc[k] + 1, k]
                    if v > u:
                        v, code[k, j] = u, CAPPED
                pred[k, j] = v
            if seed == "chain":
                fed[j] = v if p is not None else float(level[k, j])
                if not mean_modulus:
                    fed_ph[j] = _NAN if ph is None or p is None else ph
    return pred, raw, code, upper, oc, env


def predict_profile(model: Bundle | Model, profile: Profile, engine: EngineState | None = None,
                    fill: InputFill | None = None, seed: Seed = "chain", label: str = "",
                    bound: AmplitudeBound | None = None, widths: IntervalWidths | None = None,
                    levels: InputFill | None = None) -> Prediction:
    """The expected orders over a planned profile (``read_profile``, ``schedule_profile``);
    the bounds and the interval as ``predict_runs`` sets them."""
    m = as_model(model)
    runs = profile.runs(OCDetector(m.schedule, m.config).off_level)
    return predict_runs(m, runs, engine, fill, seed, label, bound, widths, levels=levels)


@dataclass
class RecordedPrediction:
    """A recorded run's prediction from its own inputs against what it measured.

    measured (K, n) per target, mm/s; segments: the run's OC segments (``segment_runs``, as
    training cuts them; their ``run`` is 0); eps (n, OCs): eps_td per target and OC
    (schedule order), pooled over the OC's segments where both are finite; NaN where the run
    does not reach the OC or no model predicted it (``recorded_eps`` pools several runs).
    """

    prediction: Prediction
    measured: np.ndarray
    segments: list[Segment]
    eps: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 0)))

    def __post_init__(self) -> None:
        if not self.eps.size:
            self.eps = recorded_eps([self])


def recorded_eps(recs: Sequence[RecordedPrediction]) -> np.ndarray:
    """eps_td (n targets, OCs) pooled over the OC segments of every run in ``recs`` (NaN where
    none has a prediction and a measurement)."""
    first = recs[0].prediction
    eps = np.full((len(first.targets), len(first.oc_names)), _NAN)
    for j in range(len(first.targets)):
        for oc in range(len(first.oc_names)):
            pairs = []
            for rec in recs:
                for s in rec.segments:
                    if s.oc != oc:
                        continue
                    y = rec.measured[s.start:s.stop, j]
                    p = rec.prediction.predicted[s.start:s.stop, j]
                    ok = np.isfinite(y) & np.isfinite(p)
                    if ok.any():
                        pairs.append((y[ok], p[ok]))
            if pairs:
                eps[j, oc] = pooled_eps(pairs)
    return eps


def predict_recorded_run(model: Bundle | Model, run: Run, engine: EngineState | None = None,
                         seed: Seed = "chain", label: str = "", bound: AmplitudeBound | None = None,
                         widths: IntervalWidths | None = None, mean_modulus: bool = True,
                         levels: InputFill | None = None) -> RecordedPrediction:
    """The prediction for a held-out ``run`` from its own profile (its switch speed and every
    other input as recorded, the targets left out) and a stated history ``engine`` (e.g.
    ``history_after(training_runs, model)``, or ``stated_history``), compared per OC with the
    targets it measured (eps_td, ``node.sysid.metrics``); bounds and interval as
    ``predict_runs``."""
    m = as_model(model)
    pred = predict_runs(m, [run], engine, None, seed, label, bound, widths, mean_modulus, levels)
    measured = np.column_stack([run.column(tg) if tg in run.channels else np.full(len(run.t), _NAN)
                                for tg in pred.targets])
    return RecordedPrediction(pred, measured, segment_runs([run], m.schedule))


def predict_recorded_runs(model: Bundle | Model, runs: list[Run], engine: EngineState | None = None,
                          seed: Seed = "chain", bound: AmplitudeBound | None = None,
                          widths: IntervalWidths | None = None, mean_modulus: bool = True,
                          levels: InputFill | None = None) -> list[RecordedPrediction]:
    """``predict_recorded_run`` of each of one engine's ``runs`` (returned in the order given),
    each with the history the runs before it (in time order) leave, from ``engine`` (the
    history before the first: default unknown, a cold engine); ``recorded_eps`` pools them."""
    m = as_model(model)
    out: dict[int, RecordedPrediction] = {}
    state = engine
    for i in time_order(runs):
        out[i] = predict_recorded_run(m, runs[i], state, seed, f"run {i + 1}", bound, widths, mean_modulus,
                                      levels)
        state = history_after([runs[i]], m, state)
    return [out[i] for i in range(len(runs))]


# -- output ---------------------------------------------------------------------------------------
def csv_columns(preds: Sequence[Prediction]) -> list[str]:
    """The columns ``write_csv`` writes: the stated history's label, time, OC, each target
    predicted with its interval and its model's envelope (``yB``, ``yB_lo``, ``yB_hi``,
    ``yB_envelope``: the node's monitor-message field, above 1 where the model's inputs, the
    engine history among them, left its training region), the engine-history channels, and
    every input fed to the node."""
    p = preds[0]
    per_target = (c for tg in p.targets for c in (tg, f"{tg}_lo", f"{tg}_hi", f"{tg}_envelope"))
    return ["history", "t", "oc", *per_target, *HISTORY_CHANNELS, *p.channels]


def csv_notes(preds: Sequence[Prediction]) -> list[str]:
    """The notes ``write_csv`` puts above the header (without their "# "): the bounds and where
    they acted, where a model left its training region (``Prediction.envelope_notes``), the
    interval, and how each filled channel was filled."""
    p = preds[0]
    out = [f"bounds: {p.bound_rule}"]
    for q in preds:
        at = f" ({q.label} h stood)" if len(preds) > 1 and q.label else ""
        out += [f"bounds acted{at}: {line}" for line in q.bound_notes()]
    for q in preds:
        at = f" ({q.label} h stood)" if len(preds) > 1 and q.label else ""
        out += [f"envelope{at}: {line}" for line in q.envelope_notes()]
    out.append(f"interval: {', '.join(f'{tg}_lo..{tg}_hi' for tg in p.targets)}: {p.interval_rule}")
    for how in dict.fromkeys(p.filled_how.values()):
        mine = [c for c, h in p.filled_how.items() if h == how]
        out.append(f"filled {', '.join(mine)}: {how}")
    if p.filled_own:
        out.append("filled from the OC's own curve: " + ", ".join(
            f"{c} {100 * v:.0f} %" for c, v in p.filled_own.items()) + " of the samples")
    if not p.filled_how:
        out.append("filled: none (the profile holds every channel the model takes)")
    return out


def write_csv(preds: Sequence[Prediction], f: TextIO) -> int:
    """Rows of each prediction (one per stated history) into ``f``; returns the rows written.

    Lines starting with "# " come first (``csv_notes``: read with a CSV reader that skips
    comments, e.g. pandas' ``comment="#"``), then the header (``csv_columns``). ``history``:
    each prediction's label (``ordervib predict``: the hours the engine stood before the
    profile as stated); numbers with 6 significant digits, NaN as an empty cell."""
    for line in csv_notes(preds):
        f.write(f"# {line}\n")
    w = csv.writer(f, lineterminator="\n")
    w.writerow(csv_columns(preds))
    n = 0
    for p in preds:
        names = [p.oc_names[i] if i >= 0 else "" for i in p.oc.tolist()]
        env = p.envelope if p.envelope.shape == p.predicted.shape else np.full(p.predicted.shape, _NAN)
        band = np.stack([p.predicted, p.lo, p.hi, env], axis=2).reshape(p.t.size, -1)
        body = np.column_stack([band, p.history, p.inputs])
        for k in range(p.t.size):
            w.writerow([p.label, f"{p.t[k]:.3f}", names[k], *map(_g, body[k].tolist())])
        n += p.t.size
    return n


def _g(x: float) -> str:
    return "" if x != x else f"{x:.6g}"
