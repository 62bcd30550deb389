"""This run's own characteristic curve, as a derived model input (``run_curve``); no I/O.

A tracked order's amplitude at a given shaft speed depends on this run's imbalance and
thermal bow, vector sums whose phases no gas-path input carries: the same engine crosses
a resonance with a peak in one run and a dip in the next. What the run did at the same
speed earlier tells: the run-up predicts the run-down. ``RunCurve`` gives, per sample,
the mean target amplitude this run showed at the current switch speed (bins of
``RuntimeConfig.run_curve_bin``) in its *earlier* OC segments, and the fleet's characteristic curve
(the training runs' mean) where this run has not been yet. Samples of the current
segment never count, so a fault inside it is not explained away by its own samples.

The node (``MonitorPipeline``) and training (``add_run_curve``) step the very same object.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from node.models.baseline import FleetCurve
from node.models.config import RuntimeConfig
from node.models.ocmodel import RUN_CURVE


class RunCurve:
    """Stateful, bounded memory (one sum per speed bin visited).

    Args:
        fleet_speed, fleet_mean: the fleet characteristic curve (B,), (B,), speeds ascending.
        bin_width: speed bin, rpm (``RuntimeConfig.run_curve_bin``).

    >>> rc = RunCurve(np.array([0.0, 10000.0]), np.array([0.0, 10.0]))  # fleet: 1 per 1000 rpm
    >>> rc.step(4010.0, 7.0, True)  # first segment: the fleet curve
    4.01
    >>> rc.step(4020.0, 9.0, False)  # its own samples never count
    4.02
    >>> rc.step(4030.0, 1.0, True)  # a later segment: the run's own mean in that bin
    8.0
    """

    def __init__(self, fleet_speed: np.ndarray, fleet_mean: np.ndarray,
                 bin_width: float = RuntimeConfig.run_curve_bin) -> None:
        self.fleet = FleetCurve(fleet_speed, fleet_mean).at  # the fleet curve at a speed
        self.bin_width = bin_width
        self.reset()

    def reset(self) -> None:
        """A new run: forget every bin."""
        self._sum: dict[int, float] = {}
        self._n: dict[int, int] = {}
        self._pend_sum: dict[int, float] = {}
        self._pend_n: dict[int, int] = {}

    def _commit(self) -> None:
        for b, v in self._pend_sum.items():
            self._sum[b] = self._sum.get(b, 0.0) + v
            self._n[b] = self._n.get(b, 0) + self._pend_n[b]
        self._pend_sum, self._pend_n = {}, {}

    def step(self, speed: float, y: float, new_segment: bool) -> float:
        """Feature for this sample (target unit); ``new_segment``: the OC changed at it.

        speed, y: this sample's switch speed and target (NaN: unknown; a NaN speed gives NaN).
        """
        if new_segment:
            self._commit()
        if not math.isfinite(speed):
            return math.nan
        b = int(speed // self.bin_width)
        n = self._n.get(b)
        if n:
            out = self._sum[b] / n
        else:
            out = self.fleet(speed)
        if math.isfinite(y):
            self._pend_sum[b] = self._pend_sum.get(b, 0.0) + y
            self._pend_n[b] = self._pend_n.get(b, 0) + 1
        return out


def hold_last(x: np.ndarray) -> np.ndarray:
    """Each NaN replaced by the last finite value before it (NaN before the first), (K,)."""
    ok = np.isfinite(x)
    idx = np.where(ok, np.arange(x.size), 0)
    np.maximum.accumulate(idx, out=idx)
    out = x[idx]
    out[: int(np.argmax(ok)) if ok.any() else x.size] = np.nan
    return out


def run_curve_column(speed: np.ndarray, y: np.ndarray, oc_codes: np.ndarray,
                     fleet: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """The feature over one run, as the node computes it sample by sample: (K,).

    speed, y: (K,) raw (NaN at dropouts: held, as the node holds them); oc_codes: (K,)
    the OC detector's labels (-1 outside every OC).
    """
    rc = RunCurve(*fleet)
    sp, yy = hold_last(np.asarray(speed, float)), hold_last(np.asarray(y, float))
    out = np.empty(sp.size)
    prev = None
    for k, (s, v, c) in enumerate(zip(sp.tolist(), yy.tolist(), np.asarray(oc_codes).tolist())):
        out[k] = rc.step(s, v, prev is not None and c != prev)
        prev = c
    return out


def add_run_curve(run, schedule, target: str, fleet: tuple[np.ndarray, np.ndarray],
                  codes: np.ndarray | None = None):
    """``run`` (a ``node.mcap.Run``) with the ``run_curve`` column appended.

    codes: the run's (K,) model index per sample (``OCDetector.label`` by model, as the node
    switches its models; None: labelled here).
    """
    from node.runtime.ocdetect import OCDetector

    if RUN_CURVE in run.channels or schedule.switch not in run.channels or target not in run.channels:
        return run
    if codes is None:
        codes = OCDetector(schedule).label(run.column(schedule.switch), models=True)[0]
    col = run_curve_column(run.column(schedule.switch), run.column(target), codes, fleet)
    return dataclasses.replace(run, data=np.column_stack([run.data, col]),
                               channels=(*run.channels, RUN_CURVE))
