"""The node's numerics, free of I/O: aligned samples in, monitor messages out.

Live (Zenoh) and offline replay feed the very same ``MonitorPipeline``, so
they give the very same numbers. Per sample: the OC detector steps on the
switch speed; at an OC switch the OC's model is seeded from the measured
past (a bounded ring buffer) and then steps once per sample (the start is
the first OC's transition, with a model of its own until it leaves the speed
it held, ``OCDetector.segment``; after the last plateau the rundown, ``oc``
"rundown", has its model like an OC where the bundle holds one: a bundle
trained without them leaves them ``no-model``); its residual
goes to the OC's ``ResidualCheck`` (``reason`` "residual"). Model-free checks
flag, with or without a model, an abrupt step of the measured target during a
steady plateau (``StepCheck``, ``reason`` "step") and a target stuck on one value
while the engine runs (``FlatlineCheck``, ``reason`` "flatline"); see
``node.runtime.alarms``. A bundle trained on recordings with the target's phase
channel (``<target>_ph``) also watches the order's 1x vector, measured amplitude x
exp(-j phase), on steady plateaus (``reason`` "vector"): its abrupt change (``StepCheck``)
and its change since the plateau settled (``StepCheck`` anchored, its threshold the OC's own
where training set one), which see an added
imbalance at right angles to the existing one (the amplitude hardly moves) and a mode's
stiffness drifting in. An OC model that predicts the vector (a vector curve) is seeded
with the measured vectors. The monitor message then carries ``measured_phase``,
``predicted_phase``, ``vector_residual`` (|measured - predicted vector|) and
``vector_score``. Every timing comes from the bundle's ``RuntimeConfig``.

An OC model with a plateau shift (``node.models.plateau``) has its prediction moved by what this
run's earlier plateaus (``RunPlateaus``, stepped with every sample's measured level) add to the
level before the switch, faded in after the switch; one with a settle anchor
(``node.models.settle``), from 15 s after the switch, by a share of what it missed over the 2 s
before. A predicted 1x vector moves with it, along its own direction.

Where the schedule holds acceptance limits for the target, each message carries ``limit`` (the
limit in force, ``limit_in_force``) and ``over_limit``, and the run's ``RunVerdict``
(``node.runtime.verdict``) steps on it: at an OC switch and at the run's end (the engine stopped,
the next run, ``end_verdict``) ``verdicts`` holds its ``monitor/verdict`` message.

Each sample also steps the target's ``TransientWatch`` (``node.runtime.transient_watch``): at
the end of a transition (a run-up, a coast-down, a ramp between plateaus; a run's last one at
the next run or the end of the stream, ``end_transient``) ``transient`` holds its
``monitor/transient`` message for that sample, else None.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from node.contract import FS, Flag, Phase, Reason, phase_channel
from node.contract.schedule import limit_in_force
from node.contract.vector import NAN_VECTOR, lag_degrees, order_vector, order_vectors
from node.models.average import AverageRuntime, predicts_vector
from node.models.bundle import Bundle
from node.models.curve import CurveRuntime
from node.models.envelope import HELD, OUTSIDE, Envelope
from node.models.forecast import MIN_RUNS, Forecaster
from node.models.ocmodel import OCRuntime
from node.models.plateau import PlateauShift
from node.models.settle import AT as SETTLE_AT
from node.models.settle import WINDOW as SETTLE_WINDOW
from node.models.settle import SettleAnchor
from node.runtime.alarms import FlatlineCheck, ResidualCheck, RunScale, StepCheck
from node.runtime.align import AlignedSample
from node.runtime.chirp import CHIRP_RATE, ChirpRate
from node.runtime.guard import CURVE, guard_of
from node.runtime.history import HISTORY_CHANNELS, SLOW_TEMPERATURES, EngineState, HistoryTracker
from node.runtime.ocdetect import OCDetector
from node.runtime.plateaus import RunPlateaus
from node.runtime.rows import RecentRows
from node.runtime.runcurve import RUN_CURVE, RunCurve
from node.runtime.transient_watch import PendingTransient, TransientWatch
from node.runtime.verdict import RunVerdict

_NAN = float("nan")
_PHASE = {p: p.value for p in Phase}  # each phase's string (an enum's .value is a slow descriptor)
# the members the per-sample step names, looked up once (an enum class attribute costs a descriptor call)
_NO_MODEL, _OK, _STEADY, _OFF = Flag.NO_MODEL, Flag.OK, Phase.STEADY, Phase.OFF
_NO_SLOW = (_NAN, _NAN, _NAN)


@dataclass
class _Active:
    """The OC model in force: its stepper, inputs and residual rule."""

    runtime: OCRuntime
    inputs: list[str]
    model_id: str
    check: ResidualCheck
    vector: CurveRuntime | AverageRuntime | None = None  # the runtime again when it predicts the 1x vector
    envelope: Envelope | None = None  # the region its training runs covered (None: not known)
    since: int = 0  # samples since the OC switch
    shift: float = 0.0  # what the run's earlier plateaus add (node.models.plateau), faded in
    settle: SettleAnchor | None = None  # the re-anchor on the visit's own level (node.models.settle)
    window: list[float] = field(default_factory=list)  # its residuals before SETTLE_AT (<= SETTLE_WINDOW)
    moved: float | None = None  # its move from SETTLE_AT on (None: not yet known)


def _num(x: float) -> float | None:
    return None if not math.isfinite(x) else float(x)


class MonitorPipeline:
    """Stateful per-bed pipeline (bounded memory: ``config.history_s`` of samples).

    ``step(sample)`` returns ``(monitor_message, oc_message_or_None)`` as dicts
    ready for JSON (contract section 2). ``engine``: the bed's engine history before
    (``node.runtime.history``; default: unknown, a cold engine); ``history.state`` keeps it
    up to date across runs (a new run does not reset it).
    """

    def __init__(self, bundle: Bundle, engine: EngineState | None = None,
                 history: HistoryTracker | None = None, slow_temperatures: bool = False,
                 detector: OCDetector | None = None) -> None:
        """history: the bed's tracker when several targets' pipelines share it (it is stepped
        once per sample; ``engine`` is then unused); slow_temperatures: await the slow
        temperatures even when this target's models take no history input (another target's do);
        detector: the OC detector of the bed's first target's pipeline, when this one follows it
        (the targets of a model share schedule and settings, so their detectors agree): that
        pipeline steps (and resets) it on each sample before this one reads its state."""
        cfg = bundle.config
        self.bundle = bundle
        self.target = bundle.target
        self.switch = bundle.schedule.switch
        if detector is not None and (detector.schedule != bundle.schedule or detector.config != cfg):
            raise ValueError("a shared OC detector must have the pipeline's schedule and settings")
        self._follows = detector is not None  # another pipeline steps the detector
        self.detector = detector or OCDetector(bundle.schedule, cfg, FS)
        # per model index (``OCDetector.segment``, ``Schedule.models``): its ``oc`` (the start's: the
        # first OC's) and its model's name (tuples built on each access: keep them)
        self._names = (*bundle.schedule.segments, bundle.schedule.names[0])
        self._models = bundle.schedule.models
        self._uses_history = any(c in HISTORY_CHANNELS for c in bundle.inputs)
        slow = SLOW_TEMPERATURES if self._uses_history or slow_temperatures else ()
        # the vector rule: a sliding and an anchored StepCheck on the 1x vector (either may be off);
        # the anchored one's threshold per OC where training set one (``_switch``)
        self._vector = [StepCheck(float(thr), cfg, FS, anchored) for anchored, thr in
                        ((False, bundle.checks.get("vector_step_threshold")),
                         (True, bundle.checks.get("vector_drift_threshold"))) if thr]
        self._drift = next((c for c in self._vector if c.anchored), None)
        pooled = self._drift.threshold if self._drift is not None else math.inf
        per_oc = bundle.checks.get("vector_drift_thresholds") or {}
        self._drift_thr = [float(per_oc.get(n, pooled)) or math.inf  # 0: off in that OC
                           for n in self._models]
        self._phase_ch = phase_channel(self.target)
        vector_models = any(predicts_vector(r.model) for r in bundle.ocs)
        shifts = [r.plateau for r in bundle.ocs if r.plateau is not None]
        self._plateau_vector = bool(shifts) and shifts[0].vector  # (a bundle's shifts are of one kind)
        self._uses_phase = bool(self._vector) or vector_models or self._plateau_vector
        phase = (self._phase_ch,) if self._uses_phase else ()
        # the acceptance limits on the target (contract section 4): limit and over_limit per sample
        self._limits = bundle.schedule.limits_of(self.target)
        # and the verdict of the run (node.runtime.verdict): its messages of the last sample, if any
        table = bundle.forecast
        forecaster = Forecaster(table) if table is not None and len(table.peak) >= MIN_RUNS else None
        self._verdict = (RunVerdict(self.target, bundle.schedule.segments, forecaster) if self._limits
                         else None)
        self.verdicts: list[dict] = []
        # the transitions: on the speed and phase the fleet's were analysed on (an older bundle:
        # the switch speed, and the phase where the other rules read it)
        self._transient = TransientWatch(self.target, bundle.schedule, bundle.transients)
        self._tr_phase = self._uses_phase or self._transient.settings.phase
        # the transient message of the last sample, if any (a PendingTransient when deferred)
        self.transient: dict | PendingTransient | None = None
        if self._tr_phase:
            phase = (self._phase_ch,)
        self.channels = sorted({self.switch, self.target, *bundle.inputs, *slow, *phase,
                                self._transient.speed})
        # what the test bed publishes: the derived inputs are computed here, never awaited
        derived = {RUN_CURVE, CHIRP_RATE, *HISTORY_CHANNELS}
        self.sensor_channels = [c for c in self.channels if c not in derived]
        self.history = history or HistoryTracker(self.detector.off_level, cfg.history_cooling, engine)
        self._slow = slow
        self._hist = RecentRows(maxlen=int(cfg.history_s * FS))  # the measured past
        self._last: dict[str, float] = dict.fromkeys(self.channels, _NAN)  # in channel order
        self._state: tuple[int | None, Phase] = (None, Phase.OFF)
        self._active: _Active | None = None
        self._clear = int(cfg.residual_clear_s * FS)  # the residual rule's off-delay, samples
        limit = bundle.checks.get("flatline_samples")
        self._flat = FlatlineCheck(int(limit)) if limit else None
        thr = bundle.checks.get("step_threshold")
        self._jump = StepCheck(float(thr), cfg, FS) if thr else None
        prior = bundle.checks.get("run_scale_prior_ocs")
        self._runscale = RunScale(float(prior)) if prior else None
        # the curve guard (node.runtime.guard): the characteristic curve where the OC model erred more
        self._guard = guard_of(bundle.curve, cfg)
        self._curve = None  # this run's own characteristic, when a model takes it as input
        if RUN_CURVE in self.channels and bundle.curve is not None:
            self._curve = RunCurve(*bundle.curve, cfg.run_curve_bin)
        # the chirp rate (node.runtime.chirp), when a model takes it as input
        self._chirp = ChirpRate() if CHIRP_RATE in self.channels else None
        # this run's plateaus, when an OC model's plateau shift reads them (node.runtime.plateaus)
        self._plateaus = RunPlateaus(len(bundle.schedule.names)) if shifts else None

    def step(self, sample: AlignedSample) -> tuple[dict, dict | None]:
        self.transient = None
        if self.verdicts:
            self.verdicts = []
        if sample.new_run:
            self._new_run()
        values = sample.values
        vals = self._filled(values)
        detector = self.detector
        st = detector.state if self._follows else detector.step(values.get(self.switch, _NAN))
        phase = st.phase
        oc = detector.segment  # the model in force (the start's apart from its OC's)
        oc_changed = oc != self._state[0]
        if self._curve is not None:
            vals[RUN_CURVE] = self._curve.step(vals[self.switch], vals[self.target], oc_changed)
        if self._chirp is not None:
            vals[CHIRP_RATE] = self._chirp.step(vals[self.switch])
        # stepped with or without history inputs: the bed's engine history stays known
        known = self.history.step(sample.t, vals[self.switch],
                                  tuple([vals[c] for c in self._slow]) if self._slow else _NO_SLOW)
        if self._uses_history:
            vals.update(zip(HISTORY_CHANNELS, known))
        oc_msg = None
        if oc_changed or phase != self._state[1]:
            oc_msg = self._switch(sample.t, oc, phase, oc_changed)
        measured = values.get(self.target, _NAN)
        # one dict literal per sample, its keys in the contract's order (the JSON bytes follow it)
        if self._uses_phase:
            phase_deg = values.get(self._phase_ch, _NAN)
            z = order_vector(measured, phase_deg)
            msg = {"t": sample.t, "oc": None if oc is None else self._names[oc], "phase": _PHASE[phase],
                   "measured": _num(measured), "predicted": None, "residual": None, "flag": _NO_MODEL,
                   "score": None, "band": None, "model": None, "reason": None,
                   "run_scale": None, "envelope": None, "measured_phase": _num(phase_deg),
                   "predicted_phase": None, "vector_residual": None, "vector_score": None}
        else:
            z = NAN_VECTOR
            msg = {"t": sample.t, "oc": None if oc is None else self._names[oc], "phase": _PHASE[phase],
                   "measured": _num(measured), "predicted": None, "residual": None, "flag": _NO_MODEL,
                   "score": None, "band": None, "model": None, "reason": None,
                   "run_scale": None, "envelope": None}
        verdict = self._verdict
        if verdict is not None:
            speed = vals[self.switch]
            name = None if oc is None else self._names[oc]
            lim = msg["limit"] = limit_in_force(self._limits, speed, name)
            msg["over_limit"] = lim is not None and measured > lim
            verdict.step(sample.t, name, speed, measured, lim)
            if oc_msg is not None and oc_msg["oc"] != oc_msg["previous"]:  # an OC switch: the verdict
                stopped = oc_msg["oc"] is None and speed < self.detector.off_level  # the run's end
                v = verdict.end(sample.t) if stopped else verdict.switch(sample.t, oc_msg["oc"])
                if v is not None:
                    self.verdicts.append(v)
        active = self._active
        if active is not None:
            self._predict(active, vals, measured, msg, z)
            active.since += 1
        steady = phase is _STEADY
        if self._jump is not None:
            self._jump.step(measured, steady)
            if self._jump.flagged:
                msg["flag"], msg["reason"] = Flag.ALARM, Reason.STEP
        if self._vector:
            self._watch_vector(self._vector, z, steady, msg)
        if self._flat is not None and self._flat.step(measured, phase is not _OFF):
            msg["flag"], msg["reason"] = Flag.ALARM, Reason.FLATLINE
        self._hist.push(tuple(vals.values()))
        if self._plateaus is not None:
            self._plateaus.step(z if self._plateau_vector else measured)
        tw = self._transient
        ended = tw.step(sample.t, values.get(tw.speed, _NAN), values.get(self.switch, _NAN), measured,
                        values.get(self._phase_ch) if self._tr_phase else None)
        if ended is not None:
            self.transient = ended
        return msg, oc_msg

    def end_verdict(self) -> dict | None:
        """The stream ended: the verdict of the run going on (None: none, or no limits)."""
        return self._verdict.end() if self._verdict is not None else None

    def end_transient(self) -> dict | PendingTransient | None:
        """The stream ended: the transition in progress analysed, its message (None: none)."""
        return self._transient.end()

    def defer_transients(self) -> None:
        """From now on a transition's end gives a ``PendingTransient`` (the live node analyses it
        off its worker thread), not its message."""
        self._transient.defer = True

    @property
    def transients_dropped(self) -> int:
        """Transitions too long to analyse (over the analyser's bound), dropped."""
        return self._transient.dropped

    def _predict(self, a: _Active, vals: dict[str, float], measured: float, msg: dict, z: complex) -> None:
        """Step the model in force when its inputs are known, and its residual rule; into msg
        (z: the measured 1x vector, for a model that predicts it)."""
        u = [vals[c] for c in a.inputs]
        for x in u:
            if x - x != 0.0:  # an input never seen yet in this run
                return
        env, model_id, widen, e = a.envelope, a.model_id, 1.0, None
        if env is not None:  # beyond it: inputs held at its edge, the band widened, both said
            e = env.distance(u, a.since / FS)
            u = env.clamp(u)
            if e > OUTSIDE:
                model_id, widen = model_id + HELD, env.band_factor
        pred = raw = a.runtime.step(u)
        if a.shift != 0.0:
            pred = pred + PlateauShift.ramp(a.since) * a.shift
        if a.settle is not None:
            pred = self._settled(a, measured, pred)
        on, own = False, pred
        if self._guard is not None:
            pred, on = self._guard.step(measured, pred, vals[self.switch])
            if on:
                model_id += CURVE
        r = measured - pred if math.isfinite(measured) and math.isfinite(pred) else _NAN
        check = a.check
        if on:  # the run scale measures the model's own residuals, as training calibrated it
            score, raised = check.step(r / widen, (measured - own) / widen)
        else:
            score, raised = check.step(r / widen if widen != 1.0 else r)
        msg["predicted"] = _num(pred)
        msg["residual"] = None if r != r else r
        msg["score"] = score
        msg["band"] = check.band * widen if widen != 1.0 else check.band
        msg["model"] = model_id
        msg["run_scale"] = check.run_scale
        msg["envelope"] = e
        if a.vector is not None and not on:
            v = a.vector.vector
            m = abs(v)
            if pred != raw and m > 0.0:  # moved (plateau shift, settle anchor): along its own direction
                v = v * ((m + (pred - raw)) / m)
            msg["predicted_phase"] = _num(lag_degrees(v))
            msg["vector_residual"] = _num(abs(z - v))
        if raised:
            msg["flag"], msg["reason"] = Flag.ALARM, Reason.RESIDUAL
        else:
            msg["flag"] = _OK

    @staticmethod
    def _watch_vector(checks: list[StepCheck], z: complex, steady: bool, msg: dict) -> None:
        """The vector rule on this sample's 1x vector z (NaN when amplitude or phase is null;
        steady: on a steady plateau): ``vector_score`` the larger statistic over its threshold
        (alarm beyond 1; the first of equal ones, as ``max``)."""
        score = None
        flagged = False
        for chk in checks:
            x = chk.step(z, steady) / chk.threshold
            if score is None or x > score:
                score = x
            flagged = flagged or chk.flagged
        msg["vector_score"] = score
        if flagged and msg["flag"] is not Flag.ALARM:
            msg["flag"], msg["reason"] = Flag.ALARM, Reason.VECTOR

    def _name(self, oc: int | None) -> str | None:
        return None if oc is None else self._names[oc]

    @staticmethod
    def _settled(a: _Active, measured: float, pred: float) -> float:
        """The prediction moved by the OC's settle anchor (``SettleAnchor.moved``, sample by
        sample: the window's residuals kept, the move from ``SETTLE_AT`` on)."""
        since = a.since
        if since < SETTLE_AT:
            if since >= SETTLE_AT - SETTLE_WINDOW:
                a.window.append(measured - pred)
            return pred
        if a.moved is None:
            a.moved = a.settle.offset(a.window) if a.settle is not None else 0.0
            a.window.clear()
        return pred + a.moved if a.moved != 0.0 else pred

    def _new_run(self) -> None:
        """A new run: the detector restarts off (reset by the pipeline that steps it), every rule
        and the held values afresh."""
        if not self._follows:
            self.detector.reset()
        self.transient = self._transient.end()  # the last run's last transition (its coast-down)
        ended = self.end_verdict()  # the last run's verdict, if it did not stop
        if ended is not None:
            self.verdicts.append(ended)
        self._hist.clear()
        self._last = dict.fromkeys(self.channels, _NAN)
        for rule in (self._flat, self._jump, *self._vector, self._runscale, self._curve, self._chirp,
                     self._plateaus):
            if rule is not None:
                rule.reset()
        self._active = None  # its segment is not this run's: RunScale never hears of it

    def _switch(self, t: float, oc: int | None, phase: Phase, oc_changed: bool) -> dict | None:
        """The model (``oc``: its index) or phase changed at this sample: the OC's model in force,
        and the OC message (None: the OC and phase it names unchanged, the start's model ending)."""
        prev, before = self._state
        if oc_changed:
            if self._plateaus is not None:
                self._plateaus.switch(oc)
            self._activate(oc)
            if self._drift is not None and oc is not None:
                self._drift.threshold = self._drift_thr[oc]
        self._state = (oc, phase)
        name, was = self._name(oc), self._name(prev)
        if name == was and phase is before:
            return None
        return {"t": t, "oc": name, "phase": phase.value, "previous": was}

    def _filled(self, values: dict[str, float]) -> dict[str, float]:
        """Hold each channel's last finite value over dropouts (NaN before the first); in place."""
        last = self._last
        for c in self.channels:
            v = values.get(c)
            if v is not None and v - v == 0.0:  # finite
                last[c] = v
        return last

    def _activate(self, oc: int | None) -> None:
        """The model of OC ``oc`` (None: no model) takes over, seeded from the measured past."""
        done = self._active
        if done is not None and self._runscale is not None and done.check.count:
            self._runscale.add(done.check.mean_sq)
        self._active = None
        if oc is None:
            return
        res = self.bundle.oc(self._models[oc])
        if res is None or res.model is None or res.calibration is None:
            return
        rt = res.model.runtime()
        vector = rt if isinstance(rt, (CurveRuntime, AverageRuntime)) and predicts_vector(res.model) else None
        cols = [self.channels.index(c) for c in [self.target, *res.inputs]]
        if self._hist:
            full = self._hist.array()
            H = full[:, cols]
            ok = np.all(np.isfinite(H), axis=1)
            first = int(np.argmax(ok)) if ok.any() else len(H)  # history from the first complete row
            y, U = H[first:, 0], H[first:, 1:]
            if vector is None:
                rt.start(y, U)
            else:  # its past: the 1x vectors (an average's vector members), and the amplitudes
                z = order_vectors(y, full[first:, self.channels.index(self._phase_ch)])
                if isinstance(vector, AverageRuntime):
                    vector.start(y, U, z)
                else:
                    vector.start(z, U)
        else:
            rt.start(np.zeros(0), np.zeros((0, len(res.inputs))))
        if self._guard is not None:
            self._guard.reset()
        c = res.calibration
        scale = 1.0 if self._runscale is None else self._runscale.factor
        check = ResidualCheck(c.sigma, c.threshold, c.ewma_alpha, c.persist, self._clear, scale)
        shift = 0.0
        if res.plateau is not None and self._plateaus is not None:
            shift = res.plateau.shift(self._plateaus.pre, self._plateaus.levels)
        self._active = _Active(rt, list(res.inputs), f"{res.model.method.value}:{res.name}", check, vector,
                               res.envelope, shift=shift, settle=res.settle)
