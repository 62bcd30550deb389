"""The forecast of the rest of a pass-off run: each remaining segment's peak of the target, and
the probability that it breaks its acceptance limit, conditioned on the run so far.

Training keeps every training run's peak of the target in each segment of the schedule
(``PeakTable.peak``, the target's unit) and its peak over the limit in force (``ratio``: the
largest measured / limit over the segment's samples with a limit; NaN where none applies or the
run lacks the segment), in the bundle (versioned JSON).

The model: a run's log peaks over the segments are jointly normal, mean ``mu`` (the training runs')
and covariance their sample covariance shrunk towards a level model's (``PRIOR_RUNS``)::

    log peak[r, s] = mu_s + a_r + e[r, s],   a_r ~ N(0, tau^2),  e[r, s] ~ N(0, sigma_s^2)

(the run's level ``a_r`` common to its segments: the engine's balance, its sensors' gain; each
variance shrunk towards the pooled one). With a few training runs the forecast is the level
model's: the segments done scale the training runs' peaks; with many, the segments' own
correlations take over (a bow that shows at idle and is gone at speed, resonances that move
together). At an OC switch the segments done so far condition the normal: each remaining
segment's predicted peak is its conditional median with a 90 % interval; its peak over the limit
is the peak less the training runs' mean log(peak / ratio) there (their spread added), and
``p_exceed`` the probability that it exceeds 1. ``p_fail`` (any remaining segment over) and the
segment of the first exceedance come from ``DRAWS`` fixed draws of the conditional normal (the
same numbers live and in replay); ``first`` is given when an exceedance is expected (``p_fail``
at least one half).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.special import ndtr

PRIOR_RUNS = 8.0  # the level model weighs as this many training runs in the shrunk covariance
DRAWS = 2000  # draws of the conditional normal for p_fail and the first exceedance
VERSION = 1  # the stored table's version: another is not read (no forecast, said once)
MIN_RUNS = 3  # training runs a forecast needs at least
MAX_RUNS = 100_000  # rows a stored table holds at most
Z90 = 1.6448536269514722  # the standard normal's 95th percentile: a central 90 % interval
FLOOR = 1e-6  # peaks and ratios below are taken as this (logarithms), the target's unit
SHRINK = 4.0  # a segment's variance is shrunk towards the pooled one as by this many runs


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
    """The model of a ``PeakTable`` (module docstring), fitted once; ``forecast`` at each OC
    switch. None of it runs per sample."""

    def __init__(self, table: PeakTable, prior_runs: float | None = None) -> None:
        """prior_runs: the level model's weight in the covariance, in runs (None: ``PRIOR_RUNS``)."""
        prior_runs = PRIOR_RUNS if prior_runs is None else prior_runs
        self.segments = table.segments
        x = np.log(np.fmax(table.peak, FLOOR))
        x[~np.isfinite(table.peak)] = np.nan
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
        spread = float(np.var(level[known], ddof=1)) if known.sum() > 1 else 0.0
        self.tau2 = max(spread - float(np.mean(self.sigma2)) / max(per_run, 1.0), FLOOR ** 2)
        self.runs = int(known.sum())
        # the covariance: the sample one (pairwise complete runs) shrunk towards the level model's
        d = x - self.mu
        ok = np.isfinite(d)
        d0 = np.where(ok, d, 0.0)
        pairs = ok.T.astype(float) @ ok.astype(float)
        sample = (d0.T @ d0) / np.maximum(pairs - 1.0, 1.0)
        level_model = self.tau2 + np.diag(self.sigma2)
        w = np.where(pairs > 1.0, (pairs - 1.0) / (pairs - 1.0 + prior_runs), 0.0)
        cov = w * sample + (1.0 - w) * level_model
        vals, vecs = np.linalg.eigh(np.where(np.isfinite(cov), cov, 0.0))
        self.cov = (vecs * np.maximum(vals, FLOOR ** 2)) @ vecs.T  # (segments, segments), positive
        # the peak over the limit: the peak less log(peak / ratio), its training mean and spread
        z = np.log(np.fmax(table.ratio, FLOOR))
        gap = np.where(np.isfinite(table.ratio) & np.isfinite(x), x - z, np.nan)
        m = np.isfinite(gap).sum(axis=0)
        self.offset = np.where(m > 0, np.nansum(np.where(m > 0, gap, 0.0), axis=0) / np.maximum(m, 1), np.nan)
        self.offset_var = np.where(m > 1, np.nansum((gap - self.offset) ** 2, axis=0) / np.maximum(m - 1, 1),
                                   0.0)
        rng = np.random.default_rng(0)
        self._draws = rng.standard_normal((DRAWS, len(self.segments)))
        self._noise = rng.standard_normal((DRAWS, len(self.segments)))

    def conditional(self, done: Mapping[int, float], remaining: Sequence[int]
                    ) -> tuple[np.ndarray, np.ndarray]:
        """The remaining segments' log peaks given the done ones' (index: peak): mean (k,) and
        covariance (k, k), the uncertainty of the training means included."""
        rem = np.asarray(remaining, dtype=int)
        given = [s for s, p in done.items() if math.isfinite(p) and math.isfinite(self.mu[s])
                 and s not in set(remaining)]
        mean = self.mu[rem].copy()
        cov = self.cov[np.ix_(rem, rem)].copy()
        if given:
            g = np.asarray(given, dtype=int)
            d = np.log(np.fmax([done[s] for s in given], FLOOR)) - self.mu[g]
            gain = np.linalg.solve(self.cov[np.ix_(g, g)], self.cov[np.ix_(g, rem)]).T  # (k, |g|)
            mean = mean + gain @ d
            cov = cov - gain @ self.cov[np.ix_(g, rem)]
        cov = cov + np.diag(self.sigma2[rem] / np.maximum(self.n[rem], 1))
        return mean, 0.5 * (cov + cov.T)

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
        known = [s for s in remaining if math.isfinite(self.mu[s])]
        out: dict[int, dict[str, Any]] = {
            s: {"oc": self.segments[s], "peak": None, "peak_lo": None, "peak_hi": None, "p_exceed": None}
            for s in remaining}
        if not known:
            return list(out.values()), 0.0, None
        mean, cov = self.conditional(done, known)
        sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
        limited = np.array([math.isfinite(self.offset[s]) for s in known])
        over_mean = mean - np.where(limited, self.offset[known], 0.0)
        over_sd = np.sqrt(sd ** 2 + np.where(limited, self.offset_var[known], 0.0))
        p = ndtr(over_mean / over_sd)
        for j, s in enumerate(known):
            e = out[s]
            e["peak"], e["peak_lo"], e["peak_hi"] = (math.exp(mean[j]), math.exp(mean[j] - Z90 * sd[j]),
                                                     math.exp(mean[j] + Z90 * sd[j]))
            if limited[j]:
                e["p_exceed"] = float(p[j])
        if not limited.any():
            return list(out.values()), 0.0, None
        vals, vecs = np.linalg.eigh(cov)
        root = vecs * np.sqrt(np.maximum(vals, 0.0))  # (k, k): cov = root @ root.T
        k = len(known)
        draws = mean + self._draws[:, :k] @ root.T + self._noise[:, :k] * np.sqrt(
            np.where(limited, self.offset_var[known], 0.0))
        over = (draws > np.where(limited, self.offset[known], np.inf))  # (DRAWS, k)
        any_over = over.any(axis=1)
        p_fail = float(any_over.mean())
        first = None
        if p_fail >= 0.5:
            firsts = np.bincount(np.argmax(over[any_over], axis=1), minlength=k)
            first = self.segments[known[int(np.argmax(firsts))]]
        return list(out.values()), p_fail, first
