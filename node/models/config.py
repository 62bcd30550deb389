"""The settings that define how a trained model behaves at run time, stored in its bundle.

A bundle keeps behaving as it did when it was trained: every timing the node's
per-sample logic uses (the aligner's wait, the OC detector's timings, the alarm
rules' windows and delays, the run-curve bin) is read from the bundle's
``RuntimeConfig``, never from a module constant. Bundles of format version 1,
written before the settings were stored, get the values those versions had in
code: the defaults below, but for ``V1_SETTINGS``.

>>> c = RuntimeConfig()
>>> c.align_wait_s, c.residual_clear_s
(0.25, 5.0)
>>> RuntimeConfig.from_dict(c.to_dict()) == c
True
>>> RuntimeConfig.from_dict({"align_wait_s": -1})
Traceback (most recent call last):
...
ValueError: runtime.align_wait_s must be a finite number >= 0, got -1
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any

V1_SETTINGS = {"align_wait_s": 0.1}  # where bundles of format version 1 differ from the defaults


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
        detector_off_fraction: below this fraction of the highest plateau the engine is off.
        step_settle_s: the first seconds of a plateau the step rule leaves out.
        step_short_s: the step rule's recent window.
        step_long_s: its reference window, just before the recent one.
        step_noise_s: EWMA span of its noise estimate.
        step_persist_s: how long its statistic must stay beyond the threshold.
        history_cooling: energy the engine-history input ``hist_energy`` loses per hour of
            shutdown, rpm min per h (``node.runtime.history``); training estimates it from
            its runs, the default is the dissertation's one-engine value 4.5e5 / 12.
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
    detector_off_fraction: float = 0.05
    step_settle_s: float = 3.0
    step_short_s: float = 1.0
    step_long_s: float = 4.0
    step_noise_s: float = 10.0
    step_persist_s: float = 0.25
    history_cooling: float = 4.5e5 / 12.0

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise ValueError(f"runtime.{f.name} must be a finite number >= 0, got {v!r}")
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
