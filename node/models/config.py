"""The settings that define how a trained model behaves at run time, stored in its bundle.

A bundle keeps behaving as it did when it was trained: every timing the node's
per-sample logic uses (the aligner's wait, the OC detector's timings, the alarm
rules' windows and delays, the run-curve bin) is read from the bundle's
``RuntimeConfig``, never from a module constant. Bundles of format version 1,
written before the settings were stored, get the values those versions had in
code: the defaults below, but for ``V1_SETTINGS``.

A bundle is untrusted input: every setting has a range (``RANGES``, each with its
reason), and a value outside it is a ``SettingError`` naming the setting, never a node
that fails later (``history_s = 1e300`` overflowed on the 9th message) or one that
looks healthy and publishes nothing (``align_wait_s = 1e300``).

>>> c = RuntimeConfig()
>>> c.align_wait_s, c.residual_clear_s
(0.25, 5.0)
>>> RuntimeConfig.from_dict(c.to_dict()) == c
True
>>> RuntimeConfig.from_dict({"align_wait_s": -1})  # doctest: +ELLIPSIS
Traceback (most recent call last):
...
node.models.config.SettingError: runtime.align_wait_s = -1 is outside [0, 10] s (a slot waits ...)
>>> RuntimeConfig(history_s=1e300)  # doctest: +ELLIPSIS
Traceback (most recent call last):
...
node.models.config.SettingError: runtime.history_s = 1e+300 is outside (0, 600] s (measured past ...)
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from typing import Any, NamedTuple

from node.contract import FS, OFF_FRACTION

V1_SETTINGS = {"align_wait_s": 0.1}  # where bundles of format version 1 differ from the defaults
BEFORE_GUARD = {"guard_wait_s": 0.0}  # bundles stored before the curve guard keep it off


@dataclass(frozen=True)
class RuntimeConfig:
    """Run-time settings of the node's per-sample logic (seconds unless said).

    Attributes:
        align_wait_s: newer data after which an incomplete 40 Hz slot is emitted anyway (and
            a run's first slot; complete slots go out at once). 0.25 s covers a reordering
            of 0.2 s at any clock phases (0.1 s, format 1's value, leaves a 0.1 s one borderline).
        history_s: measured past kept to seed an OC's model at a switch.
        residual_clear_s: a residual alarm clears after this long back under its threshold.
        episode_gap_s: alarm samples of one rule less than this apart form one episode.
        run_curve_bin: speed bin of the derived ``run_curve`` input, in the switch unit (rpm).
        detector_smooth_s: causal moving average of the switch speed.
        detector_confirm_s: time within the band of the expected plateau to call it steady.
        detector_depart_s: time beyond half the band to call a departure.
        detector_settle_s: time of near-constant speed to accept an unexpected plateau.
        detector_off_fraction: below this fraction of the highest plateau the engine is off
            (the contract's ``OFF_FRACTION`` of a shaft's maximum, ``node.contract.off_speed``).
        step_settle_s: the first seconds of a plateau the step rule leaves out.
        step_short_s: the step rule's recent window.
        step_long_s: its reference window, just before the recent one.
        step_noise_s: EWMA span of its noise estimate.
        step_persist_s: how long its statistic must stay beyond the threshold.
        history_cooling: energy the engine-history input ``hist_energy`` loses per hour of
            shutdown, rpm min per h (``node.runtime.history``); training estimates it from
            its runs, the default is the dissertation's one-engine value 4.5e5 / 12.
        guard_wait_s: samples an OC model and the characteristic curve are compared on within
            an OC visit (their errors so far) before the curve may take over
            (``node.runtime.guard``); 0: never (the guard off).
        guard_margin: the guard's hysteresis: the curve takes over beyond ``1 + margin`` times
            its error so far, the model again below ``1 / (1 + margin)`` times it.
    """

    align_wait_s: float = 0.25
    history_s: float = 60.0
    residual_clear_s: float = 5.0
    episode_gap_s: float = 1.0
    run_curve_bin: float = 50.0
    detector_smooth_s: float = 0.25
    detector_confirm_s: float = 1.0
    detector_depart_s: float = 0.25
    detector_settle_s: float = 5.0
    detector_off_fraction: float = OFF_FRACTION
    step_settle_s: float = 3.0
    step_short_s: float = 1.0
    step_long_s: float = 4.0
    step_noise_s: float = 10.0
    step_persist_s: float = 0.25
    history_cooling: float = 4.5e5 / 12.0
    guard_wait_s: float = 5.0
    guard_margin: float = 0.1

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            RANGES[f.name].check(f"runtime.{f.name}", v)
            object.__setattr__(self, f.name, float(v))

    def to_dict(self) -> dict[str, float]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: Any, **defaults: float) -> RuntimeConfig:
        """From a manifest's ``runtime`` object; unknown keys are an error (ValueError)."""
        if not isinstance(d, dict):
            raise ValueError(f"runtime must be an object, got {type(d).__name__}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ValueError(f"unknown runtime setting(s): {', '.join(unknown)}")
        return cls(**{**defaults, **d})


class SettingError(ValueError):
    """A run-time setting that is not a finite number within its range (one line naming it)."""


class Range(NamedTuple):
    """A setting's allowed values: from ``low`` to ``high`` (``open_low``: ``low`` excluded,
    ``open_high``: ``high`` excluded), in ``unit``, and why."""

    low: float
    high: float
    unit: str
    why: str
    open_low: bool = False
    open_high: bool = False

    def __str__(self) -> str:
        return (f"{'(' if self.open_low else '['}{self.low:g}, {self.high:g}{')' if self.open_high else ']'}"
                + (f" {self.unit}" if self.unit else ""))

    def check(self, what: str, v: object) -> None:
        """A ``SettingError`` unless ``v`` is a number (not a bool) within the range."""
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise SettingError(f"{what} must be a number, got {v!r}")
        inside = (v > self.low if self.open_low else v >= self.low) and \
            (v < self.high if self.open_high else v <= self.high)  # (NaN: never inside)
        if not inside:
            raise SettingError(f"{what} = {v!r} is outside {self} ({self.why})")


# Each setting's range and why. The upper bounds are far beyond any value training writes (it
# writes the defaults, and estimates history_cooling on a grid up to 1e7) and keep every count
# of samples the node derives from a setting (seconds x 40 Hz) a small integer.
RANGES: dict[str, Range] = {
    "align_wait_s": Range(0.0, 10.0, "s", "a slot waits this long for a late channel and every "
                          "output with it: beyond 10 s the node publishes nothing for that long while "
                          "it looks healthy"),
    "history_s": Range(0.0, 600.0, "s", "measured past kept per bed to seed a model at a switch: "
                       "none seeds nothing, beyond 10 min it is memory no model reads", open_low=True),
    "residual_clear_s": Range(0.0, 600.0, "s", "a residual alarm holds this long after the residual "
                              "is back: beyond 10 min it hides the next one"),
    "episode_gap_s": Range(0.0, 600.0, "s", "alarm samples closer than this are one episode: beyond "
                           "10 min the alarms of separate plateaus merge"),
    "run_curve_bin": Range(0.01, 1e5, "", "the switch speed (rpm, or % speed) is divided by it: 0 "
                           "fails on the first sample, less than 0.01 bins the speed noise, more than "
                           "1e5 puts every speed in one bin"),
    "detector_smooth_s": Range(0.0, 10.0, "s", "moving average of the switch speed: beyond 10 s it "
                               "smears the transitions it must find"),
    "detector_confirm_s": Range(0.0, 60.0, "s", "time within the band to call a plateau steady: "
                                "beyond a minute short plateaus are never steady"),
    "detector_depart_s": Range(0.0, 60.0, "s", "time beyond half the band to call a departure: "
                               "beyond a minute transitions are seen when they are over"),
    "detector_settle_s": Range(0.0, 600.0, "s", "time of near-constant speed to accept an unexpected "
                               "plateau: beyond 10 min none is"),
    "detector_off_fraction": Range(0.0, 1.0, "", "a fraction of the highest plateau below which the "
                                   "engine is off: 1 or more calls every plateau off", open_high=True),
    "step_settle_s": Range(0.0, 600.0, "s", "the first seconds of a plateau the step rule leaves "
                           "out: beyond 10 min it leaves out whole plateaus"),
    "step_short_s": Range(0.0, 60.0, "s", "the step rule's recent window: beyond a minute a step "
                          "is found a minute late"),
    "step_long_s": Range(0.0, 600.0, "s", "the step rule's reference window: beyond 10 min it "
                         "outlasts the plateaus"),
    "step_noise_s": Range(1.0 / FS, 600.0, "s", "EWMA span of the step rule's noise: shorter than "
                          "one sample weighs it above 1 (a diverging estimate), beyond 10 min it "
                          "never follows the noise"),
    "step_persist_s": Range(0.0, 60.0, "s", "how long the step statistic must stay beyond its "
                            "threshold: beyond a minute a step is found a minute late"),
    "history_cooling": Range(0.0, 1e9, "rpm min per h", "hist_energy lost per hour of shutdown; "
                             "training searches up to 1e7: beyond 1e9 any run's energy is gone "
                             "within seconds of standing"),
    "guard_wait_s": Range(0.0, 600.0, "s", "an OC model and the curve are compared this long before "
                          "the curve may take over: 0 turns the guard off, beyond 10 min it never acts"),
    "guard_margin": Range(0.0, 100.0, "", "the guard's hysteresis, a fraction of the curve's error: "
                          "beyond 100 the curve never takes over"),
}
