"""The characteristic-curve OC model (``curve``): no dynamics, a lookup of the speed.

:class:`CurveModel` holds the OC's curve (the training runs' mean target per speed bin,
rising, falling and steady speed apart), the curve anchored to the run's level (or 1x
vector) at the switch, the influence-coefficient curve, or the derived ``run_curve`` input
itself: the baseline every other kind must beat. :class:`CurveRuntime` is its online stepper.

A fit is a sum over trajectories: ``CurveModel.part`` takes from one trajectory what the fit
needs of it (its samples' bin sums, and for the anchored curves its samples and its level at
the switch), ``CurveModel.from_parts`` makes the model of any set of parts, and ``fit`` is
``from_parts`` of every trajectory's part. The leave-one-run-out CV computes each run's part
once and makes every fold's model from the other runs' parts: the very model a fit on those
runs gives, bit for bit, at a fraction of the cost.
"""

from __future__ import annotations

import bisect
import cmath
import dataclasses
import functools
import math
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import ClassVar, NamedTuple

import numpy as np

from node.contract import FS
from node.contract.vector import NAN_VECTOR
from node.models.ocmodel import Method, Trajectory, _readonly


class Variant(StrEnum):
    FLEET = "fleet"  # the training runs' characteristic curve of this OC; input: the switch speed
    RUN = "run"  # the derived run_curve input itself (node.runtime.runcurve); input: run_curve
    ANCHORED = "anchored"  # the fleet curve moved to the level this run had at the switch
    VECTOR = "vector"  # anchored, on the order's 1x vector (its phase recorded): |vector| predicted
    INFLUENCE = "influence"  # the 1x vector from its value at the switch by per-speed influence coefficients

    @property
    def on_vector(self) -> bool:
        """Whether the variant predicts the order's 1x vector (needs its phase)."""
        return self in (Variant.VECTOR, Variant.INFLUENCE)

    @property
    def anchored(self) -> bool:
        """Whether the variant is moved by the run's measured level (or vector) at the switch."""
        return self in (Variant.ANCHORED, Variant.VECTOR, Variant.INFLUENCE)


STEADY, RISING, FALLING = 0, 1, 2  # the speed's recent change: the rows of CurveModel.means
GAINS = 3  # an influence curve's runtime row of gains
HELD = (1.0, 0.0, 1.0)  # an anchor that does not fade: CurveModel.decay (alpha, beta, r)
# The fade times (s) an anchored curve's decay is chosen among (CurveModel.decay): a bowed
# rotor straightens within minutes at idle, faster at speed.
DECAY_TAUS = (15.0, 30.0, 60.0, 120.0, 240.0, 480.0)
FADE_SHARES = (0.0, 0.25, 0.5, 0.75)  # the share of the anchor's term that stays (alpha)
FADE_GAIN = 0.01  # a fade's leave-one-run-out error must be this much below the held anchor's


def direction_codes(hist: np.ndarray, speed: np.ndarray, window: int, deadband: float) -> np.ndarray:
    """Each sample's direction code (K,) as :class:`CurveRuntime` finds it, vectorised (for fitting).

    The change is speed[k] - speed[k - window] (the oldest of the last ``window`` finite samples,
    ``hist`` (K1,) before ``speed`` (K,) included); beyond +deadband RISING, below -deadband
    FALLING, else STEADY (also without any past, or with window 0). NaN speeds are skipped.

    >>> direction_codes(np.array([100.0]), np.array([150.0, 140.0, 110.0, 110.0]), 2, 20.0)
    array([1, 1, 2, 2])
    """
    full = np.concatenate([np.asarray(hist, float), np.asarray(speed, float)])
    keep = np.isfinite(full)
    out = np.zeros(len(speed), dtype=np.int64)
    if window <= 0:
        return out
    n_hist = int(keep[:len(hist)].sum())
    vals = full[keep]
    pos = np.arange(n_hist, vals.size)  # the finite samples of ``speed`` in ``vals``
    ref = vals[np.maximum(pos - window, 0)]
    change = np.where(pos > 0, vals[pos] - ref, 0.0)
    codes = np.where(change > deadband, RISING, np.where(change < -deadband, FALLING, STEADY))
    out[keep[len(hist):]] = codes
    return out


@dataclass(frozen=True, eq=False)
class CurvePart:
    """What a curve fit needs of one trajectory (``CurveModel.part``), whatever the others are.

    bins: (nb,) the speed bins holding samples (bin b spans [b, b + 1) x the bin width);
    sums, counts: (3, nb) the sum (complex on the 1x vector) and count of the fitted level's
    finite samples per bin and direction (STEADY, RISING, FALLING).
    The anchored curves' weights: seg_x, seg_codes, seg_level (K,) the OC samples' speeds,
    direction codes as the stepper finds them, and levels; anchor_x (n,) the finite speeds of
    the anchor window before the switch and y_sw the mean level there (None: no anchor; the
    influence curve keeps only y_sw).
    """

    bins: np.ndarray
    sums: np.ndarray
    counts: np.ndarray
    seg_x: np.ndarray = field(default_factory=lambda: np.zeros(0))
    seg_codes: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    seg_level: np.ndarray = field(default_factory=lambda: np.zeros(0))
    anchor_x: np.ndarray = field(default_factory=lambda: np.zeros(0))
    y_sw: complex | None = None


def _code_bin_sums(speed: np.ndarray, y: np.ndarray, code: np.ndarray, width: float
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bins (nb,), sums and counts (3, nb) per direction of the finite (speed, y) pairs (K,)."""
    ok = np.isfinite(speed) & np.isfinite(y)
    bins, inv = np.unique(np.floor(speed[ok] / width).astype(np.int64), return_inverse=True)
    flat = code[ok] * bins.size + inv  # (code, bin) as one index
    size = 3 * bins.size
    counts = np.bincount(flat, minlength=size).reshape(3, -1)
    yo = y[ok]
    if np.iscomplexobj(yo):
        sums = (np.bincount(flat, yo.real, size) + 1j * np.bincount(flat, yo.imag, size)).reshape(3, -1)
    else:
        sums = np.bincount(flat, yo, size).reshape(3, -1)
    return bins, sums, counts


def _merge_parts(parts: Sequence[CurvePart]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The bins every part holds (B,), and each part's sums and counts on them (P, 3, B)."""
    bins = np.unique(np.concatenate([np.zeros(0, np.int64), *(p.bins for p in parts)]))
    kind = complex if any(np.iscomplexobj(p.sums) for p in parts) else float
    sums = np.zeros((len(parts), 3, bins.size), kind)
    counts = np.zeros((len(parts), 3, bins.size), np.int64)
    for k, p in enumerate(parts):
        pos = np.searchsorted(bins, p.bins)
        sums[k][:, pos], counts[k][:, pos] = p.sums, p.counts
    return bins, sums, counts


def _binned_means(sums: np.ndarray, counts: np.ndarray, min_count: int) -> np.ndarray:
    """The mean level per direction and bin (3, B) from the parts' sums and counts (P, 3, B):
    a direction's own mean where it has at least ``min_count`` (and 1) samples, else the mean
    of every sample in the bin."""
    s, n = sums.sum(axis=0), counts.sum(axis=0)  # the parts in order, then the directions
    means = np.tile(s.sum(axis=0) / n.sum(axis=0), (3, 1))
    enough = (n > 0) & (n >= min_count)
    means[enough] = s[enough] / n[enough]
    return means


class LookupTables(NamedTuple):
    """A curve's lookup tables (``CurveModel.tables``): Python lists and the same as arrays."""

    xs: list[float]  # (B,) the bins' centres, rpm
    rows: list[list[complex]]  # (R, B) the curve's rows
    slopes: list[list[complex]]  # (R, B - 1) per rpm between centres
    xa: np.ndarray  # xs as (B,) float
    ra: np.ndarray  # rows as (R, B) complex
    sa: np.ndarray  # slopes as (R, B - 1) complex


@dataclass(frozen=True, eq=False)
class CurveModel:
    """A characteristic-curve OC model (``curve``): no dynamics, a lookup of the speed.

    Attributes:
        params: variant (``Variant``: "fleet", "run", "anchored", "vector" or "influence"),
            and but for run: bin (rpm), window (samples the speed's change is taken over; 0:
            one curve; influence: one curve whatever it), deadband (rpm over the window),
            min_count (a direction's own mean in a bin needs this many samples, else the
            bin's mean of every sample; default 1), and for the anchored ones: anchor
            (samples before the switch whose mean level, or 1x vector, anchors the curve) and
            fade (true: the anchor's fade is learned, ``decay``; default false: held); influence:
            ridge.
        centres: (B,) the speed bins' centres, rpm (empty for run).
        means: (3, B) the mean target per bin when the speed is steady, rising, falling
            (rows STEADY, RISING, FALLING); a bin without samples of a direction holds the
            mean of every sample in it.
        weights: anchored only, (2,): (w_mul, w_add). With c the curve at the speed, y_sw and
            c_sw the measured mean and the steady curve's mean over the ``anchor`` samples
            before the switch, the prediction is
            c + w_mul c (y_sw / c_sw - 1) + w_add (y_sw - c_sw): the curve scaled and shifted
            towards this run's level (a new run's imbalance and bow move its level, its
            curve keeps its shape). The weights are least squares over the training runs.
            vector: the same on the order's 1x vector (``Trajectory.z``; means complex, y_sw
            and c_sw complex, the weights real), the predicted amplitude the modulus: a run's
            own imbalance and bow turn the vector, which the amplitude alone cannot tell
            from a change of level.
        gains: influence only, (B,) complex: the influence coefficients g per bin. With z_sw
            the measured 1x vector over the ``anchor`` samples before the switch and
            ``anchor_mean`` its mean over the training runs, the predicted vector at speed v is
            b(v) + g(v) (z_sw - anchor_mean), b the ``means`` (the training runs' mean vector):
            a linear rotor's response to the run's own unbalance u is H(v) u, so the vector at
            any speed is an affine function of the vector at the switch, the ratio H(v) / H(v_sw)
            being what trim balancing calls an influence coefficient. b and g are least squares
            per bin over every training sample (with its run's z_sw), g shrunk by ``ridge``
            (relative to the spread of the runs' z_sw; default 1e-3) where the runs' anchors
            cannot tell it.
        anchor_mean: influence only, the training runs' mean z_sw (complex).
        decay: the anchored ones, (3,): (alpha, beta, r). The anchor's term a (what the run's
            level at the switch adds to the curve: the weights' or the gains' term above) fades
            as (alpha + beta r^k) a, k the samples since the switch: a rotor bowed by a hot
            shutdown carries a 1x vector that fades within minutes once it runs, while the run's
            own imbalance stays. alpha + beta = 1 (influence: a scale of the gains' term);
            alpha (the share that stays) and r = exp(-1 / (tau FS)) are chosen by the training
            runs' leave-one-run-out error with the weights (``_fade_fit``); (1, 0, 1): the
            anchor held (no fade that predicts other runs better, or a bundle from before).

    A law that differs on the way up and down is recovered exactly:

    >>> up = np.arange(1002.5, 2000.0, 5.0)  # the bins' centres
    >>> speed = np.concatenate([up, up[::-1]])
    >>> law = np.where(np.diff(speed, prepend=speed[0]) >= 0, speed / 1000.0, 3.0)
    >>> traj = Trajectory(law, speed[:, None], start=0)
    >>> m = CurveModel.fit(Method.CURVE, {"variant": "fleet", "bin": 5.0, "window": 1,
    ...                                   "deadband": 1.0}, [traj])
    >>> rt = m.runtime()
    >>> rt.start(np.array([1.0]), np.array([[1497.5]]))
    >>> rt.step([1502.5]), rt.step([1497.5])
    (1.5025, 3.0)

    Runs whose level is the curve's times a run factor are followed from their switch:

    >>> speed = np.concatenate([np.full(50, 1010.0), np.arange(1010.0, 3000.0, 20.0)])  # bin centres
    >>> trajs = [Trajectory(f * speed / 1000.0, speed[:, None], start=50) for f in (1.0, 2.0, 3.0)]
    >>> m = CurveModel.fit(Method.CURVE, {"variant": "anchored", "bin": 20.0, "anchor": 10}, trajs)
    >>> np.round(m.weights, 6) + 0.0
    array([1., 0.])
    >>> new = Trajectory(2.5 * speed / 1000.0, speed[:, None], start=50)
    >>> round(float(m.predict(new)[-1]), 6)  # the fleet curve says 2 x 2.99 at 2990 rpm
    7.475
    """

    params: dict
    centres: np.ndarray
    means: np.ndarray
    weights: np.ndarray = field(default_factory=lambda: np.zeros(2))
    gains: np.ndarray = field(default_factory=lambda: np.zeros(0, complex))
    anchor_mean: complex = 0j
    decay: np.ndarray = field(default_factory=lambda: np.array(HELD))
    method: ClassVar[Method] = Method.CURVE
    repaired: ClassVar[int] = 0
    n_states: ClassVar[int] = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "centres", _readonly(self.centres))
        kind = complex if self.variant.on_vector else float
        object.__setattr__(self, "means", _readonly(np.reshape(self.means, (3, -1)), kind))
        object.__setattr__(self, "weights", _readonly(np.reshape(self.weights, (2,))))
        object.__setattr__(self, "gains", _readonly(np.reshape(self.gains, (-1,)), complex))
        object.__setattr__(self, "anchor_mean", complex(self.anchor_mean))
        object.__setattr__(self, "decay", _readonly(np.reshape(self.decay, (3,))))
        if not (np.isfinite(self.decay).all() and 0.0 < self.decay[2] <= 1.0):
            raise ValueError(f"a curve's decay must be finite with its ratio in (0, 1], not {self.decay}")

    @property
    def variant(self) -> Variant:
        return Variant(self.params.get("variant", Variant.FLEET))

    @classmethod
    def fit(cls, method: Method, params: dict, trajs: Sequence[Trajectory]) -> CurveModel:
        """The binned mean of the OC samples' target against their one input (the speed);
        anchored: of every sample with its past (so the curve knows the speed at the switch),
        then the anchoring weights by least squares over the OC samples; influence: the mean
        vector and the gains per bin by least squares. ``from_parts`` of each trajectory's
        ``part``."""
        return cls.from_parts(params, [cls.part(params, t) for t in trajs])

    @classmethod
    def part(cls, params: dict, traj: Trajectory) -> CurvePart:
        """What the fit of ``params`` needs of ``traj`` (see :class:`CurvePart`)."""
        if traj.U.shape[1] != 1:
            raise ValueError("a curve model takes exactly one input")
        variant = Variant(params.get("variant", Variant.FLEET))
        if variant is Variant.RUN:
            return CurvePart(np.zeros(0, np.int64), np.zeros((3, 0)), np.zeros((3, 0), np.int64))
        width, window = float(params.get("bin", 25.0)), int(params.get("window", 0))
        deadband = float(params.get("deadband", 0.0))
        vector = variant.on_vector
        if vector and traj.z is None:
            raise ValueError("a vector curve needs the target's phase")
        level, start = _levels(traj, vector), traj.start
        seg_x = np.asarray(traj.seg_U[:, 0], float)
        past = traj.U[:start, 0][-window:] if window > 0 else traj.U[:0, 0]
        if not variant.anchored:
            codes = direction_codes(past, seg_x, window, deadband)
            return CurvePart(*_code_bin_sums(seg_x, traj.seg_y, codes, width))
        # whole trajectories: the switch is in the past (the influence curve: one curve)
        window = 0 if variant is Variant.INFLUENCE else window
        speed = np.asarray(traj.U[:, 0], float)
        codes = direction_codes(speed[:0], speed, window, deadband)
        bins, sums, counts = _code_bin_sums(speed, level, codes, width)
        anchor = _anchor_window(level[:start], traj.U[:start], int(params.get("anchor", FS)))
        if variant is Variant.INFLUENCE:
            finite = anchor is not None and cmath.isfinite(anchor[0])
            return CurvePart(bins, sums, counts, seg_x, np.zeros(seg_x.size, np.int64), level[start:],
                             y_sw=anchor[0] if anchor and finite else None)
        y_sw, anchor_x = anchor if anchor else (None, np.zeros(0))
        return CurvePart(bins, sums, counts, seg_x, direction_codes(past, seg_x, window, deadband),
                         level[start:], anchor_x, y_sw)

    @classmethod
    def from_parts(cls, params: dict, parts: Sequence[CurvePart]) -> CurveModel:
        """The model ``fit`` gives on the trajectories of ``parts`` (in their order)."""
        variant = Variant(params.get("variant", Variant.FLEET))
        if variant is Variant.RUN:
            return cls(dict(params), np.zeros(0), np.zeros((3, 0)))
        if variant is Variant.INFLUENCE:
            return cls._with_decay(cls._from_parts_influence(params, parts), parts)
        width = float(params.get("bin", 25.0))
        bins, sums, counts = _merge_parts(parts)
        if not bins.size:
            raise ValueError("no finite (speed, target) pairs to fit a curve")
        centres = (bins + 0.5) * width
        means = _binned_means(sums, counts, int(params.get("min_count", 1)))
        plain = cls(dict(params), centres, means)
        if not variant.anchored:
            return plain
        vector = variant.on_vector
        rt = plain.runtime()
        use = [(p, p.y_sw) for p in parts if p.y_sw is not None]
        if not use:
            return cls(dict(params), centres, means, np.zeros(2))
        # every part's lookups at once (each sample's on its own: the same numbers)
        c_anchor = rt._lookups(np.concatenate([p.anchor_x for p, _ in use]), STEADY)
        c_seg = rt._table(np.concatenate([p.seg_x for p, _ in use]),
                          np.concatenate([p.seg_codes for p, _ in use]))
        if not vector:
            c_anchor, c_seg = c_anchor.real, c_seg.real
        rows, targets, since, runs = [], [], [], []
        a0 = s0 = 0
        for k, (p, y_sw) in enumerate(use):
            a1, s1 = a0 + p.anchor_x.size, s0 + p.seg_x.size
            c_sw, c = _mean(c_anchor[a0:a1]), c_seg[s0:s1]
            a0, s0 = a1, s1
            if not (cmath.isfinite(c_sw) and cmath.isfinite(y_sw)) or c_sw == 0.0:
                continue  # as the stepper: no anchor
            rows.append(np.column_stack([c * (y_sw / c_sw - 1.0), np.full(c.size, y_sw - c_sw)]))
            targets.append(p.seg_level - c)
            since.append(np.arange(c.size, dtype=float))
            runs.append(np.full(c.size, k))
        if not rows:
            return cls(dict(params), centres, means, np.zeros(2))
        weights, decay = _fade_fit(np.vstack(rows), np.concatenate(targets), np.concatenate(since),
                                   np.concatenate(runs), True, bool(params.get("fade", False)))
        return cls(dict(params), centres, means, weights, decay=decay)

    @classmethod
    def _with_decay(cls, model: CurveModel, parts: Sequence[CurvePart]) -> CurveModel:
        """The influence curve ``model`` with the fade of its anchor's term that fits the parts'
        OC samples best (``_fade_fit``, its gains kept); held where no run has an anchor."""
        if not model.params.get("fade", False):
            return model
        rt = model.runtime()
        terms, resid, since, runs = [], [], [], []
        for k, p in enumerate(parts):
            if p.y_sw is None or not p.seg_x.size:
                continue
            got = rt.anchor_terms(p.y_sw, p.anchor_x, p.seg_x, p.seg_codes)
            if got is None:
                continue
            c, a = got
            terms.append(a[:, None])
            resid.append(p.seg_level - c)
            since.append(np.arange(p.seg_x.size, dtype=float))
            runs.append(np.full(p.seg_x.size, k))
        if not terms:
            return model
        _, decay = _fade_fit(np.vstack(terms), np.concatenate(resid), np.concatenate(since),
                             np.concatenate(runs), False)
        return dataclasses.replace(model, decay=decay)

    @classmethod
    def _from_parts_influence(cls, params: dict, parts: Sequence[CurvePart]) -> CurveModel:
        """b and g per speed bin by least squares over every sample of the trajectories (with
        their past) against its run's vector at the switch (see the class's ``gains``): a run's
        anchor is one number, so its samples enter each bin by their count and sum alone."""
        width, ridge = float(params.get("bin", 25.0)), float(params.get("ridge", 1e-3))
        known = [p for p in parts if p.y_sw is not None]
        # only runs with their vector at the switch tell the gains; none: the plain mean
        # vector per bin (as a node without the anchor predicts)
        use = known or list(parts)
        bins, sums, counts = _merge_parts(use)
        n_rb, z_rb = counts[:, STEADY, :].astype(float), sums[:, STEADY, :].astype(complex)  # (P, B)
        n_r, n_b = n_rb.sum(axis=1), n_rb.sum(axis=0)
        if not n_r.sum():
            raise ValueError("no finite (speed, 1x vector) pairs to fit a curve")
        a = np.array([p.y_sw for p in known], complex) if known else np.zeros(len(use), complex)
        a_mean = complex(np.sum(n_r * a) / n_r.sum()) if known else 0j
        x = a - a_mean  # (P,) each run's anchor about the mean
        keep = n_b > 0
        bins, n_rb, z_rb, n_b = bins[keep], n_rb[:, keep], z_rb[:, keep], n_b[keep]
        xm = (n_rb * x[:, None]).sum(axis=0) / n_b
        zm = z_rb.sum(axis=0) / n_b
        dx = x[:, None] - xm[None, :]
        sxx = (n_rb * np.abs(dx) ** 2).sum(axis=0)
        sxz = (np.conj(dx) * (z_rb - n_rb * zm[None, :])).sum(axis=0)
        mean_x2 = float(np.sum(n_r * np.abs(x) ** 2) / n_r.sum())
        g = sxz / (sxx + ridge * n_b * mean_x2 + 1e-300)  # 0 where x is 0
        b = zm - g * xm  # the mean vector at the runs' mean anchor
        return cls(dict(params), (bins + 0.5) * width, np.tile(b, (3, 1)), gains=g, anchor_mean=a_mean)

    def predict(self, traj: Trajectory) -> np.ndarray:
        """Prediction over the OC samples of ``traj``, by the node's stepper vectorised
        (``CurveRuntime.speeds_ahead``: the same numbers to the last bit): (K_seg,)."""
        if self.variant is Variant.RUN:
            return np.array(traj.seg_U[:, 0], dtype=float)
        rt = self.runtime()
        rt.start(_levels(traj, self.variant.on_vector)[:traj.start], traj.U[:traj.start])
        pred = rt.speeds_ahead(traj.seg_U[:, 0])
        # the modulus as Python's abs() takes it (numpy's own may differ in the last bit)
        return np.hypot(pred.real, pred.imag) if self.variant.on_vector else pred.real

    def runtime(self) -> CurveRuntime:
        return CurveRuntime(self)

    @functools.cached_property
    def tables(self) -> LookupTables:
        """The runtime's lookup tables, built on first use and shared by every runtime (read
        only): the centres, the rows (``means``' three, and influence's gains as a fourth,
        ``GAINS``) and their slopes between centres, as Python lists (a sample's lookup) and as
        arrays (the vectorised lookups: speeds_ahead, the anchor)."""
        xs = [float(x) for x in self.centres]
        rows: list[list[complex]] = [row.tolist() for row in self.means]
        if self.variant is Variant.INFLUENCE:
            rows.append(self.gains.tolist())
        slopes = [[(r[i + 1] - r[i]) / (xs[i + 1] - xs[i]) for i in range(len(r) - 1)] for r in rows]
        return LookupTables(xs, rows, slopes, np.array(xs), np.array(rows, complex),
                            np.array(slopes, complex).reshape(len(rows), -1))

    def arrays(self) -> dict[str, np.ndarray]:
        out = {"centres": self.centres, "means": self.means.real}
        if self.variant.on_vector:
            out["means_im"] = self.means.imag
        if self.variant in (Variant.ANCHORED, Variant.VECTOR):
            out["weights"] = self.weights
        if self.variant.anchored:
            out["decay"] = self.decay
        if self.variant is Variant.INFLUENCE:
            out["gains"], out["gains_im"] = self.gains.real, self.gains.imag
            out["anchor_mean"] = np.array([self.anchor_mean.real, self.anchor_mean.imag])
        return out

    @classmethod
    def from_arrays(cls, method: Method, params: dict, arrays: Mapping[str, np.ndarray],
                    repaired: int = 0) -> CurveModel:
        means = arrays["means"] + 1j * arrays["means_im"] if "means_im" in arrays else arrays["means"]
        gains = arrays["gains"] + 1j * arrays["gains_im"] if "gains" in arrays else np.zeros(0, complex)
        a_mean = complex(*arrays["anchor_mean"]) if "anchor_mean" in arrays else 0j
        return cls(dict(params), arrays["centres"], means,
                   arrays["weights"] if "weights" in arrays else np.zeros(2), gains, a_mean,
                   arrays["decay"] if "decay" in arrays else np.array(HELD))


def _levels(traj: Trajectory, vector: bool) -> np.ndarray:
    """What a curve is fitted to and anchored on: the 1x vectors (K,) complex, or the target (K,)."""
    if not vector:
        return traj.y
    if traj.z is None:  # no phase recorded: as the node without it, no anchor
        return np.full(traj.y.shape, NAN_VECTOR)
    return traj.z


class CurveRuntime:
    """Online stepper of a :class:`CurveModel`: a bin lookup per sample.

    Memory: the last ``window`` speeds (the direction of the speed's recent change), and
    for an anchored curve the run's level at the switch (``anchor``: (y_sw, c_sw) or None);
    a vector curve's are complex, ``start`` takes the 1x vectors as its measured past, and
    ``step`` returns the predicted amplitude, the predicted vector left in ``vector``.

    >>> m = CurveModel({"variant": "fleet", "window": 0}, np.array([0.0, 100.0]),
    ...                np.tile([0.0, 10.0], (3, 1)))
    >>> rt = m.runtime()
    >>> rt.start(np.zeros(0), np.zeros((0, 1)))
    >>> rt.step([25.0]), rt.step([500.0])
    (2.5, 10.0)
    """

    def __init__(self, model: CurveModel) -> None:
        self._run = model.variant is Variant.RUN
        self._vector = model.variant.on_vector
        self._anchored = model.variant.anchored
        self._influence = model.variant is Variant.INFLUENCE
        self._anchor_mean = model.anchor_mean
        self._anchor_n = int(model.params.get("anchor", FS))
        self._w_mul, self._w_add = (float(w) for w in model.weights)
        self.anchor: tuple[complex, complex] | None = None
        self._alpha, self._beta, self._ratio = (float(v) for v in model.decay)
        self._fades = model.variant.anchored and (self._alpha, self._beta) != HELD[:2]
        self._fade = 1.0  # ratio ** (samples since the switch)
        self._shift: complex = 0.0
        self._gain: complex = 0.0
        self.vector: complex = math.nan  # the last predicted 1x vector (vector curves)
        # the lookup tables, read only (built once per model: an OC switch builds a runtime)
        self._xs, self._rows, self._slopes, self._xa, self._ra, self._sa = model.tables
        window = int(model.params.get("window", 0))
        self._deadband = float(model.params.get("deadband", 0.0))
        self._past: deque[float] | None = deque(maxlen=window) if window > 0 else None

    def start(self, y_hist: np.ndarray, U_hist: np.ndarray) -> None:
        """Seed the recent speeds (and the anchor) from the measured past y_hist (K1,) (the 1x
        vectors, complex, for a vector curve), U_hist (K1, 1) (K1 may be 0)."""
        if self._anchored:
            levels = np.asarray(y_hist, complex if self._vector else float)
            self._set_anchor(levels, np.asarray(U_hist, float))
        if self._past is None:
            return
        self._past.clear()
        n = self._past.maxlen or 0
        for x in np.asarray(U_hist, float)[:, 0][-n:].tolist() if len(U_hist) else []:
            if x == x:
                self._past.append(x)

    def _set_anchor(self, y_hist: np.ndarray, U_hist: np.ndarray) -> None:
        """The run's level just before the switch against the steady curve's there."""
        self.anchor, self._shift, self._gain, self._fade = None, 0.0, 0.0, 1.0
        window = _anchor_window(y_hist, U_hist, self._anchor_n)
        if window is not None:
            self._anchor_at(*window)

    def _anchor_at(self, y_sw: complex, x: np.ndarray) -> None:
        """Anchor on the mean level y_sw over the anchor window, whose speeds are x (k,)."""
        if self._influence:
            if cmath.isfinite(y_sw):
                self.anchor = (y_sw, self._anchor_mean)
                self._shift = y_sw - self._anchor_mean
            return
        c = self._lookups(x, STEADY)  # each sample's _lookup, at once
        c_sw = _mean(c if self._vector else c.real)
        if not (cmath.isfinite(y_sw) and cmath.isfinite(c_sw)) or c_sw == 0.0:
            return
        self.anchor = (y_sw, c_sw)
        self._gain = self._w_mul * (y_sw / c_sw - 1.0)
        self._shift = self._w_add * (y_sw - c_sw)

    def step(self, u: Sequence[float] | np.ndarray) -> float:
        """Prediction for this sample from its raw input u (1,): the speed, or run_curve itself."""
        if self._run:
            return float(u[0])
        if self._vector:
            self.vector = self.step_speed(float(u[0]))
            return abs(self.vector)
        return self.step_speed(float(u[0])).real

    def speeds_ahead(self, speeds: np.ndarray) -> np.ndarray:
        """``step_speed`` over speeds (K,) at once, vectorised for training: the same numbers to
        the last bit (the same real operations in the same order: numpy's own complex product
        and modulus may round otherwise); complex (K,). The stepper's recent speeds are left
        as ``start`` set them."""
        x = np.asarray(speeds, float)
        codes = np.zeros(x.size, dtype=np.int64)
        if self._past is not None:
            codes = direction_codes(np.array(self._past, float), x, self._past.maxlen or 0, self._deadband)
        c = self._table(x, codes)
        if self.anchor is not None and self._fades:
            fade = np.cumprod(np.concatenate([[self._fade], np.full(max(x.size - 1, 0), self._ratio)]))
            share = self._alpha + self._beta * fade
            c = _add_faded(c, self._term(x, c), share, self._vector or self._influence)
        elif self.anchor is not None:
            if self._influence:
                c = c + _cmul(self._lookups(x, GAINS), complex(self._shift))
            elif self._vector:
                c = c + _cmul(c, complex(self._gain)) + complex(self._shift)
            else:  # real: as Python floats
                c = (c.real + float(self._gain.real) * c.real + float(self._shift.real)).astype(complex)
        c[~np.isfinite(x)] = complex(math.nan, 0.0)
        return c

    def _term(self, x: np.ndarray, c: np.ndarray) -> np.ndarray:
        """What the anchor adds to the curve c (K,) at the speeds x (K,), vectorised as
        ``step_speed`` adds it: complex (K,)."""
        if self._influence:
            return _cmul(self._lookups(x, GAINS), complex(self._shift))
        if self._vector:
            return _cmul(c, complex(self._gain)) + complex(self._shift)
        return (float(self._gain.real) * c.real + float(self._shift.real)).astype(complex)

    def anchor_terms(self, y_sw: complex, anchor_x: np.ndarray, x: np.ndarray, codes: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray] | None:
        """For fitting the fade: the curve (K,) at the speeds x (K,) in their directions
        ``codes`` (K,) and the anchor's unfaded term there (K,) for a run whose mean level over
        the anchor window (speeds ``anchor_x``) was y_sw; None when that anchors nothing. Real
        for the amplitude curve, else complex. Leaves this stepper anchored there."""
        self.anchor = None
        self._anchor_at(y_sw, np.asarray(anchor_x, float))
        if self.anchor is None:
            return None
        c = self._table(np.asarray(x, float), np.asarray(codes, np.int64))
        a = self._term(np.asarray(x, float), c)
        vector = self._vector or self._influence
        return (c, a) if vector else (c.real, a.real)

    def _table(self, x: np.ndarray, codes: np.ndarray) -> np.ndarray:
        """The curve of each speed x (K,) in its direction ``codes`` (K,), without the anchor:
        complex (K,), NaN where x is (``_lookup`` of each, the same numbers to the last bit)."""
        xs, rows, slopes = self._xa, self._ra, self._sa
        i = np.searchsorted(xs, x, side="right")
        j = np.clip(i - 1, 0, max(xs.size - 2, 0))
        c = np.empty(x.size, complex)
        for code in np.unique(codes):
            m = codes == code
            c[m] = _interp(rows[code], slopes[code], xs, i[m], j[m], x[m])
        c[~np.isfinite(x)] = complex(math.nan, 0.0)
        return c

    def _lookups(self, x: np.ndarray, code: int) -> np.ndarray:
        """``_lookup`` of each speed x (K,) on row ``code``: complex (K,), the same numbers to the
        last bit (``_interp``); a non-finite x gets a value its caller must discard."""
        i = np.searchsorted(self._xa, x, side="right")
        j = np.clip(i - 1, 0, max(self._xa.size - 2, 0))
        return _interp(self._ra[code], self._sa[code], self._xa, i, j, x)

    def _lookup(self, x: float, code: int) -> complex:
        xs, ys = self._xs, self._rows[code]
        i = bisect.bisect_right(xs, x)
        if i == 0:
            return ys[0]
        if i == len(xs):
            return ys[-1]
        return ys[i - 1] + self._slopes[code][i - 1] * (x - xs[i - 1])

    def step_speed(self, x: float) -> complex:
        """Prediction at speed x (rpm) (NaN: NaN, and the recent speeds are kept); complex for a
        vector curve, else real."""
        if self._fades:  # the fade advances with every sample, a NaN one too
            fade = self._fade
            self._fade = fade * self._ratio
        if x != x:
            return math.nan
        code = STEADY
        past = self._past
        if past is not None:
            if past:
                change = x - past[0]
                code = RISING if change > self._deadband else FALLING if change < -self._deadband else STEADY
            past.append(x)
        c = self._lookup(x, code)
        if self.anchor is None:
            return c
        if self._fades:
            if self._influence:
                term = self._lookup(x, GAINS) * self._shift
            else:
                term = self._gain * c + self._shift
            share = self._alpha + self._beta * fade
            if self._vector or self._influence:
                return c + complex(term.real * share, term.imag * share)
            return c + term.real * share
        if self._influence:
            return c + self._lookup(x, GAINS) * self._shift
        return c + self._gain * c + self._shift


def _fade_fit(X: np.ndarray, r: np.ndarray, since: np.ndarray, runs: np.ndarray, fit_weights: bool,
              fade: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """The anchor's weights and fade (``CurveModel.decay``) that predict new runs best.

    X (n, m): the anchor's terms per sample (m = 2, the weights' columns; or m = 1, the
    influence curve's term); r (n,): the samples' residual from the curve; since (n,): samples
    since the switch; runs (n,): each sample's run; real or complex (both parts count). The
    anchor's share of its term is s = alpha + (1 - alpha) ratio^since: 1 at the switch (all the
    run's deviation there), alpha once faded (the part that stays: the run's own imbalance; the
    rest, a bow, fades). Held (s = 1) and every alpha of ``FADE_SHARES`` with every fade time of
    ``DECAY_TAUS`` are compared by their leave-one-run-out squared error (a run's samples are
    not independent: an in-sample criterion took fades from noise); a fade must beat the held
    anchor by ``FADE_GAIN``, and needs 3 runs. With ``fit_weights`` the weights are least
    squares for each s; without, the weight is 1 when held and a fade's scale is least squares
    too, folded into the decay as (w alpha, w (1 - alpha), ratio). The chosen s's weights are
    then least squares over every run. Without ``fade``: held. Returns (weights (m,), decay (3,)).
    """
    ok = np.isfinite(r) & np.isfinite(X).all(axis=1)  # complex: both parts (a NaN speed's curve
    X, r, since, runs = X[ok], r[ok], since[ok], runs[ok]  # is NaN + 0j, its influence term whatever)
    if np.iscomplexobj(X) or np.iscomplexobj(r):
        X, r = np.vstack([X.real, X.imag]), np.concatenate([r.real, r.imag])
        since, runs = np.tile(since, 2), np.tile(runs, 2)
    n, m = X.shape
    ones = np.ones(m)
    if n <= m + 3:
        return (np.zeros(m) if fit_weights else ones), np.array(HELD)
    _, group = np.unique(runs, return_inverse=True)
    n_runs = int(group.max()) + 1
    best: tuple[float, np.ndarray, tuple[float, float, float]] | None = None
    if fade and n_runs >= 3:
        held = _loo_sse(X, r, group, n_runs, fit_weights)
        for tau in DECAY_TAUS:
            ratio = math.exp(-1.0 / (tau * FS))
            left = ratio ** since
            for alpha in FADE_SHARES:
                share = alpha + (1.0 - alpha) * left
                sse = _loo_sse(X * share[:, None], r, group, n_runs, True)
                if sse < (1.0 - FADE_GAIN) * held and (best is None or sse < best[0]):
                    best = (sse, share, (alpha, 1.0 - alpha, ratio))
    if best is None:
        w = np.linalg.lstsq(X, r, rcond=None)[0] if fit_weights else ones
        return np.asarray(w, float), np.array(HELD)
    _, share, (alpha, beta, ratio) = best
    w = np.linalg.lstsq(X * share[:, None], r, rcond=None)[0]
    if fit_weights:
        return np.asarray(w, float), np.array([alpha, beta, ratio])
    scale = float(w[0])
    return ones, np.array([scale * alpha, scale * beta, ratio])


def _loo_sse(X: np.ndarray, r: np.ndarray, group: np.ndarray, n_runs: int, fit_weights: bool) -> float:
    """Leave-one-run-out squared error of r (n,) ~ X w (X (n, m)), each run's w least squares on
    the other runs' samples (``fit_weights``; else w = 1), from the runs' sums of products."""
    m = X.shape[1]
    G = np.empty((n_runs, m, m))
    b = np.empty((n_runs, m))
    for i in range(m):
        b[:, i] = np.bincount(group, X[:, i] * r, n_runs)
        for j in range(i, m):
            G[:, i, j] = G[:, j, i] = np.bincount(group, X[:, i] * X[:, j], n_runs)
    c = np.bincount(group, r * r, n_runs)
    if fit_weights:
        G_all, b_all = G.sum(axis=0), b.sum(axis=0)
        w = np.stack([np.linalg.lstsq(G_all - G[g], b_all - b[g], rcond=None)[0] for g in range(n_runs)])
    else:
        w = np.ones((n_runs, m))
    return float(np.sum(c - 2.0 * np.einsum("gi,gi->g", w, b) + np.einsum("gi,gij,gj->g", w, G, w)))


def _add_faded(c: np.ndarray, term: np.ndarray, share: np.ndarray, vector: bool) -> np.ndarray:
    """c + term x share (K,) (share real) as ``CurveRuntime.step_speed`` adds it, each part on
    its own: complex (K,)."""
    if not vector:
        return (c.real + term.real * share).astype(complex)
    out = np.empty(c.size, complex)
    out.real = c.real + term.real * share
    out.imag = c.imag + term.imag * share
    return out


def _cmul(a: np.ndarray, b: complex) -> np.ndarray:
    """a * b (K,) complex as CPython multiplies complex numbers (``_Py_c_prod``)."""
    return (a.real * b.real - a.imag * b.imag) + 1j * (a.real * b.imag + a.imag * b.real)


def _interp(ys: np.ndarray, slopes: np.ndarray, xs: np.ndarray, i: np.ndarray, j: np.ndarray,
            x: np.ndarray) -> np.ndarray:
    """``CurveRuntime._lookup`` vectorised (K,): i = bisect_right(xs, x), j = i - 1 clipped to a
    segment; a complex slope times a real offset as CPython does it."""
    if slopes.size == 0:
        return np.full(x.size, ys[0], complex)
    sl, dx = slopes[j], x - xs[j]
    out = ys[j] + ((sl.real * dx - sl.imag * 0.0) + 1j * (sl.real * 0.0 + sl.imag * dx))
    out = np.where(i == 0, ys[0], out)
    return np.where(i == xs.size, ys[-1], out)


def _mean(values: np.ndarray | Sequence[complex]) -> complex:
    """Exact-sum mean of real or complex values (K,) (real stays real)."""
    a = np.asarray(values)
    re = math.fsum(a.real.tolist()) / a.size
    if not np.iscomplexobj(a):
        return re
    return complex(re, math.fsum(a.imag.tolist()) / a.size)


def _anchor_window(y_hist: np.ndarray, U_hist: np.ndarray, n: int) -> tuple[complex, np.ndarray] | None:
    """The mean level over the last ``n`` samples before the switch where the level y_hist (K1,)
    and the speed U_hist (K1, 1) are finite, and those speeds (k,); None: fewer than ``n``
    samples of past, or none of them finite."""
    if n <= 0 or len(y_hist) < n:
        return None
    y, x = y_hist[-n:], U_hist[-n:, 0]
    ok = np.isfinite(y) & np.isfinite(x)
    if not ok.any():
        return None
    return _mean(y[ok]), np.asarray(x[ok], float)
