"""What a prediction of a planned profile needs beside the model and the stated history: the
training runs at hand and the aids fitted on them (``node.training.prediction_aids``), and
where the engine first runs in the profile (``prepare_prediction``; ``ordervib predict``).

The training runs: the recordings given; else the runs the model keeps
(``node.training.kept_runs``); else its training recordings, when they are where and as they
were (``node.training.provenance.training_recordings``); else none, and the prediction is
bounded at 0 only, its interval the CV residuals' alone.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from node.contract.errors import OrdervibError
from node.models.bundle import Model
from node.runtime.history import SLOW_TEMPERATURES
from node.runtime.ocdetect import OCDetector
from node.training.fit import load_runs
from node.training.kept_runs import RUNS_META, load_kept_runs
from node.training.prediction import Profile, fit_interval_widths, needed_channels
from node.training.prediction_aids import AmplitudeBound, InputFill, IntervalWidths
from node.training.prediction_reach import SpeedRange
from node.training.provenance import training_recordings
from node.training.runs import Run

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PredictionSetup:
    """The arguments of ``predict_profile`` beside the model, the profile and the history.

    fill: the channels the profile lacks (None: it holds every one the node needs); bound,
    widths, levels: the upper bound, the interval's widths and the targets' mean amplitude
    per OC (None: no training runs at hand); start: the time the engine first runs in the
    profile, s (a stated shutdown ends there); speeds: the switch speeds the training runs went
    through (without runs: up to the OC models' envelopes; None: not known), against which the
    prediction marks a plan's samples beyond.
    """

    fill: InputFill | None
    bound: AmplitudeBound | None
    widths: IntervalWidths | None
    levels: InputFill | None
    start: float
    speeds: SpeedRange | None = None


def prepare_prediction(model: Model, folder: str, profile: Profile, train: Sequence[str] | None = None,
                       quiet: bool = False) -> PredictionSetup:
    """The set-up of a prediction of ``profile`` by the model read from ``folder``: the training
    runs (``train``'s recordings; else as the module says), the fill, the bound, the interval
    and the profile's first time on. ``quiet``: no progress while recordings are read."""
    runs, source = _training_runs(model, folder, train, quiet)
    fill = _fill(model, profile, runs, source)
    bound, widths, levels = _limits(model, runs, source)
    on_grid = profile.runs(OCDetector(model.schedule, model.config).off_level)
    speeds = SpeedRange.fit(runs, model.schedule.switch, source) if runs else None
    return PredictionSetup(fill, bound, widths, levels, _first_on(on_grid, model),
                           speeds if speeds is not None else SpeedRange.from_model(model))


def _training_runs(model: Model, folder: str, train: Sequence[str] | None, quiet: bool
                   ) -> tuple[list[Run], str]:
    """The training runs that fill the channels a profile lacks and set the bound and the
    interval, and what they are: ``train``'s recordings; else the runs the model keeps;
    else its training recordings, when they are where and as they were; else none (an empty
    list, and why)."""
    if train:
        return load_runs(train, quiet), f"runs of {', '.join(train)}"
    if os.path.isfile(os.path.join(folder, RUNS_META)):
        runs = load_kept_runs(folder)[0]
        log.info("the model keeps %d training run(s)", len(runs))
        return runs, "training runs the model keeps"
    paths = training_recordings(model)
    if paths:
        return load_runs(paths, quiet), f"training runs of {', '.join(paths)}"
    return [], "the model keeps no training runs and its training recordings are not at hand"


def _fill(model: Model, profile: Profile, runs: list[Run], source: str) -> InputFill | None:
    """The InputFill of the channels the profile lacks, from the training ``runs``; None when
    the profile holds every channel the node needs."""
    need = needed_channels(model)
    lacking = [c for c in need if c not in profile.channels]
    if not lacking:
        return None
    if not runs:
        raise OrdervibError(f"the profile lacks {', '.join(lacking)}, which the model takes: add them as "
                            "columns, or give --train REC.mcap (recordings of this engine) to fill them from")
    want = sorted({*lacking, *(c for c in SLOW_TEMPERATURES if c not in profile.channels)})
    fill = InputFill.fit(runs, model.schedule, want, source)
    still = [c for c in lacking if c not in fill.channels]
    if still:
        raise OrdervibError(f"the profile lacks {', '.join(still)}, which the model takes, and the "
                            f"{source} do not hold it either")
    log.info("filled %s from %d %s, at the planned %s in each OC", ", ".join(lacking), len(runs), source,
             model.schedule.switch)
    return fill


def _limits(model: Model, runs: list[Run], source: str
            ) -> tuple[AmplitudeBound | None, IntervalWidths | None, InputFill | None]:
    """The upper bound, the interval's widths and the targets' mean amplitude per OC (for the
    1x-vector models' mean modulus) from the training ``runs`` (none: no bound above, the
    interval from the CV residuals alone, the fleet curve; said once)."""
    if not runs:
        log.warning("%s: the prediction is bounded at 0 only, not above, and its interval is the CV "
                    "residuals' alone (narrower than a plan's error); give --train REC.mcap", source)
        return None, None, None
    bound = AmplitudeBound.fit(runs, model.schedule, model.targets)
    levels = InputFill.fit(runs, model.schedule, model.targets, source)
    log.info("interval: the chained prediction of %d %s", len(runs), source)
    return bound, fit_interval_widths(model, runs, bound, levels=levels), levels


def _first_on(runs: list[Run], model: Model) -> float:
    """The time the engine first runs in the profile (s): a stated shutdown ends there."""
    on = OCDetector(model.schedule, model.config).off_level
    speed = runs[0].column(model.schedule.switch)
    k = np.flatnonzero(speed >= on)
    return float(runs[0].t[int(k[0]) if k.size else 0])
