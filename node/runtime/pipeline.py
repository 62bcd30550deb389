"""The node's numerics, free of I/O: aligned samples in, monitor messages out.

Live (Zenoh) and offline replay feed the very same ``MonitorPipeline``, so
they give the very same numbers. Per sample: the OC detector steps on the
switch speed; at an OC switch the OC's model is seeded from the measured
past (a bounded ring buffer) and then steps once per sample; the residual is
standardized by the OC's cross-validated sigma, smoothed (EWMA) and flagged
when beyond the OC's threshold for long enough (``reason`` "residual"); it clears
once back under the threshold for ``RESIDUAL_CLEAR_S`` (an off-delay against chatter). A
model-free checks flag, with or without a model, an abrupt step of the measured
target during a steady plateau (``reason`` "step") and a target stuck on one
value while the engine runs (``reason`` "flatline"); see ``node.runtime.alarms``.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from node.contract import FS, Flag, Phase, Reason
from node.models.bundle import Bundle
from node.models.ocmodel import OCRuntime
from node.runtime.alarms import RESIDUAL_CLEAR_S, FlatlineCheck, RunScale, StepCheck
from node.runtime.align import AlignedSample
from node.runtime.ocdetect import OCDetector
from node.runtime.runcurve import RUN_CURVE, RunCurve

CLEAR_SAMPLES = int(RESIDUAL_CLEAR_S * FS)


@dataclass
class _Active:
    oc: int
    runtime: OCRuntime | None
    inputs: list[str]
    sigma: float
    threshold: float
    alpha: float
    persist: int
    model_id: str
    run_scale: float = 1.0


def _num(x: float) -> float | None:
    return None if not math.isfinite(x) else float(x)


class MonitorPipeline:
    """Stateful per-bed pipeline (bounded memory: ``history_s`` of samples).

    ``step(sample)`` returns ``(monitor_message, oc_message_or_None)`` as dicts
    ready for JSON (contract section 2).
    """

    def __init__(self, bundle: Bundle) -> None:
        self.bundle = bundle
        self.target = bundle.target
        self.switch = bundle.schedule.switch
        self.detector = OCDetector(bundle.schedule, FS)
        self._names = bundle.schedule.names  # a tuple built on each access: keep one
        self.channels = sorted({self.switch, self.target, *bundle.inputs})
        # what the test bed publishes: the derived run_curve is computed here, never awaited
        self.sensor_channels = [c for c in self.channels if c != RUN_CURVE]
        self._hist: deque[tuple[float, ...]] = deque(maxlen=int(bundle.history_s * FS))
        self._last: dict[str, float] = dict.fromkeys(self.channels, math.nan)  # in channel order
        self._state: tuple[int | None, Phase] = (None, Phase.OFF)
        self._active: _Active | None = None
        self._score = 0.0
        self._beyond = 0
        self._below = 0
        self._raised = False
        limit = bundle.checks.get("flatline_samples")
        self._flat = FlatlineCheck(int(limit)) if limit else None
        thr = bundle.checks.get("step_threshold")
        self._jump = StepCheck(float(thr), FS) if thr else None
        prior = bundle.checks.get("run_scale_prior_ocs")
        self._runscale = RunScale(float(prior)) if prior else None
        self._zsum, self._zn = 0.0, 0  # squared standardized residuals of the active OC
        self._curve = None  # this run's own characteristic, when a model takes it as input
        if RUN_CURVE in self.channels and bundle.curve is not None:
            self._curve = RunCurve(*bundle.curve)

    def _filled(self, values: dict[str, float]) -> dict[str, float]:
        """Hold each channel's last finite value over dropouts (NaN before the first); in place."""
        last = self._last
        for c in self.channels:
            v = values.get(c)
            if v is not None and v - v == 0.0:  # finite
                last[c] = v
        return last

    def _activate(self, oc: int | None) -> None:
        if self._runscale is not None and self._zn:
            self._runscale.add(self._zsum / self._zn)
        self._zsum, self._zn = 0.0, 0
        self._active = None
        self._score, self._beyond, self._below, self._raised = 0.0, 0, 0, False
        if oc is None:
            return
        res = self.bundle.oc(self._names[oc])
        if res is None or res.model is None or res.calibration is None:
            return
        rt = res.model.runtime()
        cols = [self.channels.index(c) for c in [self.target, *res.inputs]]
        if self._hist:
            H = np.asarray(self._hist)[:, cols]
            ok = np.all(np.isfinite(H), axis=1)
            H = H[np.argmax(ok):] if ok.any() else H[:0]  # history from the first complete row
            rt.start(H[:, 0], H[:, 1:])
        else:
            rt.start(np.zeros(0), np.zeros((0, len(res.inputs))))
        c = res.calibration
        self._active = _Active(oc, rt, list(res.inputs), c.sigma, c.threshold, c.ewma_alpha,
                               c.persist, f"{self.bundle.method}:{res.name}",
                               1.0 if self._runscale is None else self._runscale.factor)

    def step(self, sample: AlignedSample) -> tuple[dict, dict | None]:
        if sample.new_run:
            self.detector.reset()
            self._hist.clear()
            self._last = dict.fromkeys(self.channels, math.nan)
            if self._flat is not None:
                self._flat.reset()
            if self._jump is not None:
                self._jump.reset()
            if self._runscale is not None:
                self._runscale.reset()
            self._zsum, self._zn = 0.0, 0
            if self._curve is not None:
                self._curve.reset()
        vals = self._filled(sample.values)
        st = self.detector.step(sample.values.get(self.switch, float("nan")))
        oc_msg = None
        names = self._names
        prev_oc = self._state[0]
        oc_changed = st.oc != prev_oc
        if self._curve is not None:
            vals[RUN_CURVE] = self._curve.step(vals[self.switch], vals[self.target], oc_changed)
        if oc_changed or st.phase != self._state[1]:
            if oc_changed:
                self._activate(st.oc)
            oc_msg = {"t": sample.t, "oc": None if st.oc is None else names[st.oc],
                      "phase": st.phase.value, "previous": None if prev_oc is None else names[prev_oc]}
            self._state = (st.oc, st.phase)
        measured = sample.values.get(self.target, float("nan"))
        msg = {"t": sample.t, "oc": None if st.oc is None else names[st.oc], "phase": st.phase.value,
               "measured": _num(measured), "predicted": None, "residual": None, "flag": Flag.NO_MODEL,
               "score": None, "band": None, "model": None, "reason": None,
               "run_scale": None}
        a = self._active
        if a is not None and a.runtime is not None:
            u = [vals[c] for c in a.inputs]
            if all(x - x == 0.0 for x in u):
                pred = a.runtime.step(u)
                msg["predicted"] = _num(pred)
                msg["model"] = a.model_id
                msg["band"] = a.threshold * a.sigma * a.run_scale
                msg["run_scale"] = a.run_scale
                if math.isfinite(measured) and math.isfinite(pred):
                    r = measured - pred
                    z = r / a.sigma
                    self._zsum += z * z
                    self._zn += 1
                    self._score = (1.0 - a.alpha) * self._score + a.alpha * z / a.run_scale
                    if abs(self._score) > a.threshold:
                        self._beyond, self._below = self._beyond + 1, 0
                    else:
                        self._beyond, self._below = 0, self._below + 1
                    # on-delay (persist) to raise, off-delay to clear: no chattering alarm
                    if self._beyond >= a.persist:
                        self._raised = True
                    elif self._below >= CLEAR_SAMPLES:
                        self._raised = False
                    msg["residual"] = r
                msg["score"] = self._score
                if self._raised:
                    msg["flag"], msg["reason"] = Flag.ALARM, Reason.RESIDUAL
                else:
                    msg["flag"] = Flag.OK
        if self._jump is not None:
            self._jump.step(measured, st.phase is Phase.STEADY)
            if self._jump.flagged:
                msg["flag"], msg["reason"] = Flag.ALARM, Reason.STEP
        if self._flat is not None and self._flat.step(measured, st.phase is not Phase.OFF):
            msg["flag"], msg["reason"] = Flag.ALARM, Reason.FLATLINE
        self._hist.append(tuple(vals.values()))
        return msg, oc_msg
