"""The expected tracked orders for a planned run (the toolbox's prediction, appendix A.2.4-A.2.5).

What an engineer asks before a pass-off: given this speed profile and this engine history
(how long the engine stood, what it ran before), what amplitude should each order show? And,
for a run already made, how close was that expectation?

Design:

* The numbers are the node's own: the profile is put on the 40 Hz grid and fed, sample by
  sample, through ``NodeCore`` (``handle_aligned``): the same OC detector, model switching,
  seeding and derived inputs (engine history, run curve) as live; no model is re-implemented.
* Inputs the profile does not carry (typically the temperatures) are filled from training
  runs (:class:`InputFill`): inside an OC, the training runs' mean of the channel at each
  second since the OC's start (its transition, then its plateau: the thermal drift an OC
  brings), held beyond the longest; outside every OC, the channel's mean at the speed (its
  characteristic curve against the switch speed). A recorded run's own inputs are used as
  recorded.
* The target is never measured. The node, finding no measured past at an OC switch, starts
  the OC's model from rest: a state-space model from state 0 (it then predicts its own
  transient from zero, not the engine), an anchored or vector curve without its anchor (the
  fleet curve). A prediction of a whole profile is therefore chained (``seed="chain"``, the
  default): the target the node is fed at each sample is the prediction of the sample before,
  or the fleet characteristic curve at the speed (``Bundle.curve``) where no model predicted
  (before the first OC, an OC without a model); so each OC's model is seeded from the
  prediction of the OC before it, the first from the fleet level. The predicted phase is fed
  back likewise to models of the 1x vector. ``seed="absent"`` is the node with the target
  missing, exactly.
* The engine history (appendix A.2.5): the ``hist_*`` inputs are derived by the node's own
  ``HistoryTracker`` from the profile's speed and slow temperatures, starting from a stated
  ``EngineState`` (:func:`stated_history`: the hours the engine stood before the profile and
  the energy it carried; or the history of recorded runs, :func:`history_after`);
  ``Prediction.history`` holds the four channels over the profile (figure A.5).

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
from node.models.baseline import CharacteristicCurve
from node.models.bundle import Bundle, Model, as_model
from node.runtime.align import AlignedSample
from node.runtime.core import NodeCore
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
@dataclass
class InputFill:
    """Channels a profile lacks, as the training runs had them (see the module's design).

    speed_curves: per channel, its characteristic curve against the switch speed (centres, means);
    tracks: per channel, per OC index, the training runs' mean at each whole second since the
    OC's start (L,).
    """

    switch: str
    speed_curves: dict[str, tuple[np.ndarray, np.ndarray]]
    tracks: dict[str, dict[int, np.ndarray]]

    @property
    def channels(self) -> tuple[str, ...]:
        return tuple(self.speed_curves)

    @classmethod
    def fit(cls, runs: list[Run], schedule: Schedule, channels: Sequence[str]) -> InputFill:
        """From training runs holding the switch and ``channels`` (those some run lacks are left
        out: ``channels`` tells what was learned)."""
        sw = schedule.switch
        have = [c for c in channels if c != sw and all(c in r.channels for r in runs)]
        curves, tracks = {}, {}
        segs = segment_runs(runs, schedule, min_samples=1)
        for c in have:
            speed = np.concatenate([r.column(sw) for r in runs])
            vals = np.concatenate([r.column(c) for r in runs])
            try:
                cc = CharacteristicCurve(50.0).fit(speed, vals)
            except ValueError:
                continue
            curves[c] = (cc.centres_, cc.means_)
            sums: dict[int, list[np.ndarray]] = {}
            for s in segs:
                x = runs[s.run].column(c)[s.start:s.stop]
                sec = np.arange(x.size) // int(FS)
                ok = np.isfinite(x)
                n = np.bincount(sec[ok], minlength=int(sec[-1]) + 1)
                tot = np.bincount(sec[ok], weights=x[ok], minlength=int(sec[-1]) + 1)
                sums.setdefault(s.oc, []).append(np.where(n > 0, tot / np.maximum(n, 1), np.nan))
            tracks[c] = {oc: _mean_track(parts) for oc, parts in sums.items()}
        return cls(sw, curves, tracks)

    def fill(self, run: Run, schedule: Schedule, channel: str) -> np.ndarray:
        """The channel over a run (K,) from its switch speed and OCs (as segment_runs cuts them)."""
        speed = hold_last(np.asarray(run.column(self.switch), float))
        centres, means = self.speed_curves[channel]
        out = np.interp(np.nan_to_num(speed, nan=0.0), centres, means)
        for s in segment_runs([run], schedule, min_samples=1):
            track = self.tracks[channel].get(s.oc)
            if track is None or not track.size:
                continue
            sec = np.minimum(np.arange(s.stop - s.start) // int(FS), track.size - 1)
            out[s.start:s.stop] = track[sec]
        return out


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


# -- the prediction ---------------------------------------------------------------------------------
@dataclass
class Prediction:
    """The expected orders over a profile (on the 40 Hz grid).

    t (K,) s; run (K,) the engine run of each sample (0, 1, ...); inputs (K, c) the channels
    fed to the node (``channels``; those in ``filled`` came from ``InputFill``); oc (K,) the
    OC index the node was in (-1: none); predicted (K, n) per target (``targets``), mm/s (NaN
    where no model predicted); history (K, 4) the engine-history channels
    (``HISTORY_CHANNELS``); engine: the stated history before; label: what it is.
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
    label: str = ""

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


def takes_history(model: Bundle | Model) -> bool:
    """Whether some OC model takes an engine-history input (``HISTORY_CHANNELS``): only then can
    a stated history change the prediction."""
    return any(c in HISTORY_CHANNELS for b in as_model(model).bundles for c in b.inputs)


def needed_channels(model: Bundle | Model) -> list[str]:
    """The sensor channels the node awaits for ``model``, but the targets and their phases."""
    m = as_model(model)
    own = {c for b in m.bundles for c in (b.target, phase_channel(b.target))}
    pipes = [MonitorPipeline(b) for b in m.bundles]
    return sorted({c for p in pipes for c in p.sensor_channels} - own)


def predict_runs(model: Bundle | Model, runs: list[Run], engine: EngineState | None = None,
                 fill: InputFill | None = None, seed: Seed = "chain", label: str = "") -> Prediction:
    """The node's prediction over ``runs`` (on the 40 Hz grid, in time order, one engine) with
    the targets unmeasured (see the module's design); ``engine``: the history before the
    first run. A channel the node needs that the runs lack and ``fill`` cannot give is a
    one-line OrdervibError."""
    m = as_model(model)
    sched = m.schedule
    need = needed_channels(m)
    slow = [c for c in SLOW_TEMPERATURES if c not in need]
    targets = tuple(m.targets)
    uses_phase = [phase_channel(b.target) in MonitorPipeline(b).channels for b in m.bundles]
    fleet = [b.curve for b in m.bundles]
    core = NodeCore(m, {_BED: engine} if engine is not None else None)
    keys = {monitor_key(_BED, tg): j for j, tg in enumerate(targets)}
    history = HistoryTracker(OCDetector(sched, m.config).off_level, m.config.history_cooling, engine)
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("t", "run", "inputs", "oc", "pred", "hist")}
    filled: set[str] = set()
    for r, run in enumerate(runs):
        cols = []
        for c in [*need, *slow]:
            if c in run.channels:
                cols.append(np.asarray(run.column(c), float))
            elif fill is not None and c in fill.channels:
                cols.append(fill.fill(run, sched, c))
                filled.add(c)
            elif c in need:
                raise OrdervibError(
                    f"the model takes {c!r}, which the profile does not hold: add it as a column, or "
                    "give the training recordings to fill it from (see ordervib predict --train)")
            else:
                cols.append(np.full(len(run.t), _NAN))
        X = np.column_stack(cols)
        t = np.asarray(run.t, float)
        pred, oc = _step_node(core, keys, t, X, need, targets, uses_phase, fleet, seed, sched)
        speed = hold_last(X[:, need.index(sched.switch)])
        slow_cols = np.column_stack([hold_last(X[:, [*need, *slow].index(c)]) for c in SLOW_TEMPERATURES])
        parts["hist"].append(history_columns(t, speed, slow_cols, history))
        parts["t"].append(t)
        parts["run"].append(np.full(t.size, r))
        parts["inputs"].append(X)
        parts["oc"].append(oc)
        parts["pred"].append(pred)
    cat = {k: np.concatenate(v) for k, v in parts.items()}
    return Prediction(cat["t"], cat["run"], sched.switch, (*need, *slow), cat["inputs"],
                      tuple(sorted(filled)), cat["oc"], sched.names, targets, cat["pred"], cat["hist"],
                      engine or EngineState(), label)


def _step_node(core: NodeCore, keys: dict[str, int], t: np.ndarray, X: np.ndarray, need: list[str],
               targets: tuple[str, ...], uses_phase: list[bool],
               fleet: list[tuple[np.ndarray, np.ndarray] | None], seed: Seed,
               sched: Schedule) -> tuple[np.ndarray, np.ndarray]:
    """Feed one run through the node sample by sample: (predicted (K, n), oc index (K,))."""
    K, n = t.size, len(targets)
    pred = np.full((K, n), _NAN)
    oc = np.full(K, -1, dtype=np.int64)
    index = {name: j for j, name in enumerate(sched.names)}
    speed = X[:, need.index(sched.switch)]
    level = np.column_stack([np.interp(np.nan_to_num(speed), *f) if f is not None else np.full(K, _NAN)
                             for f in fleet])
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
                vals[phases[j]] = fed_ph[j]
        for key, msg in core.handle_aligned(_BED, [AlignedSample(times[k], vals, new_run=k == 0)]):
            if key not in keys:
                continue
            j = keys[key]
            p = msg["predicted"]
            pred[k, j] = _NAN if p is None else p
            if msg["oc"] is not None:
                oc[k] = index[msg["oc"]]
            if seed == "chain":
                fed[j] = p if p is not None else float(level[k, j])
                ph = msg.get("predicted_phase")
                fed_ph[j] = _NAN if ph is None or p is None else ph
    return pred, oc


def predict_profile(model: Bundle | Model, profile: Profile, engine: EngineState | None = None,
                    fill: InputFill | None = None, seed: Seed = "chain", label: str = "") -> Prediction:
    """The expected orders over a planned profile (``read_profile``, ``schedule_profile``)."""
    m = as_model(model)
    runs = profile.runs(OCDetector(m.schedule, m.config).off_level)
    return predict_runs(m, runs, engine, fill, seed, label)


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
                         seed: Seed = "chain", label: str = "") -> RecordedPrediction:
    """The prediction for a held-out ``run`` from its own profile (its switch speed and every
    other input as recorded, the targets left out) and a stated history ``engine`` (e.g.
    ``history_after(training_runs, model)``, or ``stated_history``), compared per OC with the
    targets it measured (eps_td, ``node.sysid.metrics``)."""
    m = as_model(model)
    pred = predict_runs(m, [run], engine, None, seed, label)
    measured = np.column_stack([run.column(tg) if tg in run.channels else np.full(len(run.t), _NAN)
                                for tg in pred.targets])
    return RecordedPrediction(pred, measured, segment_runs([run], m.schedule))


def predict_recorded_runs(model: Bundle | Model, runs: list[Run], engine: EngineState | None = None,
                          seed: Seed = "chain") -> list[RecordedPrediction]:
    """``predict_recorded_run`` of each of one engine's ``runs`` (returned in the order given),
    each with the history the runs before it (in time order) leave, from ``engine`` (the
    history before the first: default unknown, a cold engine); ``recorded_eps`` pools them."""
    m = as_model(model)
    out: dict[int, RecordedPrediction] = {}
    state = engine
    for i in time_order(runs):
        out[i] = predict_recorded_run(m, runs[i], state, seed, f"run {i + 1}")
        state = history_after([runs[i]], m, state)
    return [out[i] for i in range(len(runs))]


# -- output ---------------------------------------------------------------------------------------
def csv_columns(preds: Sequence[Prediction]) -> list[str]:
    """The columns ``write_csv`` writes: the stated history's label, time, OC, the targets
    predicted, the engine-history channels, and every input fed to the node."""
    p = preds[0]
    return ["history", "t", "oc", *p.targets, *HISTORY_CHANNELS, *p.channels]


def write_csv(preds: Sequence[Prediction], f: TextIO) -> int:
    """Rows of each prediction (one per stated history) into ``f``; returns the rows written.

    ``history``: each prediction's label (``ordervib predict``: the hours the engine stood
    before the profile as stated); numbers with 6 significant digits, NaN as an empty cell."""
    w = csv.writer(f, lineterminator="\n")
    w.writerow(csv_columns(preds))
    n = 0
    for p in preds:
        names = [p.oc_names[i] if i >= 0 else "" for i in p.oc.tolist()]
        body = np.column_stack([p.predicted, p.history, p.inputs])
        for k in range(p.t.size):
            w.writerow([p.label, f"{p.t[k]:.3f}", names[k], *map(_g, body[k].tolist())])
        n += p.t.size
    return n


def _g(x: float) -> str:
    return "" if x != x else f"{x:.6g}"
