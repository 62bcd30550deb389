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

The fill, the bound and the interval are fitted aids (``node.training.prediction_aids``); the
profile CSV is read and the rows written by ``node.training.prediction_csv``; the command is
``node.cli.predict``.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from node.contract import FS, RUN_GAP, monitor_key, phase_channel
from node.contract.errors import OrdervibError
from node.contract.schedule import Schedule
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
from node.training.prediction_aids import INTERVAL_LEVEL, AmplitudeBound, InputFill, IntervalWidths
from node.training.prediction_reach import NO_OC, SpeedRange, finite_speeds, plan_marks, reach_note
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
RAISED, MODULUS, CAPPED = 1, 2, 3  # how a sample was bounded (``Prediction.bounded``; 0: as predicted)
MEAN_MODULUS = 4  # a model of the 1x vector without a measured level: the fleet's mean amplitude instead


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
    or none known), as in the node's monitor messages; marks (K,) where the plan leaves what the
    model knows (``node.training.prediction_reach``: 0 inside, ``BEYOND`` the training runs'
    speeds, ``NO_OC`` held where the node is steady in no OC: not predicted); speeds: the
    training runs' speed range (None: not known); steady (K,) bool where the node was steady
    on an OC's plateau.
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
    marks: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, dtype=np.int8))
    speeds: SpeedRange | None = None
    steady: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, dtype=bool))

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


    def reach_note(self) -> str | None:
        """One line on where the plan leaves what the model knows (``marks``), or that the node
        found no OC in it; None: neither."""
        marks = self.marks if self.marks.shape == self.t.shape else np.zeros(self.t.size, dtype=np.int8)
        steady = self.steady if self.steady.shape == self.t.shape else self.oc >= 0
        return reach_note(self.t, marks, self.predicted, steady, self.speeds, self.switch)

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
                 mean_modulus: bool = True, levels: InputFill | None = None,
                 speeds: SpeedRange | None = None) -> Prediction:
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
    curve (``Bundle.curve``, over every OC's samples). ``speeds``: the training runs' speed
    range, against which ``Prediction.marks`` marks the samples beyond (None: not known)."""
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
                                                          "upper", "hist", "env", "steady")}
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
        for key, arr in zip(("pred", "raw", "code", "upper", "oc", "env", "steady"), step):
            parts[key].append(arr)
    cat = {k: np.concatenate(v) for k, v in parts.items()}
    pred, oc, upper = cat["pred"], cat["oc"], cat["upper"]
    marks = plan_marks(cat["inputs"][:, need.index(sched.switch)], cat["steady"], cat["run"], speeds,
                       sched.tolerance, OCDetector(sched, m.config).off_level, m.config.detector_settle_s)
    pred[marks == NO_OC] = _NAN  # a hold no OC has: a transition's model is no model of it
    lo, hi = _interval(pred, oc, upper, widths)
    how = {c: fill.describe(c) for c in sorted(filled)} if fill is not None else {}
    own_share = {c: filled[c][1] / max(filled[c][0], 1) for c in sorted(filled)}
    rule = bound.describe() if bound is not None else "amplitudes >= 0 (a model of the 1x vector: its " \
        "modulus); not bounded above (no training runs at hand)"
    return Prediction(cat["t"], cat["run"], sched.switch, (*need, *slow), cat["inputs"],
                      tuple(sorted(filled)), oc, sched.names, targets, pred, cat["hist"],
                      engine or EngineState(), cat["raw"], cat["code"], upper, lo, hi,
                      how, own_share, rule, widths.describe(), label, widths.level, cat["env"], marks, speeds,
                      cat["steady"])


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
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Feed one run through the node sample by sample: (predicted within the bounds (K, n), the
    node's own (K, n), how each was bounded (K, n), the bound (K, n), oc index (K,), the node's
    envelope (K, n), steady on the OC's plateau (K,) bool).

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
    steady = np.zeros(K, dtype=bool)
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
                steady[k] = msg["phase"] == "steady"
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
    return pred, raw, code, upper, oc, env, steady


def predict_profile(model: Bundle | Model, profile: Profile, engine: EngineState | None = None,
                    fill: InputFill | None = None, seed: Seed = "chain", label: str = "",
                    bound: AmplitudeBound | None = None, widths: IntervalWidths | None = None,
                    levels: InputFill | None = None, speeds: SpeedRange | None = None) -> Prediction:
    """The expected orders over a planned profile (``read_profile``, ``schedule_profile``);
    the bounds, the interval and the marks as ``predict_runs`` sets them. A switch speed that
    is negative or not finite is a one-line OrdervibError."""
    m = as_model(model)
    col = profile.channels.index(profile.switch) if profile.switch in profile.channels else 0
    why = finite_speeds(profile.data[:, col])
    if why is not None:
        raise OrdervibError(f"the profile's {profile.switch or profile.channels[0]}: {why}")
    runs = profile.runs(OCDetector(m.schedule, m.config).off_level)
    return predict_runs(m, runs, engine, fill, seed, label, bound, widths, levels=levels, speeds=speeds)


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


def fit_interval_widths(model: Bundle | Model, runs: list[Run], bound: AmplitudeBound | None = None,
                        level: float = INTERVAL_LEVEL, levels: InputFill | None = None) -> IntervalWidths:
    """The interval widths from the chained prediction of each training run (one engine's, each
    with the history the runs before it leave) against what it measured
    (``IntervalWidths.from_recorded``); ``levels`` as ``predict_runs`` takes them."""
    return IntervalWidths.from_recorded(model, predict_recorded_runs(model, runs, bound=bound, levels=levels),
                                        level)
