"""Transient analysis: an order's 1x vector against speed through a ramp, and its critical speeds.

What a rotordynamics engineer reads from a run-up or a coast-down (API 684): the Bode plot
(amplitude and phase against speed) and, for each resonance crossed, its critical speed,
peak amplitude, phase change and amplification factor by the half-power method,
AF = Nc / (N2 - N1), N1 and N2 the speeds where the amplitude is the peak's 1 / sqrt(2).

Steps (pure numerics, no I/O; arrays time-major, one sample per 1 / fs s):

* ``find_transitions``: the ramps of a run (speed moving one way faster than a rate).
* ``bode``: one ramp's samples binned by speed. The order tracker smooths the complex order
  with a first-order lag of ``tracker_tau`` s, so on a ramp of rate dN/dt the tracked vector
  trails the steady response by about dN/dt * tracker_tau in speed (run-up: peaks show high;
  coast-down: low) and the lag blurs the peak (a lower AF). The lag is undone first
  (``untracked``: x + tau dx/dt on the complex vector; on an amplitude alone, where there is
  no phase, only approximately). Velocities are divided by the speed (``velocity``): the
  unbalance response in displacement, |z| ~ r^2 / |1 - r^2 + 2j zeta r|, whose peak and
  half-power band the corrections below assume. Where a phase exists the bins average the
  complex 1x vector A exp(-j phase) (``node.contract.vector``), less the slow-roll vector
  when one is given.
* ``criticals``: where a phase exists, where the phase lag turns as a mode's does (the slope
  read at two scales: a weak, well-damped mode's noisy lag breaks up at the fine one), the
  modes there (one, or neighbours together: close modes merge into one hump of amplitude)
  fitted to the complex vector, kept where they explain it better than a background alone:
  each critical is where its mode's lag has turned 90 degrees, its AF API 684's half-power
  AF of the fitted mode's own response (the other modes, the background and the noise
  removed; slightly below 1 / (2 zeta)), ``af_phase`` = 1 / (2 zeta) the phase slope there,
  (Nc / 2) dphi/dN. Without phase: each amplitude peak whose two half-power points lie
  inside the ramp, the half-power AF read on it and the critical and damping through the
  single-mode unbalance response (its peak lies at Nc / sqrt(1 - 2 zeta^2) and its
  half-power AF is slightly below 1 / (2 zeta)).
* ``analyse``: the three for one ramp. The same sample by sample, as the node analyses its
  ramps: ``node.runtime.ramp_analyser``.

>>> import numpy as np
>>> t = np.arange(0, 60, 1 / 40)
>>> speed = 3000 + 100 * t                          # a run-up at 100 rpm/s
>>> r = speed / 6000                                # one mode at 6000 rpm, zeta 0.05
>>> z = r**2 / (1 - r**2 + 0.1j * r)
>>> v = speed * z * 1e-3                            # velocity-like 1x vector
>>> out = analyse(speed, np.abs(v), -np.degrees(np.angle(v)))
>>> [(round(c.speed), round(c.af, 1), round(c.af_phase, 1)) for c in out.criticals]
[(6000, 9.9, 10.0)]
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.signal import lfilter, savgol_filter

from node.contract import FS
from node.contract.vector import order_vectors

HALF_POWER = 1.0 / math.sqrt(2.0)
NOISE_DROP = 6.0  # a peak's drop to half power must be this many noise sigmas
BIC_MARGIN = 10.0  # how much lower a fit with one mode more (or with modes, than none) must bring the BIC
RESOLUTION = 1e-4  # a tracked order's resolution over its RMS: a smaller misfit is no evidence (BIC floor)
ZETA_RANGE = (0.01, 0.4)  # damping ratios a fitted mode may have (AF 1.25-50)
WIDE = 4  # the phase-roll search's second pass averages the slope over WIDE x smooth + 1 bins


@dataclass(frozen=True)
class Span:
    """One ramp of a run: samples ``start`` to ``stop`` (exclusive), moving ``direction``."""

    start: int
    stop: int
    direction: str  # "up" or "down"
    from_speed: float  # rpm
    to_speed: float  # rpm
    rate: float  # mean speed rate over the ramp, rpm/s (+ up, - down)


@dataclass(frozen=True)
class Bode:
    """One ramp's 1x response binned by speed (B bins, ascending speed).

    speed: (B,) mean (tracker-lag corrected) speed of each bin, rpm; amplitude: (B,) mean
    amplitude as measured (input units); response: (B,) the amplitude the peaks are read on
    (divided by the speed for velocities, less the slow roll where there is phase); vector:
    (B,) complex mean 1x vector (the same units as ``response``), None without phase;
    count: (B,) samples per bin.
    """

    speed: np.ndarray
    amplitude: np.ndarray
    response: np.ndarray
    vector: np.ndarray | None
    count: np.ndarray


@dataclass(frozen=True)
class Critical:
    """One resonance crossed (speeds in rpm; ``None`` where the ramp has no phase).

    speed: the critical speed (the modal fit's where there is phase, else the half-power
    estimate); speed_peak: the speed of the amplitude peak (tracker lag undone; the fitted
    mode's where the measured one is not clean); speed_hp: the critical from the measured peak
    and its half-power band (the peak less the single-mode offset; None without a clean peak);
    n1, n2: the half-power speeds; amplitude: the peak amplitude (input units); af: API 684's
    Nc / (N2 - N1), with phase that of the fitted mode's own response (``af_method`` "modal
    fit"), else of the measured amplitude ("half-power"); zeta: the damping ratio that AF
    implies; phase_change: the change of the phase lag across the resonance (degrees, + as the
    lag grows with speed; over the critical -/+ 3 half-widths, within the ramp); speed_phase,
    af_phase, zeta_phase: the modal fit to the complex vector (its AF, 1 / (2 zeta), is the
    phase slope at the critical, (Nc / 2) dphi/dN); af_hp: with phase, the half-power AF of the
    measured vectors less the other fitted modes where that has a clean peak at the mode (the
    background and the noise left in: a check, biased on a wide band), else None.
    """

    speed: float
    speed_peak: float
    speed_hp: float | None
    n1: float
    n2: float
    amplitude: float
    af: float
    zeta: float
    phase_change: float | None = None
    speed_phase: float | None = None
    af_phase: float | None = None
    zeta_phase: float | None = None
    af_method: str = "half-power"
    af_hp: float | None = None


@dataclass(frozen=True)
class Transient:
    """One ramp analysed: its direction, speeds, mean rate, Bode data and criticals."""

    direction: str
    from_speed: float
    to_speed: float
    rate: float
    bode: Bode
    criticals: list[Critical]


def filled(x: np.ndarray) -> np.ndarray:
    """x (K,) with NaNs linearly interpolated (ends held); all-NaN stays NaN.

    >>> filled(np.array([np.nan, 1.0, np.nan, 3.0, np.nan])).tolist()
    [1.0, 1.0, 2.0, 3.0, 3.0]
    """
    x = np.asarray(x, dtype=float)
    ok = np.isfinite(x)
    if ok.all() or not ok.any():
        return x.copy()
    idx = np.arange(len(x))
    return np.interp(idx, idx[ok], x[ok])


def _moving_average(x: np.ndarray, n: int) -> np.ndarray:
    """Centred moving average over n samples (n odd; at most x's length), NaN-aware, same length;
    works on complex."""
    if n > len(x):  # np.convolve's "same" would give the kernel's length
        n = len(x) if len(x) % 2 else len(x) - 1
    if n <= 1:
        return x.copy()
    ok = np.isfinite(x)
    kernel = np.ones(n)
    num = np.convolve(np.where(ok, x, 0), kernel, mode="same")
    den = np.convolve(ok.astype(float), kernel, mode="same")
    with np.errstate(invalid="ignore", divide="ignore"):
        out = num / den
    out[den == 0] = np.nan
    return out


def smoothed(x: np.ndarray, n: int) -> np.ndarray:
    """x (K,) with gaps interpolated (ends held), then its centred moving average over n samples
    (shorter at the ends; n at most K), same length."""
    return _moving_average(filled(x), n)


MIN_SPAN = 0.03  # a ramp analysed covers at least this share of its top speed (9,000 to 9,300 rpm)


def find_transitions(speed: np.ndarray, fs: float = FS, min_rate: float = 20.0,
                     min_span: float = MIN_SPAN, smooth_s: float = 1.0, gap_s: float = 1.0,
                     pad_s: float = 2.0) -> list[Span]:
    """The ramps of a run: where the speed keeps moving one way faster than ``min_rate`` rpm/s.

    speed: (K,) rpm (NaN for a missing sample); the rate is taken on a ``smooth_s`` moving
    average; pauses shorter than ``gap_s`` join two ramps of the same sign; a ramp must
    cover at least ``min_span`` of its top speed; each ramp is widened by ``pad_s`` at both
    ends (the slow start and settling of the speed), never into its neighbour.

    >>> s = np.concatenate([np.linspace(0, 2600, 800), np.full(400, 2600.0),
    ...                     np.linspace(2600, 6000, 1360), np.full(400, 6000.0)])
    >>> [(x.direction, round(x.from_speed), round(x.to_speed)) for x in find_transitions(s)]
    [('up', 0, 2600), ('up', 2600, 6000)]
    """
    s = _moving_average(filled(np.asarray(speed, dtype=float)), max(1, int(round(smooth_s * fs)) | 1))
    if len(s) < 3 or not np.isfinite(s).all():
        return []
    rate = np.gradient(s) * fs
    sign = np.where(rate > min_rate, 1, np.where(rate < -min_rate, -1, 0))
    runs: list[list[int]] = []  # [start, stop, sign]
    i = 0
    while i < len(sign):
        if sign[i] == 0:
            i += 1
            continue
        j = i
        while j < len(sign) and sign[j] == sign[i]:
            j += 1
        if runs and runs[-1][2] == sign[i] and i - runs[-1][1] <= gap_s * fs:
            runs[-1][1] = j
        else:
            runs.append([i, j, int(sign[i])])
        i = j
    raw = filled(np.asarray(speed, dtype=float))
    out: list[Span] = []
    pad = int(round(pad_s * fs))
    for n, (a, b, sg) in enumerate(runs):
        if abs(float(s[b - 1] - s[a])) < min_span * max(abs(float(s[a])), abs(float(s[b - 1])), 1e-9):
            continue
        a = max(a - pad, out[-1].stop if out else 0)
        b = min(b + pad, runs[n + 1][0] if n + 1 < len(runs) else len(s))
        lo, hi = float(raw[a]), float(raw[b - 1])
        out.append(Span(a, b, "up" if sg > 0 else "down", lo, hi, (hi - lo) / ((b - 1 - a) / fs)))
    return out


def lagged(x: np.ndarray, tau: float, fs: float = FS) -> np.ndarray:
    """x (K,) through the first-order lag tau dy/dt = x - y (exact for x held over a sample),
    starting settled; tau <= 0 returns a copy."""
    x = np.asarray(x, dtype=float)
    if tau <= 0 or len(x) == 0:
        return x.copy()
    a = math.exp(-1.0 / (fs * tau))
    y, _ = lfilter([1.0 - a], [1.0, -a], x, zi=np.array([a * x[0]]))
    return np.asarray(y)


def untracked(x: np.ndarray, tau: float, fs: float = FS, window_s: float = 0.5,
              max_gap_s: float = 0.1) -> np.ndarray:
    """The input of a first-order lag of ``tau`` s from its output x (K,), real or complex:
    x + tau dx/dt, the derivative a Savitzky-Golay fit (quadratic, ``window_s`` long) to x
    with its gaps interpolated; NaN stays NaN, and so does every sample whose window reaches
    into a gap longer than ``max_gap_s`` (a straight fill across a turning vector is no
    signal to differentiate). tau <= 0: a copy.

    Undoes an order tracker that smooths the complex 1x vector exactly; on an amplitude alone
    it is exact only while the phase stands still (an approximation through a resonance).

    >>> t = np.arange(0, 20, 1 / 40)
    >>> u = np.sin(0.5 * t)
    >>> y = lagged(u, 1.0)
    >>> bool(np.max(np.abs(untracked(y, 1.0)[40:-40] - u[40:-40])) < 0.01)
    True
    """
    x = np.asarray(x)
    if tau <= 0 or len(x) < 5:
        return x.copy()
    n = max(5, int(round(window_s * fs)) | 1)
    n = min(n, len(x) - (1 - len(x) % 2))
    bad = ~np.isfinite(x)
    parts = [x.real, x.imag] if np.iscomplexobj(x) else [x]
    out = []
    for p in parts:
        f = filled(np.where(bad, np.nan, p))  # (a complex NaN may carry a finite part)
        if not np.isfinite(f).all():
            return np.full(x.shape, np.nan, dtype=x.dtype)
        out.append(f + tau * savgol_filter(f, n, 2, deriv=1, delta=1.0 / fs))
    y = out[0] + 1j * out[1] if len(out) == 2 else out[0]
    y[_near_gaps(bad, max_gap_s * fs, n // 2)] = np.nan
    return y


def _near_gaps(bad: np.ndarray, longest: float, reach: int) -> np.ndarray:
    """The samples (K,) bool that are missing (``bad``, K,) or lie within ``reach`` samples of
    a run of more than ``longest`` missing ones (whose interpolated fill a derivative over
    ``reach`` either side would read as the signal)."""
    out = bad.copy()
    if not bad.any():
        return out
    edges = np.diff(np.concatenate([[0], bad.astype(np.int8), [0]]))
    for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True):
        if b - a > longest:
            out[max(0, a - reach):b + reach] = True
    return out


def bode(speed: np.ndarray, amplitude: np.ndarray, phase: np.ndarray | None = None, *,
         fs: float = FS, tracker_tau: float = 0.0, velocity: bool = True,
         bin_fraction: float = 0.002, slow_roll: complex | None = None) -> Bode:
    """One ramp's samples binned by speed (see the module's docstring).

    speed, amplitude, phase (degrees lag, optional): (K,), NaN where missing; tracker_tau:
    the order tracker's lag (s); velocity: amplitudes are velocities (divided by the speed);
    bin_fraction: bin width as a fraction of the top speed; slow_roll: a 1x vector in the
    response's units (``slow_roll_vector``) subtracted from every bin's vector.
    """
    speed = np.asarray(speed, dtype=float)
    amplitude = np.asarray(amplitude, dtype=float)
    if speed.shape != amplitude.shape or (phase is not None and np.shape(phase) != speed.shape):
        raise ValueError("speed, amplitude and phase must have the same shape (K,)")
    s = filled(speed)
    ok = np.isfinite(s) & np.isfinite(amplitude) & (s > 0)
    if ok.sum() < 3:
        raise ValueError("a ramp needs at least 3 samples with speed and amplitude")
    v_all = None
    if phase is not None:
        ph = np.asarray(phase, dtype=float)
        v_all = order_vectors(amplitude, np.where(np.isfinite(ph), ph, np.nan))  # (no warning for inf)
        v_all = untracked(v_all, tracker_tau, fs)
    amp_all = untracked(amplitude, tracker_tau, fs)
    top = float(np.max(s[ok]))
    width = max(bin_fraction * top, 1e-9)
    lo = float(np.min(s[ok]))
    nb = int((top - lo) / width) + 1
    idx = np.minimum(((s[ok] - lo) / width).astype(int), nb - 1)
    count = np.bincount(idx, minlength=nb).astype(float)
    keep = count > 0
    mean_s = np.bincount(idx, s[ok], nb)[keep] / count[keep]
    amp = amp_all[ok]
    mean_a = np.bincount(idx, amp, nb)[keep] / count[keep]
    scale = s[ok] if velocity else np.ones(ok.sum())
    vec: np.ndarray | None = None
    response = np.bincount(idx, amp / scale, nb)[keep] / count[keep]
    if v_all is not None:
        vv = v_all[ok]
        has = np.isfinite(vv)
        v = np.where(has, vv, 0) / scale
        nv = np.bincount(idx, has.astype(float), nb)[keep]
        re = np.bincount(idx, v.real, nb)[keep]
        im = np.bincount(idx, v.imag, nb)[keep]
        with np.errstate(invalid="ignore", divide="ignore"):
            mean_v: np.ndarray = (re + 1j * im) / nv
        mean_v[nv == 0] = np.nan
        if slow_roll is not None:
            mean_v = mean_v - slow_roll
        response = np.where(np.isfinite(mean_v), np.abs(mean_v), response)
        vec = mean_v
    return Bode(mean_s, mean_a, response, vec, count[keep])


def slow_roll_vector(speed: np.ndarray, amplitude: np.ndarray, phase: np.ndarray,
                     band: tuple[float, float], velocity: bool = True) -> complex | None:
    """The mean 1x vector (response units, as ``bode`` makes them) of the samples whose speed
    lies in ``band`` (rpm): the runout or bow seen at slow roll; None without such samples."""
    s = np.asarray(speed, dtype=float)
    ph = np.asarray(phase, dtype=float)
    amp = np.asarray(amplitude, dtype=float)
    sel = (s >= band[0]) & (s <= band[1]) & np.isfinite(amp) & np.isfinite(ph) & (s > 0)
    if not sel.any():
        return None
    v = order_vectors(amp[sel], ph[sel]) / (s[sel] if velocity else 1.0)
    return complex(np.mean(v))


@functools.lru_cache(maxsize=4)
def _single_mode_table(power: float) -> tuple[np.ndarray, ...]:
    """For zeta on a grid: the half-power AF (peak speed over the band), the peak's r and the
    half-power points r1, r2 of the response r^power / |1 - r^2 + 2j zeta r| (ascending AF)."""
    zetas = np.geomspace(0.004, 0.3, 160)
    r = np.linspace(0.2, 3.0, 60001)
    af, rp, r1s, r2s = [], [], [], []
    for z in zetas:
        a = r**power / np.abs(1 - r**2 + 2j * z * r)
        i = int(np.argmax(a))
        hp = a[i] * HALF_POWER
        left = np.flatnonzero(a[:i] < hp)[-1]
        right = i + np.flatnonzero(a[i:] < hp)[0]
        r1 = np.interp(hp, [a[left], a[left + 1]], [r[left], r[left + 1]])
        r2 = np.interp(hp, [a[right], a[right - 1]], [r[right], r[right - 1]])
        af.append(r[i] / (r2 - r1))
        rp.append(r[i])
        r1s.append(r1)
        r2s.append(r2)
    order = np.argsort(af)
    return (np.asarray(af)[order], zetas[order], np.asarray(rp)[order], np.asarray(r1s)[order],
            np.asarray(r2s)[order])


def half_power_band(zeta: float, power: float = 2.0) -> tuple[float, float, float]:
    """(r1, r2, peak r) of the single-mode unbalance response r^power / |1 - r^2 + 2j zeta r|:
    its half-power points and its peak as fractions of the critical (zeta clipped to 0.004-0.3).

    >>> r1, r2, rp = half_power_band(0.05)
    >>> round(rp / (r2 - r1), 2), round(rp, 4)
    (9.9, 1.0025)
    """
    _, zetas, rps, r1s, r2s = _single_mode_table(float(power))
    order = np.argsort(zetas)
    return (float(np.interp(zeta, zetas[order], r1s[order])),
            float(np.interp(zeta, zetas[order], r2s[order])),
            float(np.interp(zeta, zetas[order], rps[order])))


def zeta_from_af(af: float, power: float = 2.0) -> tuple[float, float]:
    """(zeta, peak r) of the single-mode unbalance response r^power / |1 - r^2 + 2j zeta r|
    whose half-power AF is ``af`` (clipped to the table's 0.004-0.3 damping).

    >>> z, rp = zeta_from_af(9.9)
    >>> round(z, 3), round(rp, 4)
    (0.05, 1.0025)
    """
    afs, zetas, rps, *_ = _single_mode_table(float(power))
    return float(np.interp(af, afs, zetas)), float(np.interp(af, afs, rps))


def _half_power(x: np.ndarray, a: np.ndarray, i: int, step: int) -> float | None:
    """The speed where a falls below a[i] / sqrt(2) walking from bin i by ``step`` (+1/-1);
    None if the data ends first or a higher value comes first."""
    hp = a[i] * HALF_POWER
    j = i
    while 0 <= j + step < len(a):
        j += step
        if not np.isfinite(a[j]):
            continue
        if a[j] > a[i]:
            return None
        if a[j] < hp:
            prev = j - step
            while not np.isfinite(a[prev]):
                prev -= step
            return float(np.interp(hp, [a[j], a[prev]], [x[j], x[prev]]))
    return None


def _peak_speed(x: np.ndarray, a: np.ndarray, i: int) -> float:
    """Vertex of the parabola through bins i - 1, i, i + 1 (bin i's speed at an edge)."""
    if i == 0 or i == len(a) - 1 or not np.isfinite(a[i - 1 : i + 2]).all():
        return float(x[i])
    x0, x1, x2 = x[i - 1 : i + 2]
    y0, y1, y2 = a[i - 1 : i + 2]
    den = (x0 - x1) * (x0 - x2) * (x1 - x2)
    if den == 0:
        return float(x1)
    c2 = (x2 * (y1 - y0) + x1 * (y0 - y2) + x0 * (y2 - y1)) / den
    c1 = (x2**2 * (y0 - y1) + x1**2 * (y2 - y0) + x0**2 * (y1 - y2)) / den
    if c2 >= 0:
        return float(x1)
    return float(np.clip(-c1 / (2 * c2), x0, x2))


@dataclass(frozen=True)
class _ModalFit:
    """A fit of modes to complex vectors: modes [(Nc, zeta)], its BIC, the complex
    coefficients [c0, c1, A_1, B_1, ...] and the speed normalisation of the c1 term."""

    modes: list[tuple[float, float]]
    bic: float
    coef: np.ndarray
    mid: float
    span: float

    def mode(self, k: int, x: np.ndarray) -> np.ndarray:
        """Mode k's own response (B,) at speeds x (B,)."""
        nc, zeta = self.modes[k]
        r = x / nc
        d = 1 - r**2 + 2j * zeta * r
        return np.asarray(self.coef[2 + 2 * k] * r**2 / d + self.coef[3 + 2 * k] * r / d)

    def others(self, k: int, x: np.ndarray) -> np.ndarray:
        """The other modes' response (B,) at speeds x (B,): all the fitted modes but mode k."""
        return np.asarray(sum((self.mode(j, x) for j in range(len(self.modes)) if j != k),
                              np.zeros(len(x), dtype=complex)))


def _fit_modes(x: np.ndarray, v: np.ndarray, start: list[tuple[float, float]]) -> _ModalFit | None:
    """Critical speeds and damping ratios of sum_m (A_m r_m^2 + B_m r_m) / (1 - r_m^2 + 2j zeta_m
    r_m) + c0 + c1 N fitted to the complex vectors v (B,) at speeds x (B,) from ``start``
    [(Nc, zeta)], with the fit's Bayesian information criterion (lower: better, over the
    bins fitted: compare fits of the same bins only); None if it fails.

    A_m: the imbalance's modal force; B_m with the other terms spans a force that does not
    grow with speed (a bow: runout-like); c0 + c1 N: the modes outside. The complex
    coefficients by least squares for given modes (variable projection).
    """
    ok = np.isfinite(v)
    x, v = x[ok], v[ok]
    m = len(start)
    if len(x) < 3 * (4 * m + 4):
        return None

    mid, span = float(np.mean(x)), float(np.ptp(x)) or 1.0

    def basis(p: np.ndarray) -> np.ndarray:
        cols = [np.ones(len(x)), (x - mid) / span]
        for k in range(m):
            r = x / p[2 * k]
            d = 1 - r**2 + 2j * p[2 * k + 1] * r
            cols += [r**2 / d, r / d]
        return np.column_stack(cols)

    def resid(p: np.ndarray) -> np.ndarray:
        b = basis(p)
        coef, *_ = np.linalg.lstsq(b, v, rcond=None)
        e = b @ coef - v
        return np.concatenate([e.real, e.imag])

    p0 = np.array([q for nc, z in start for q in (nc, min(max(z, 2e-3), 0.4))])
    lo = np.array([q for _ in start for q in (float(x.min()), ZETA_RANGE[0] / 2)])
    hi = np.array([q for _ in start for q in (float(x.max()), 2 * ZETA_RANGE[1])])
    scale = np.array([q for nc, z in start for q in (max(z * nc, 1.0), max(z, 1e-3))])
    try:
        fit = least_squares(resid, np.clip(p0, lo, hi), bounds=(lo, hi), x_scale=scale)
    except (ValueError, np.linalg.LinAlgError):
        return None
    if not fit.success:
        return None
    bic = _bic(float(np.sum(fit.fun**2)), v, 2 * m + 4 * m + 4)  # 2m nonlinear, 4m + 4 linear
    coef, *_ = np.linalg.lstsq(basis(fit.x), v, rcond=None)
    return _ModalFit([(float(fit.x[2 * j]), float(fit.x[2 * j + 1])) for j in range(m)], bic, coef,
                     mid, span)


def _background_bic(x: np.ndarray, v: np.ndarray) -> float:
    """The BIC of ``_fit_modes``' background alone (c0 + c1 N, no mode) fitted to the complex
    vectors v (B,) at speeds x (B,): what a fit with modes must beat."""
    ok = np.isfinite(v)
    x, v = x[ok], v[ok]
    if len(x) < 3:
        return math.inf
    basis = np.column_stack([np.ones(len(x)), (x - np.mean(x)) / (float(np.ptp(x)) or 1.0)])
    coef, *_ = np.linalg.lstsq(basis, v, rcond=None)
    return _bic(float(np.sum(np.abs(basis @ coef - v) ** 2)), v, 4)


def _bic(rss: float, v: np.ndarray, n_params: int) -> float:
    """The Bayesian information criterion of a fit to the complex vectors v (B,) with residual
    sum of squares ``rss`` and ``n_params`` real parameters, over its 2B real residuals.

    The rss is floored at the vectors' energy times RESOLUTION squared (a vibration unit's
    0.01 mm/s on a 100 mm/s range): a misfit below it is no evidence, so that on clean data
    two fits that both reach it compare by their parameter count alone, and a mode more is
    never chosen for describing the speed bins' averaging or the last bits of the arithmetic
    (which a machine's floating-point kernels change).

    >>> v = np.ones(100, dtype=complex)
    >>> _bic(0.0, v, 4) == _bic(1e-20, v, 4) < _bic(0.0, v, 8)
    True
    """
    k = 2 * len(v)
    rss = max(rss, RESOLUTION**2 * float(np.sum(np.abs(v) ** 2)), 1e-300)
    return k * math.log(rss / k) + n_params * math.log(k)


def _max(a: np.ndarray) -> float:
    """The largest finite value of a, -inf if none."""
    f = a[np.isfinite(a)]
    return float(f.max()) if len(f) else -math.inf


def _amplitude_peaks(x: np.ndarray, a: np.ndarray, smooth: int, noise: float = 0.0
                     ) -> list[tuple[int, float, float, float]]:
    """Clean peaks of the smoothed response a (B,) at speeds x (B,): (bin, N1, N2, peak speed)
    for each local maximum whose two half-power points lie inside, highest first, none inside
    another's band, whose drop to half power is NOISE_DROP times ``noise`` (the smoothed
    response's sigma) or more."""
    n = len(a)
    peaks = [i for i in range(1, n - 1) if np.isfinite(a[i])
             and a[i] >= _max(a[max(0, i - smooth):i]) and a[i] > _max(a[i + 1:i + 1 + smooth])]
    out: list[tuple[int, float, float, float]] = []
    for i in sorted(peaks, key=lambda k: -a[k]):
        if a[i] * (1 - HALF_POWER) < NOISE_DROP * noise:
            continue  # the half-power drop is not above the noise: no peak to read
        n1, n2 = _half_power(x, a, i, -1), _half_power(x, a, i, +1)
        if n1 is None or n2 is None or any(lo <= x[i] <= hi for _, lo, hi, _ in out):
            continue
        out.append((i, n1, n2, _peak_speed(x, a, i)))
    return out


def _phase_candidates(x: np.ndarray, vs: np.ndarray, smooth: int, min_af: float,
                      wide: int = 0) -> list[list[list[tuple[float, float]]]]:
    """Where the phase lag of the vectors vs (B,) rolls as modes' do: per stretch of speed
    where the lag grows with (N / 2) dphi/dN (the AF a single mode would have there; the slope
    averaged over ``smooth`` bins) of 1 or more, two options of (speed, half-width ~ zeta Nc)
    starting guesses: m = round(roll / 180 degrees) modes (one if it rolls 90 degrees or
    more) and m + 1 (a mode hidden in its neighbour's roll), each at the middle of its share
    of the roll; a stretch must have its steepest point at ``min_af`` or more. Close modes
    roll as one stretch: fitted together. (A stretch may run off the data: the modes fitted
    there count only with their band inside.) ``wide`` > ``smooth``: the same again with the
    slope averaged over ``wide`` bins, for the stretches the first pass has none inside (a
    weak, well-damped mode whose noisy lag breaks into pieces at ``smooth``)."""
    ok = np.isfinite(vs)
    xs = x[ok]
    if len(xs) < 4 * smooth:
        return []
    lag = np.unwrap(-np.angle(vs[ok]))
    out: list[list[list[tuple[float, float]]]] = []
    taken: list[tuple[float, float]] = []  # the speeds of the stretches a finer pass found
    for n in (smooth, wide) if wide > smooth and len(xs) >= 4 * wide else (smooth,):
        found = []
        slope = _moving_average(np.gradient(lag, xs), n)  # rad/rpm
        for a, b in _rolling(0.5 * xs * slope, n, min_af):
            if any(lo <= xs[a] <= hi or xs[a] <= lo <= xs[b] for lo, hi in taken):
                continue  # a stretch already found at a finer scale
            roll = lag[b] - lag[a]
            m0 = max(int(round(roll / math.pi)), 0) or (1 if roll >= math.pi / 2 else 0)  # (a
            # net roll backwards, a lag that grows in a stretch but falls more over it: no mode)
            if not m0:
                continue
            options = []
            for m in (m0, m0 + 1):
                group = []
                for k in range(m):
                    at = lag[a] + (k + 0.5) * roll / m
                    c = float(np.interp(at, lag[a:b + 1], xs[a:b + 1]))
                    sl = float(np.interp(c, xs, slope))
                    group.append((c, min(1.0 / sl, 0.1 * c) if sl > 0 else 0.05 * c))
                options.append(group)
            out.append(options)
            found.append((float(xs[a]), float(xs[b])))
        taken += found
    return out


def _rolling(af_local: np.ndarray, n: int, min_af: float) -> list[tuple[int, int]]:
    """The stretches [a, b] (bins, inclusive) where af_local (B,) is 1 or more (gaps shorter
    than n bins bridged) whose largest value is ``min_af`` or more."""
    active = np.nan_to_num(af_local) >= 1.0
    out = []
    i = 0
    while i < len(af_local):
        if not active[i]:
            i += 1
            continue
        j = i
        while j < len(af_local) and (active[j] or active[j:j + n].any()):
            j += 1
        if np.nanmax(af_local[i:j]) >= min_af:
            out.append((i, j - 1))
        i = j
    return out


def _distinct(modes: list[tuple[float, float]]) -> bool:
    """Whether fitted modes [(Nc, zeta)] lie apart by more than their mean half-power half-width
    (two modes closer than that are one mode described twice)."""
    s = sorted(modes)
    return all(b[0] - a[0] > 0.5 * (a[0] * a[1] + b[0] * b[1]) for a, b in zip(s, s[1:]))


def af_of_zeta(zeta: float, power: float = 2.0) -> float:
    """The half-power AF of the single-mode unbalance response r^power / |1 - r^2 + 2j zeta r|
    (the inverse of ``zeta_from_af``).

    >>> round(af_of_zeta(0.05), 2)
    9.9
    """
    afs, zetas, *_ = _single_mode_table(float(power))
    order = np.argsort(zetas)
    return float(np.interp(zeta, zetas[order], afs[order]))


def _noise(y: np.ndarray, smooth: int) -> float:
    """Sigma of a ``smooth``-bin average of y (B,): the robust scatter of its first differences."""
    d = np.diff(y[np.isfinite(y)])
    if len(d) < 3:
        return 0.0
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / math.sqrt(2.0 * smooth))


def criticals(b: Bode, *, smooth: int = 5, min_amplitude: float = 0.0, power: float = 2.0,
              min_af: float = 2.5) -> list[Critical]:
    """The resonances of one ramp's Bode data, in ascending speed.

    With phase: where the phase lag turns as a mode's does (``_phase_candidates``, AF at least
    ``min_af``); neighbouring ones are fitted together (a sum of modes and a background to
    the complex vectors over their bands; with one mode more where that fits better by the
    BIC; none unless the modes beat the background alone by the BIC): each mode's critical
    speed and damping, counted with its half-power points inside the ramp. Its AF is the
    half-power AF of the fitted mode's own response (``af_method`` "modal fit"); that of the
    measured vectors less the other fitted modes, where that has a clean peak at the mode
    (both half-power points inside the fitted band), beside it (``af_hp``). Without phase:
    each clean amplitude peak (half-power method, critical and damping read through the
    single-mode response).
    Resonances below ``min_amplitude`` (input units) at their peak are left out; power: the
    exponent of r in the single-mode response (2: an unbalance response in displacement,
    which ``bode`` makes of velocities).
    """
    x = b.speed
    raw = _moving_average(b.amplitude, smooth)
    found: list[Critical] = []
    if b.vector is not None and np.isfinite(b.vector).sum() >= len(x) // 2:
        vs = _moving_average(b.vector, smooth)
        for options in _phase_candidates(x, vs, smooth, min_af, WIDE * smooth + 1):
            best = None
            lo = min(g[0][0] - 3 * g[0][1] for g in options)
            hi = max(g[-1][0] + 3 * g[-1][1] for g in options)
            band = (x >= lo) & (x <= hi)  # the same bins for every option (their BICs compare)
            for group in options:
                fitted = _fit_modes(x[band], b.vector[band], [(c, hw / c) for c, hw in group])
                if fitted is None or not _distinct(fitted.modes):
                    continue
                if best is None or fitted.bic < best.bic - BIC_MARGIN:  # a mode more must pay
                    best = fitted
            if best is None or best.bic > _background_bic(x[band], b.vector[band]) - BIC_MARGIN:
                continue  # no fit, or modes the noise explains as well (a roll of the noise)
            for k, (nc, zeta) in enumerate(best.modes):
                if not (ZETA_RANGE[0] <= zeta <= ZETA_RANGE[1]
                        and x[0] <= nc * (1 - zeta) and nc * (1 + zeta) <= x[-1]):
                    continue  # damped past a critical, or its band not inside the ramp
                amp = _max(np.where(np.abs(x - nc) <= max(zeta * nc, x[1] - x[0]), raw, np.nan))
                if not (amp >= min_amplitude and 1.0 / (2.0 * zeta) >= min_af):
                    continue
                # the mode isolated: the measured vectors of the fitted bins less the other modes
                own = _moving_average(np.where(band, b.vector - best.others(k, x), np.nan), smooth)
                own_a = np.abs(own)
                peak = [p for p in _amplitude_peaks(x, own_a, smooth, _noise(own_a, smooth))
                        if abs(p[3] - nc) <= zeta * nc]
                found.append(_critical_with_phase(x, vs, nc, zeta, amp, peak[0] if peak else None, power))
        return sorted(found, key=lambda c: c.speed)
    a = _moving_average(b.response, smooth)
    for i, n1, n2, npk in _amplitude_peaks(x, a, smooth, _noise(b.response, smooth)):
        amp = float(np.nanmax(raw[max(0, i - smooth):i + smooth + 1]))
        if amp < min_amplitude:
            continue
        af = npk / (n2 - n1)
        zeta, rp = zeta_from_af(af, power)
        found.append(Critical(speed=npk / rp, speed_peak=npk, speed_hp=npk / rp, n1=n1, n2=n2,
                              amplitude=amp, af=af, zeta=zeta))
    return sorted(found, key=lambda c: c.speed)


def _critical_with_phase(x: np.ndarray, vs: np.ndarray, nc: float, zeta: float, amp: float,
                         peak: tuple[int, float, float, float] | None, power: float) -> Critical:
    """A fitted mode (Nc rpm, zeta) as a ``Critical``: its AF and half-power band those of the
    mode's own response (the half-power method on the fitted mode: the other modes, the
    background and the noise removed); the measured peak's figures beside them where the
    mode isolated has a clean ``peak``; its phase change."""
    r1, r2, rp = half_power_band(zeta, power)
    n1, n2 = nc * r1, nc * r2
    af = rp / (r2 - r1)
    npk, speed_hp, af_hp = nc * rp, None, None
    if peak is not None:
        _, p1, p2, npk = peak
        af_hp = npk / (p2 - p1)
        speed_hp = npk / zeta_from_af(af_hp, power)[1]
    half = 0.5 * (n2 - n1)
    near = np.isfinite(vs) & (x >= nc - 3 * half) & (x <= nc + 3 * half)
    change = None
    if near.sum() >= 2:
        lag = np.unwrap(-np.angle(vs[near]))
        change = float(np.degrees(lag[-1] - lag[0]))
    return Critical(speed=nc, speed_peak=npk, speed_hp=speed_hp, n1=n1, n2=n2, amplitude=amp,
                    af=af, zeta=zeta, phase_change=change, speed_phase=nc,
                    af_phase=1.0 / (2.0 * zeta), zeta_phase=zeta, af_method="modal fit", af_hp=af_hp)


def analyse(speed: np.ndarray, amplitude: np.ndarray, phase: np.ndarray | None = None, *,
            fs: float = FS, tracker_tau: float = 0.0, velocity: bool = True,
            slow_roll: complex | None = None, min_amplitude: float = 0.0,
            bin_fraction: float = 0.002, smooth: int = 5, min_af: float = 2.5) -> Transient:
    """One ramp's samples (K,) analysed: ``bode`` then ``criticals`` (see them)."""
    b = bode(speed, amplitude, phase, fs=fs, tracker_tau=tracker_tau, velocity=velocity,
             bin_fraction=bin_fraction, slow_roll=slow_roll)
    s = filled(np.asarray(speed, dtype=float))
    first, last = float(s[0]), float(s[-1])
    dur = max(len(s) - 1, 1) / fs
    return Transient("up" if last >= first else "down", first, last, (last - first) / dur, b,
                     criticals(b, smooth=smooth, min_amplitude=min_amplitude, min_af=min_af))
