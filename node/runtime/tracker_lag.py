"""The order tracker's lag estimated from the recordings (no datasheet, no truth file).

A vibration unit's order tracker smooths the complex 1x vector with a first-order lag of tau
seconds: the tracked y obeys tau dy/dt + y = u, u the steady response. Through a resonance u
turns fast, and the lag both shifts the tracked curve (by about the ramp rate times tau, which
a critical speed alone cannot tell from the critical) and distorts it (the peak lower and
broader, the phase roll skewed: second order in tau, the same on a run-up and a coast-down).
``crossing_lag`` fits, in the time domain, the modes found in one ramp together with tau:

    y(t) = L_tau[ sum_m (A_m r_m^2 + B_m r_m) / (1 - r_m^2 + 2j zeta_m r_m) + c0 + c1 N (+ c2 N^2) ] (N)
           + e0 exp(-t / tau)

(r_m = N(t) / Nc_m; times N for a velocity; L_tau the first-order lag started from rest, e0
the tracker's state at the window's start; the complex A, B, c, e0 by least squares for each
(Nc, zeta, tau): variable projection). The shift alone would trade tau against Nc; the shape
through the crossing (and the settling where the ramp stops near the mode) pins tau. Each fit
gives tau and its standard error; ``combine`` pools the crossings of a fleet's runs (a
weighted median, the spread their weighted median absolute deviation): the training stores
the estimate with how it was found (``node.models.transients.TransientSettings``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import least_squares
from scipy.signal import lfilter

from node.contract import FS
from node.contract.vector import order_vectors
from node.runtime.transient import Critical, analyse, smoothed

TAU_BOUNDS = (0.0, 10.0)  # s: the lags a fit may find (beyond: unidentified)
BAND = 3.0  # a crossing's window: the speeds within BAND half-power half-widths of its critical
TAIL_S = 3.0  # ... and this long after the speed leaves it (the tracked vector trails)
MAX_REL_SE = 0.25  # a fit counts where its standard error is at most this share of tau (>= 0.2 s)
MIN_SAMPLES = 80  # samples a window needs
SE_FLOOR = 0.2  # pooled, a crossing's error counts as at least this share of the taus' median


@dataclass(frozen=True)
class LagFit:
    """One crossing's fit: tau and its standard error (s), the modes' critical speeds (rpm),
    the direction, the samples fitted."""

    tau: float
    se: float
    speeds: tuple[float, ...]
    direction: str
    samples: int

    @property
    def identified(self) -> bool:
        """Whether the fit pins tau: inside its bounds, its error small."""
        lo, hi = TAU_BOUNDS
        return (lo + 1e-3 < self.tau < hi - 1e-3 and math.isfinite(self.se)
                and self.se <= MAX_REL_SE * max(self.tau, 0.2))


@dataclass(frozen=True)
class LagEstimate:
    """The tracker's lag pooled over crossings: tau (s), its spread (s: the weighted median
    absolute deviation x 1.4826 of the crossings' taus), the crossings counted, those fitted."""

    tau: float
    spread: float
    crossings: int
    fitted: int


def _lag_columns(cols: np.ndarray, tau: float, fs: float) -> np.ndarray:
    """cols (K, p) through the first-order lag of tau s started from rest, plus the free
    initial state's decay (K, p + 1)."""
    k = len(cols)
    if tau <= 1e-6:
        tr = np.zeros(k)
        tr[0] = 1.0
        return np.column_stack([cols, tr])
    a = math.exp(-1.0 / (fs * tau))
    return np.column_stack([lfilter([1.0 - a], [1.0, -a], cols, axis=0), a ** np.arange(k)])


def _basis(speed: np.ndarray, modes: Sequence[tuple[float, float]], velocity: bool,
           background: int = 2) -> np.ndarray:
    """The steady response's columns (K, background + 2m) at speeds (K,): a polynomial
    background c0 + c1 x (+ c2 x^2 with ``background`` 3; x the speed centred and scaled over
    the window) and each mode's (r^2, r) / (1 - r^2 + 2j zeta r); times N / mean N for a
    velocity."""
    mid = float(np.mean(speed))
    span = float(np.ptp(speed)) or 1.0
    x = (speed - mid) / span
    cols = [x**k for k in range(background)]
    for nc, zeta in modes:
        r = speed / nc
        d = 1.0 - r**2 + 2j * zeta * r
        cols += [r**2 / d, r / d]
    b = np.column_stack(cols)
    return b * (speed / mid)[:, None] if velocity else b


def crossing_lag(speed: np.ndarray, vector: np.ndarray, modes: Sequence[tuple[float, float]],
                 direction: str, *, fs: float = FS, velocity: bool = True,
                 tau_start: Sequence[float] = (1.0, 3.0)) -> LagFit | None:
    """Tau fitted with the modes (start values [(Nc rpm, zeta)]) to one window of a ramp:
    speed (K,) rpm (gaps filled, smoothed), vector (K,) the tracked complex 1x vector (NaN
    where missing). None: too few samples or no fit.

    Two backgrounds are fitted, straight and quadratic in the speed, and the one of the lower
    BIC kept: the tail of a mode outside the window (a coast-down starting just below a higher
    critical) bends the background, and a straight one then traded the bend for the lag (a
    coast-down's tau near 0 where the tracker lagged 1.85 s); where nothing bends it, the
    quadratic's extra freedom only blurs tau. The BIC's figures are rounded to ``RESOLUTION``
    (relative) before they are compared, so that rounding cannot flip the choice."""
    ok = np.isfinite(vector)
    if ok.sum() < MIN_SAMPLES or not np.isfinite(speed).all() or not modes:
        return None
    fits = [f for bg in BACKGROUNDS if (f := _fit(speed, vector, ok, modes, velocity, bg, fs, tau_start))]
    if not fits:
        return None
    best, k = min(fits, key=lambda f: _bic(f[0].cost, len(f[0].fun), f[1]))
    n = len(best.fun)
    if n <= k:
        return None
    s2 = 2.0 * best.cost / (n - k)
    jtj = best.jac.T @ best.jac
    try:
        se = math.sqrt(float(np.linalg.inv(jtj)[-1, -1]) * s2)
    except (np.linalg.LinAlgError, ValueError):
        se = math.inf
    m = len(modes)
    return LagFit(float(best.x[-1]), se if math.isfinite(se) else math.inf,
                  tuple(float(best.x[2 * j]) for j in range(m)), direction, int(ok.sum()))


BACKGROUNDS = (2, 3)  # the backgrounds tried: straight, quadratic (complex columns)
RESOLUTION = 1e-6  # relative: BIC figures compared at this resolution (ties: the straight one)


def _bic(cost: float, n: int, k: int) -> float:
    """BIC of a least-squares fit (cost: half the residuals' sum of squares; n residuals, k
    parameters), rounded to ``RESOLUTION``."""
    if n <= k or cost <= 0.0:
        return -math.inf if cost <= 0.0 else math.inf
    b = n * math.log(2.0 * cost / n) + k * math.log(n)
    q = RESOLUTION * max(abs(b), 1.0)
    return round(b / q) * q


def _fit(speed: np.ndarray, vector: np.ndarray, ok: np.ndarray, modes: Sequence[tuple[float, float]],
         velocity: bool, background: int, fs: float, tau_start: Sequence[float]) -> tuple[Any, int] | None:
    """The variable-projection fit of (Nc, zeta per mode, tau) with ``background`` columns:
    scipy's result and the parameters counted (real; None: no fit)."""
    v = vector[ok]
    m = len(modes)

    def resid(p: np.ndarray) -> np.ndarray:
        b = _basis(speed, [(p[2 * j], p[2 * j + 1]) for j in range(m)], velocity, background)
        d = _lag_columns(b, p[-1], fs)[ok]
        coef, *_ = np.linalg.lstsq(d, v, rcond=None)
        e = d @ coef - v
        return np.concatenate([e.real, e.imag])

    lo = np.array([q for nc, _ in modes for q in (0.9 * nc, 0.005)] + [TAU_BOUNDS[0]])
    hi = np.array([q for nc, _ in modes for q in (1.1 * nc, 0.4)] + [TAU_BOUNDS[1]])
    scale = np.array([q for nc, z in modes for q in (max(z * nc, 1.0), max(z, 1e-3))] + [0.5])
    best = None
    for t0 in tau_start:  # the next start only where the last fit ends at a bound
        if best is not None and TAU_BOUNDS[0] + 1e-3 < best.x[-1] < TAU_BOUNDS[1] - 1e-3:
            break
        p0 = np.clip(np.array([q for nc, z in modes for q in (nc, z)] + [t0]), lo, hi)
        try:
            fit = least_squares(resid, p0, bounds=(lo, hi), x_scale=scale, max_nfev=60 * (2 * m + 1))
        except (ValueError, np.linalg.LinAlgError):
            continue
        if best is None or fit.cost < best.cost:
            best = fit
    if best is None:
        return None
    return best, 2 * m + 1 + 2 * (2 * m + background + 1)


def _groups(found: Sequence[Critical]) -> list[list[Critical]]:
    """Criticals whose windows (BAND half-widths about each) overlap, together (ascending)."""
    out: list[list[Critical]] = []
    for c in sorted(found, key=lambda x: x.speed):
        reach = max((x.speed * (1 + BAND * x.zeta) for x in out[-1]), default=0.0) if out else -1.0
        if out and c.speed * (1 - BAND * c.zeta) <= reach:
            out[-1].append(c)
        else:
            out.append([c])
    return out


def ramp_lags(speed: np.ndarray, amplitude: np.ndarray, phase: np.ndarray, *, fs: float = FS,
              velocity: bool = True, min_amplitude: float = 0.0) -> list[LagFit]:
    """The lag fitted at each resonance (or group of close ones) one ramp crosses: its samples
    (K,) speed (rpm), amplitude and phase lag (degrees), NaN where missing. The resonances are
    found first with no lag undone (``analyse``: shifted by the lag, a start only)."""
    try:
        tr = analyse(speed, amplitude, phase, fs=fs, tracker_tau=0.0, velocity=velocity,
                     min_amplitude=min_amplitude)
    except ValueError:
        return []
    s = smoothed(np.asarray(speed, dtype=float), max(1, int(round(0.2 * fs)) | 1))
    if not np.isfinite(s).all():
        return []
    v = order_vectors(np.asarray(amplitude, dtype=float), np.asarray(phase, dtype=float))
    tail = int(round(TAIL_S * fs))
    out = []
    for g in _groups(tr.criticals):
        lo = min(c.speed * (1 - BAND * c.zeta) for c in g)
        hi = max(c.speed * (1 + BAND * c.zeta) for c in g)
        idx = np.flatnonzero((s >= lo) & (s <= hi))
        if len(idx) < MIN_SAMPLES:
            continue
        w = slice(int(idx[0]), min(int(idx[-1]) + 1 + tail, len(s)))
        fit = crossing_lag(s[w], v[w], [(c.speed, c.zeta) for c in g], tr.direction, fs=fs,
                           velocity=velocity)
        if fit is not None:
            out.append(fit)
    return out


def _weighted_median(x: np.ndarray, w: np.ndarray) -> float:
    order = np.argsort(x, kind="stable")
    cw = np.cumsum(w[order])
    return float(x[order][int(np.searchsorted(cw, 0.5 * cw[-1]))])


def combine(fits: Sequence[LagFit]) -> LagEstimate | None:
    """The crossings' taus pooled (those ``identified``): their median weighted by 1 / se^2
    (the errors floored at ``SE_FLOOR`` of the taus' median: no one crossing decides), the
    spread their weighted median absolute deviation x 1.4826; None without one.

    >>> fits = [LagFit(t, 0.05, (5000.0,), "up", 400) for t in (0.9, 1.0, 1.1, 6.0)]
    >>> e = combine(fits)
    >>> round(e.tau, 2), e.crossings, e.fitted
    (1.0, 4, 4)
    """
    good = [f for f in fits if f.identified]
    if not good:
        return None
    x = np.array([f.tau for f in good])
    w = 1.0 / np.maximum([f.se for f in good], SE_FLOOR * float(np.median(x))) ** 2
    tau = _weighted_median(x, w)
    spread = 1.4826 * _weighted_median(np.abs(x - tau), w)
    return LagEstimate(tau, spread, len(good), len(fits))
