"""The forecast of the rest of a pass-off run: each remaining segment's peak of the target, and
the probability that it breaks its acceptance limit, conditioned on the run so far.

Training keeps every training run's peak of the target in each segment of the schedule
(``PeakTable.peak``, the target's unit) and its peak over the limit in force (``ratio``: the
largest measured / limit over the segment's samples with a limit; NaN where none applies or the
run lacks the segment), in the bundle (versioned JSON). The model is a level model on their
logarithms::

    log peak[r, s] = mu_s + a_r + e[r, s]        log ratio[r, s] = nu_s + a_r + e'[r, s]

the run's level ``a_r`` common to its segments (the engine's balance, its sensors' gain),
N(0, tau^2) over the training runs, and ``e``, ``e'`` per segment N(0, sigma_s^2), N(0, varsigma_s^2)
(each shrunk towards the pooled variance). The segments a run has done estimate its level,
shrunk towards the fleet's by their number; each remaining segment's log peak is then normal:
the predicted peak is its median, with its 90 % interval, and ``p_exceed`` the probability that
its ratio exceeds 1. ``p_fail`` integrates over the run's level (Gauss-Hermite) the probability
that any remaining segment exceeds; ``first`` is the segment where the first exceedance is most
likely, given when an exceedance is expected (``p_fail`` at least one half).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.special import ndtr

VERSION = 1  # the stored table's version: another is not read (no forecast, said once)
MIN_RUNS = 3  # training runs a forecast needs at least
MAX_RUNS = 100_000  # rows a stored table holds at most
Z90 = 1.6448536269514722  # the standard normal's 95th percentile: a central 90 % interval
FLOOR = 1e-6  # peaks and ratios below are taken as this (logarithms), the target's unit
SHRINK = 4.0  # a segment's variance is shrunk towards the pooled one as by this many runs
_NODES, _WEIGHTS = np.polynomial.hermite_e.hermegauss(24)  # over N(0, 1): weights exp(-x^2 / 2)
_WEIGHTS = _WEIGHTS / _WEIGHTS.sum()


@dataclass(frozen=True, eq=False)
class PeakTable:
    """The training runs' peaks per segment: ``peak`` and ``ratio`` (runs, segments), NaN where
    unknown; ``segments`` the schedule's (``Schedule.segments``).

    >>> t = PeakTable(("A", "rundown"), np.array([[1.0, 2.0]]), np.array([[0.5, np.nan]]))
    >>> PeakTable.from_manifest(t.manifest(), ("A", "rundown")).ratio.tolist()
    [[0.5, nan]]
    """

    segments: tuple[str, ...]
    peak: np.ndarray
    ratio: np.ndarray

    def manifest(self) -> dict:
        """As JSON (null for NaN), with its version."""
        def rows(a: np.ndarray) -> list[list[float | None]]:
            return [[float(x) if math.isfinite(x) else None for x in row] for row in a.tolist()]
        return {"version": VERSION, "segments": list(self.segments), "peak": rows(self.peak),
                "ratio": rows(self.ratio)}

    @classmethod
    def from_manifest(cls, d: object, segments: Sequence[str]) -> PeakTable | None:
        """The stored table; None for another version (the bundle then gives no forecast).
        A malformed one is a ValueError (a malformed bundle)."""
        if not isinstance(d, dict):
            raise ValueError("forecast must be an object")
        if d.get("version") != VERSION:
            return None
        if d.get("segments") != list(segments):
            raise ValueError("forecast: its segments are not the schedule's")

        def table(key: str) -> np.ndarray:
            rows = d.get(key)
            if not isinstance(rows, list) or len(rows) > MAX_RUNS or not all(
                    isinstance(r, list) and len(r) == len(segments) and all(
                        x is None or (not isinstance(x, bool) and isinstance(x, (int, float))
                                      and 0 <= x < math.inf) for x in r) for r in rows):
                raise ValueError(f"forecast.{key} must be at most {MAX_RUNS} rows of "
                                 f"{len(segments)} finite non-negative numbers or nulls")
            return np.array([[np.nan if x is None else float(x) for x in r] for r in rows],
                            dtype=float).reshape(len(rows), len(segments))

        peak, ratio = table("peak"), table("ratio")
        if peak.shape != ratio.shape:
            raise ValueError("forecast: peak and ratio differ in their number of runs")
        return cls(tuple(segments), peak, ratio)


def _fit(x: np.ndarray, level: np.ndarray, per_run: float = 0.0
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per segment: the mean of ``x - level`` (R, S) over the runs, its shrunk residual variance,
    and the runs it had (NaN mean where none); ``per_run``: the segments each level was the mean
    of (their residuals' variance is that much smaller: undone; 0: none)."""
    dev = x - level[:, None]
    ok = np.isfinite(dev)
    n = ok.sum(axis=0)
    mean = np.where(n > 0, np.where(ok, dev, 0.0).sum(axis=0) / np.maximum(n, 1), np.nan)
    e2 = np.where(ok, (dev - mean) ** 2, 0.0)
    dof = np.maximum(n - 1, 0)
    pooled = e2.sum() / max(int(dof.sum()), 1)
    own = e2.sum(axis=0) / np.maximum(dof, 1)
    var = (dof * own + SHRINK * pooled) / (dof + SHRINK)
    if per_run > 1.0:
        var = var * per_run / (per_run - 1.0)
    return mean, np.maximum(var, FLOOR ** 2), n


class Forecaster:
    """The level model of a ``PeakTable`` (module docstring), fitted once; ``forecast`` at each
    OC switch. None of it runs per sample."""

    def __init__(self, table: PeakTable) -> None:
        self.segments = table.segments
        x = np.log(np.fmax(table.peak, FLOOR))
        z = np.log(np.fmax(table.ratio, FLOOR))
        x[~np.isfinite(table.peak)] = np.nan
        z[~np.isfinite(table.ratio)] = np.nan
        mu0, _, _ = _fit(x, np.zeros(x.shape[0]))
        dev = x - mu0
        seen = np.isfinite(dev)
        counts = seen.sum(axis=1)
        known = counts > 0  # runs with a level: those with a segment the others have too
        level = np.full(x.shape[0], np.nan)
        level[known] = np.where(seen, dev, 0.0).sum(axis=1)[known] / counts[known]
        if known.any():
            level -= np.mean(level[known])  # (the fleet's level is 0: the segments' means hold it)
        per_run = float(np.mean(counts[known])) if known.any() else 1.0
        self.mu, self.sigma2, self.n = _fit(x, level, per_run)
        self.nu, self.varsigma2, self.nz = _fit(z, level, per_run)
        spread = float(np.var(level[known], ddof=1)) if known.sum() > 1 else 0.0
        self.tau2 = max(spread - float(np.mean(self.sigma2)) / max(per_run, 1.0), FLOOR ** 2)
        self.runs = int(known.sum())

    def level(self, done: Mapping[int, float]) -> tuple[float, float]:
        """This run's level (mean, variance) from its done segments' peaks (index: peak)."""
        d = [math.log(max(p, FLOOR)) - float(self.mu[s]) for s, p in done.items()
             if math.isfinite(p) and math.isfinite(self.mu[s])]
        if not d:
            return 0.0, self.tau2
        s2 = float(np.mean([self.sigma2[s] for s, p in done.items()
                            if math.isfinite(p) and math.isfinite(self.mu[s])])) / len(d)
        w = self.tau2 / (self.tau2 + s2)
        return w * float(np.mean(d)), self.tau2 * (1.0 - w)

    def forecast(self, done: Mapping[int, float], remaining: Sequence[int]
                 ) -> tuple[list[dict], float, str | None]:
        """Per remaining segment (indices, in order) ``{oc, peak, peak_lo, peak_hi, p_exceed}``
        (null where the training runs lack it, ``p_exceed`` null where no limit applies), the
        probability that any of them exceeds (``p_fail``) and the segment of the first
        exceedance where one is expected (else None).

        >>> t = PeakTable(("A", "B", "rundown"), np.array([[1.0, 2.0, 1.0], [1.2, 2.2, 1.1],
        ...               [0.9, 1.9, 0.8], [1.1, 2.1, 1.0]]), np.full((4, 3), np.nan))
        >>> t.ratio[:, 1] = t.peak[:, 1] / 2.1
        >>> f = Forecaster(t)
        >>> low, p_low, _ = f.forecast({0: 0.9}, [1, 2])
        >>> high, p_high, first = f.forecast({0: 1.3}, [1, 2])
        >>> low[0]["peak"] < high[0]["peak"], p_low < 0.5 < p_high, first, high[1]["p_exceed"]
        (True, True, 'B', None)
        """
        a, va = self.level(done)
        out: list[dict] = []
        means, sds = [], []
        for s in remaining:
            entry: dict = {"oc": self.segments[s], "peak": None, "peak_lo": None, "peak_hi": None,
                           "p_exceed": None}
            if math.isfinite(self.mu[s]):
                m = float(self.mu[s]) + a
                sd = math.sqrt(float(self.sigma2[s]) * (1.0 + 1.0 / max(int(self.n[s]), 1)) + va)
                entry["peak"], entry["peak_lo"], entry["peak_hi"] = (
                    math.exp(m), math.exp(m - Z90 * sd), math.exp(m + Z90 * sd))
            if math.isfinite(self.nu[s]):
                own = float(self.varsigma2[s]) * (1.0 + 1.0 / max(int(self.nz[s]), 1))
                entry["p_exceed"] = float(ndtr((float(self.nu[s]) + a) / math.sqrt(own + va)))
                means.append(float(self.nu[s]))
                sds.append(math.sqrt(own))
            out.append(entry)
        if not means:
            return out, 0.0, None
        levels = a + math.sqrt(va) * _NODES  # (nodes,) the run's level at the quadrature nodes
        q = ndtr((np.array(means)[:, None] + levels[None, :]) / np.array(sds)[:, None])  # (segs, nodes)
        none_before = np.cumprod(np.vstack([np.ones(len(levels)), 1.0 - q[:-1]]), axis=0)
        first = (q * none_before) @ _WEIGHTS  # (segs,) P(the first exceedance is in each)
        p_fail = float(first.sum())
        limited = [e["oc"] for e in out if e["p_exceed"] is not None]
        return out, min(max(p_fail, 0.0), 1.0), limited[int(np.argmax(first))] if p_fail >= 0.5 else None
