"""How large a simulated fault is, seen from the node: its effect on the target against the alarm band.

The simulator draws a fault from its own random stream, so a fault run and the same run
simulated without the fault (its *twin*: the first held-out normal run in ``bench faults``)
are equal sample for sample before the onset. After it, twin minus fault run is exactly
what the fault did to the measured target. Set beside the band the residual rule needs
to cross (threshold x sigma of the OC model in force, the narrowest band the node ever
uses, since its run scale is never below 1), it tells whether any residual rule with that
false-alarm budget could flag the fault in time: a ratio below 1 means the fault moves the
target by less than the model's own error on a normal run.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from node.contract import FS
from node.contract.schedule import Schedule
from node.models.bundle import Bundle
from node.runtime.ocdetect import OCDetector
from node.training.runs import Run

SMOOTH_S = 2.0  # the effect is averaged over this window (s) before it is set against the band


@dataclass(frozen=True)
class FaultEffect:
    """A fault's effect on the target within ``window`` seconds of its onset.

    peak: largest |fault run - twin| in the window, target units (mm/s).
    ratio: largest SMOOTH_S-mean |effect| over the alarm band in force at that time;
        NaN where no OC model applies throughout the window.
    """

    peak: float
    ratio: float


def band_per_sample(run: Run, bundle: Bundle, schedule: Schedule, fs: float = FS) -> np.ndarray:
    """(K,) residual alarm band (threshold x sigma, target units) of the OC in force; NaN without model."""
    det = OCDetector(schedule, bundle.config, fs)
    names = schedule.segments  # (the rundown last)
    bands = {}
    for i, name in enumerate(names):
        res = bundle.oc(name)
        c = None if res is None else res.calibration
        bands[i] = np.nan if res is None or c is None or res.model is None else c.threshold * c.sigma
    speed = run.column(schedule.switch)
    out = np.full(len(speed), np.nan)
    for k, v in enumerate(speed.tolist()):
        oc = det.step(v).oc
        if oc is not None:
            out[k] = bands[oc]
    return out


def on_common_samples(run: Run, twin: Run) -> tuple[Run, Run]:
    """The fault run and its twin on the time stamps both hold.

    ``read_runs`` drops a run's off samples (every speed below 5 % of the *file's* top speed),
    so the one-run fault file and the ten-run normal file can cut the same run's rundown a
    sample apart. Unchanged when they share less than 99 % of their samples (then they are
    not twins, and ``fault_effect`` says so).
    """
    if np.array_equal(run.t, twin.t):
        return run, twin
    _, i, j = np.intersect1d(run.t, twin.t, assume_unique=True, return_indices=True)
    if len(i) < 0.99 * max(len(run.t), len(twin.t)):
        return run, twin
    return (Run(run.t[i], run.data[i], run.channels, run.bed, run.shutdown_before),
            Run(twin.t[j], twin.data[j], twin.channels, twin.bed, twin.shutdown_before))


def fault_effect(fault_run: Run, twin: Run, target: str, onset: float, band: np.ndarray,
                 window: float = 60.0, fs: float = FS) -> FaultEffect:
    """Effect of the fault (from ``onset``, epoch s) on ``target`` within ``window`` s, against ``band``.

    fault_run, twin: the same run with and without the fault (ValueError if they differ
    more than one sample period before the onset, or in their time stamps); band: (K,) from
    ``band_per_sample``.
    """
    if len(fault_run.t) != len(twin.t) or not np.array_equal(fault_run.t, twin.t):
        raise ValueError("the fault run and its twin have different time stamps")
    y, y0 = fault_run.column(target), twin.column(target)
    # a channel's clock phase stamps its samples up to one period before the simulator's grid
    # instant: the first faulted sample may carry a stamp just before the onset
    pre = fault_run.t < onset - 1.0 / fs
    if not np.array_equal(y[pre], y0[pre], equal_nan=True):
        raise ValueError("the fault run and its twin differ before the onset: not twins")
    m = (fault_run.t >= onset) & (fault_run.t <= onset + window)
    d = np.abs(y - y0)[m]
    if not np.isfinite(d).any():
        return FaultEffect(float("nan"), float("nan"))
    n = max(1, int(round(SMOOTH_S * fs)))
    ok = np.isfinite(d)
    # mean over the finite samples of each window (dropouts are NaN in both runs)
    sums = np.convolve(np.where(ok, d, 0.0), np.ones(n), mode="valid")
    counts = np.convolve(ok.astype(float), np.ones(n), mode="valid")
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = sums / counts / band[m][n - 1:] if len(d) >= n else np.array([np.nan])
    ratio = ratio[np.isfinite(ratio)]
    return FaultEffect(float(np.nanmax(d)), float(ratio.max()) if len(ratio) else float("nan"))
