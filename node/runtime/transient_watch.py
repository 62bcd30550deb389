"""One target's transitions watched sample by sample: the ``monitor/transient`` message of each.

A ``TransientWatch`` steps a ``RampAnalyser`` (``node.runtime.ramp_analyser``) once per aligned
sample on the target's 1x amplitude (and phase, where the model uses it) against the speed of
the channel its settings name (the target's own shaft; default the schedule's switch channel).
At a transition's end it returns the message of contract section 2: each critical's speed is
stated in rpm of the switch channel (the switch channel's speed where the analysed shaft passed
the critical: both speeds averaged over 1 s, the switch's read at the shaft's critical), with
the fleet's expected speed and the shift where the model holds the fleet's transients
(``node.models.transients``). Pure: the same in the live node, replay and training.

>>> import numpy as np
>>> from node.contract.schedule import OperatingCondition, Schedule
>>> sched = Schedule((OperatingCondition("A", 9000.0),))
>>> w = TransientWatch("yB", sched, None)
>>> speed = np.concatenate([np.full(200, 3000.0), np.linspace(3000, 9000, 2400), np.full(400, 9000.0)])
>>> r = speed / 6000
>>> v = speed * r**2 / (1 - r**2 + 0.1j * r) * 1e-3
>>> out = [w.step(k / 40, s, s, a, None) for k, (s, a) in enumerate(zip(speed, np.abs(v)))]
>>> [(m["direction"], m["kind"], round(m["criticals"][0]["speed"], -1), m["flag"].value)
...  for m in out if m is not None]
[('up', 'up 35%->A', 6000.0, 'no-model')]
"""

from __future__ import annotations

import math

import numpy as np

from node.contract import CHANNEL_UNITS, Flag, Reason
from node.contract.schedule import Schedule
from node.models.transients import FleetTransients, Resonance, TransientSettings, transition_kind
from node.runtime.ramp_analyser import RampAnalyser
from node.runtime.transient import Transient, smoothed

VELOCITY_UNIT = "mm/s"  # a target in this unit is a velocity: divided by the speed (the displacement)


def _num(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


class PendingTransient:
    """A transition that ended, not yet analysed (a ``TransientWatch`` with ``defer``): ``resolve``
    gives the very message the watch would have given at once (None: too few samples). The live
    node resolves it in another process (``job``, ``message_of_job``), so that a ramp's analysis
    (tens of ms, per target and bed) never stalls the other beds' monitoring."""

    __slots__ = ("_watch", "ramp")

    def __init__(self, watch: TransientWatch, ramp: np.ndarray) -> None:
        self._watch = watch
        self.ramp = ramp  # (K, 4 or 5): the transition's samples (RampAnalyser.take)

    def resolve(self) -> dict | None:
        return self._watch.message_of(self.ramp)

    def job(self) -> tuple[str, Schedule, FleetTransients | None, TransientSettings, np.ndarray]:
        """What ``message_of_job`` needs to give ``resolve``'s message in another process: plain
        data (the watch's target, schedule, fleet and settings, and the ramp)."""
        w = self._watch
        return w.target, w.schedule, w.fleet, w.settings, self.ramp


def message_of_job(target: str, schedule: Schedule, fleet: FleetTransients | None,
                   settings: TransientSettings, ramp: np.ndarray) -> dict | None:
    """A ``PendingTransient``'s message from its ``job`` (a watch of the same target, schedule,
    fleet and settings: the same analysis, the same message to the last bit)."""
    return TransientWatch(target, schedule, fleet, settings).message_of(ramp)


class TransientWatch:
    """The transitions of one target (see the module docstring).

    target: the modelled channel; schedule: its model's (the switch channel, the OCs' plateaus
    that name the kinds of transition); fleet: the model's fleet transients (None: a model
    trained without them: no expected speed, flag ``no-model``); settings: how to analyse
    (default the fleet's, else ``TransientSettings()``). ``speed``: the channel analysed on;
    ``dropped``: ramps too long to analyse (bounded memory); ``defer``: False (default) analyses
    a transition as it ends, True returns a ``PendingTransient`` instead.
    """

    def __init__(self, target: str, schedule: Schedule, fleet: FleetTransients | None,
                 settings: TransientSettings | None = None) -> None:
        self.target = target
        self.fleet = fleet
        self.settings = settings or (fleet.settings if fleet is not None else TransientSettings())
        self.schedule = schedule
        self.switch = schedule.switch
        self.speed = self.settings.speed or schedule.switch
        self._plateaus = [(oc.name, oc.speed) for oc in schedule.ocs]
        self._own = self.speed != self.switch  # the switch speed is carried along to map to
        self.analyser = RampAnalyser(tracker_tau=self.settings.tracker_s,
                                     velocity=CHANNEL_UNITS.get(target) == VELOCITY_UNIT,
                                     min_amplitude=self.settings.min_amplitude)
        self.defer = False  # True: a transition's end gives a PendingTransient, analysed later

    @property
    def dropped(self) -> int:
        return self.analyser.dropped

    def step(self, t: float, speed: float, switch: float, amplitude: float,
             phase: float | None) -> dict | PendingTransient | None:
        """One aligned sample (t s; the analysed channel's and the switch channel's speeds, rpm;
        the target's amplitude; its phase lag, degrees, or None): the transient message of a
        transition that ended with it (with ``defer``: its ``PendingTransient``), else None."""
        ramp = self.analyser.step_ramp(speed, amplitude, phase, (t, switch) if self._own else (t,))
        return None if ramp is None else self._ended(ramp)

    def end(self) -> dict | PendingTransient | None:
        """The data ended (a new run, the end of the stream): the transition in progress analysed
        now (with ``defer``: its ``PendingTransient``), its message (None: none, or too short);
        the watch then starts afresh."""
        ramp = self.analyser.take()
        self.analyser.reset()
        return None if ramp is None else self._ended(ramp)

    def _ended(self, ramp: np.ndarray) -> dict | PendingTransient | None:
        return PendingTransient(self, ramp) if self.defer else self.message_of(ramp)

    def message_of(self, ramp: np.ndarray) -> dict | None:
        """The message of a transition whose samples (``RampAnalyser.take``'s) are ``ramp``: it is
        analysed now (None: too few samples). Reads the watch's settings and fleet, which never
        change, and changes nothing: safe in another thread."""
        tr = self.analyser.analysis_of(ramp)
        return None if tr is None else self._message(tr, ramp)

    def _message(self, tr: Transient, ramp: np.ndarray) -> dict:
        """The contract's message of a transition analysed (``tr``) from its samples ``ramp``."""
        t = ramp[:, 3]
        if self._own:
            sw = smoothed(ramp[:, 4], int(self.analyser.fs))
            own = smoothed(ramp[:, 0], int(self.analyser.fs))
            order = np.argsort(own, kind="stable")
            ok = np.isfinite(sw[order]) & np.isfinite(own[order])

            def to_switch(nc: float) -> float:
                return float(np.interp(nc, own[order][ok], sw[order][ok])) if ok.any() else math.nan
            raw = smoothed(ramp[:, 4], 1)  # gaps filled
            first, last = float(raw[0]), float(raw[-1])
        else:
            def to_switch(nc: float) -> float:
                return nc
            first, last = tr.from_speed, tr.to_speed
        kind = transition_kind(tr.direction, first, last, self._plateaus)
        fleet = self.fleet
        # the fleet's resonances matched by mode order under one common ratio (FleetTransients.match)
        ascending = sorted(range(len(tr.criticals)), key=lambda i: tr.criticals[i].speed)
        matched: dict[int, Resonance] = {}
        if fleet is not None:
            for i, res in zip(ascending, fleet.match(kind, [tr.criticals[i].speed for i in ascending])):
                if res is not None:
                    matched[i] = res
        n_kind = fleet.kinds[kind].transitions if fleet is not None and kind in fleet.kinds else 0
        alarm = False
        crits = []
        for i, c in enumerate(tr.criticals):
            speed = to_switch(c.speed)
            expected = shift = limit = expected_af = af_rise = af_limit = None
            if fleet is not None and i in matched:
                res = matched[i]
                shift, limit = fleet.shifted(res, c.speed, n_kind)
                rise, af_limit = fleet.af_rise(res, c.af, n_kind)
                af_rise = _num(rise)
                expected, expected_af = res.speed.mean, res.af.mean
                alarm = (alarm or (limit is not None and abs(shift) > limit)
                         or (af_limit is not None and af_rise is not None and af_rise > af_limit))
            crits.append({"speed": _num(speed), "amplitude": _num(c.amplitude),
                          "phase_change": _num(c.phase_change), "af": _num(c.af),
                          "expected_speed": expected, "shift": shift,
                          "shift_rpm": None if expected is None else _num(speed - expected), "limit": limit,
                          "expected_af": expected_af, "af_rise": af_rise, "af_limit": af_limit,
                          "af_method": c.af_method, "zeta": _num(c.zeta), "shaft_speed": _num(c.speed)})
        dur = (t[-1] - t[0]) if len(t) > 1 else math.nan
        flag = Flag.NO_MODEL if fleet is None else Flag.ALARM if alarm else Flag.OK
        return {"t": float(t[-1]), "target": self.target, "direction": tr.direction,
                "from_speed": _num(first), "to_speed": _num(last), "criticals": crits, "flag": flag,
                "reason": Reason.TRANSIENT if alarm else None, "kind": kind,
                "rate": _num((last - first) / dur) if dur > 0 else None, "speed_channel": self.speed}
