"""Where an OC model's knowledge ends: the region its training runs covered.

An OC model is trusted where its training runs went: in each of its inputs and in the time
since the OC switch (a dynamical model's free run is known only as long as training watched
it). ``Envelope`` keeps that region as per-feature ranges and a multivariate (Mahalanobis)
distance on the features scaled by their ranges, each normalised to 1 at the region's edge;
``distance`` is the larger of the two: at most 1 inside, above 1 outside (the contract's
``envelope`` field). Beyond the ranges the model never extrapolates: ``clamp`` holds each
input at the nearest edge of its range (the nearest in-envelope prediction; inside the
ranges it changes nothing), and the residual band is widened by ``band_factor``, which
training measures in the cross-validation (the held-out runs' samples outside the other
runs' envelope: how much larger their residuals were).

The node steps one sample at a time (``distance``, ``clamp``: plain floats, no numpy call);
training and evaluation take whole segments (``distances``, ``clamp_rows``).

>>> X = np.array([[3000.0], [3200.0], [3400.0]])  # one input, three training samples
>>> env = Envelope.fit(("nB",), X, np.array([0.0, 1.0, 2.0]))
>>> env.distance([3200.0], 1.0) <= 1.0, env.distance([3600.0], 1.0) > 1.0
(True, True)
>>> env.clamp([3600.0]), env.clamp([3100.0])
([3400.0], [3100.0])
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

SINCE_SWITCH = "since_switch"  # the envelope's last feature: seconds since the OC switch
RIDGE = 1e-3  # added to the scaled features' covariance (scaled units: the ranges are [-1, 1])
MAX_FEATURES = 64  # a bundle's envelope beyond this is malformed
OUTSIDE = 1.0  # the envelope value at the region's edge
HELD = "@envelope"  # a model id's suffix where the node predicted beyond it (inputs held at its edge)


def _scaling(low: np.ndarray, high: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each feature's centre and half-width (floored: a constant feature still scales)."""
    centre = (low + high) / 2.0
    return centre, np.maximum((high - low) / 2.0, 1e-9 * (np.abs(centre) + 1.0))


@dataclass(frozen=True, eq=False)
class Envelope:
    """The training region of one OC model (see the module).

    inputs: the model's inputs (m,), in its order; the features are these and
    ``SINCE_SWITCH``. low, high: (m + 1,) each feature's training range. mean: (m + 1,) the
    features' mean in scaled units ((x - centre) / half-width); whiten: (m + 1, m + 1), the
    upper Cholesky factor of the scaled features' precision, so that |whiten (x - mean)| is the
    Mahalanobis distance; d_max: its largest value over the training samples (the edge).
    band_factor: the residual band's widening outside (>= 1).
    """

    inputs: tuple[str, ...]
    low: np.ndarray
    high: np.ndarray
    mean: np.ndarray
    whiten: np.ndarray
    d_max: float
    band_factor: float = 1.0
    # the node's per-sample path in plain floats (derived in __post_init__)
    _lo: list[float] = field(init=False, repr=False)
    _hi: list[float] = field(init=False, repr=False)
    _centre: list[float] = field(init=False, repr=False)
    _half: list[float] = field(init=False, repr=False)
    _mean: list[float] = field(init=False, repr=False)
    _rows: list[list[float]] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        n = len(self.inputs) + 1
        for name in ("low", "high", "mean"):
            a = np.asarray(getattr(self, name), dtype=float)
            if a.shape != (n,) or not np.all(np.isfinite(a)):
                raise ValueError(f"envelope {name} must be {n} finite numbers")
            object.__setattr__(self, name, a)
        w = np.asarray(self.whiten, dtype=float)
        if w.shape != (n, n) or not np.all(np.isfinite(w)):
            raise ValueError(f"envelope whiten must be a finite {n} x {n} matrix")
        object.__setattr__(self, "whiten", w)
        if not np.all(self.low <= self.high):
            raise ValueError("envelope low must not exceed high")
        if not (math.isfinite(self.d_max) and self.d_max > 0):
            raise ValueError(f"envelope d_max must be a positive number, got {self.d_max!r}")
        if not (math.isfinite(self.band_factor) and self.band_factor >= 1.0):
            raise ValueError(f"envelope band_factor must be a number >= 1, got {self.band_factor!r}")
        centre, half = _scaling(self.low, self.high)
        object.__setattr__(self, "_lo", self.low[:-1].tolist())
        object.__setattr__(self, "_hi", self.high[:-1].tolist())
        object.__setattr__(self, "_centre", centre.tolist())
        object.__setattr__(self, "_half", half.tolist())
        object.__setattr__(self, "_mean", self.mean.tolist())
        object.__setattr__(self, "_rows", [row[j:].tolist() for j, row in enumerate(w)])  # upper

    @classmethod
    def fit(cls, inputs: Sequence[str], X: np.ndarray, since: np.ndarray) -> Envelope:
        """The envelope of training samples: X (N, m) the model's inputs, since (N,) seconds
        since the OC switch; rows with a non-finite value are left out."""
        F = np.column_stack([np.asarray(X, float).reshape(len(since), -1), np.asarray(since, float)])
        F = F[np.all(np.isfinite(F), axis=1)]
        if len(F) < 2:
            raise ValueError("an envelope needs at least two finite training samples")
        if F.shape[1] > MAX_FEATURES:
            raise ValueError(f"an envelope takes at most {MAX_FEATURES - 1} inputs")
        low, high = F.min(axis=0), F.max(axis=0)
        centre, half = _scaling(low, high)
        S = (F - centre) / half
        mean = S.mean(axis=0)
        cov = np.atleast_2d(np.cov(S, rowvar=False)) + RIDGE * np.eye(F.shape[1])
        whiten = np.linalg.cholesky(np.linalg.inv(cov)).T  # P = L L^T: |L^T s|^2 = s^T P s
        d = np.linalg.norm((S - mean) @ whiten.T, axis=1)
        return cls(tuple(inputs), low, high, mean, whiten, float(max(d.max(), 1e-12)))

    def with_band_factor(self, factor: float) -> Envelope:
        return replace(self, band_factor=max(1.0, float(factor)))

    def distance(self, u: Sequence[float], since_s: float) -> float:
        """The envelope value of one sample: inputs ``u`` (m,) and seconds since the switch."""
        s = [(x - c) / h for x, c, h in zip((*u, since_s), self._centre, self._half)]
        box = max(map(abs, s))
        d = [x - m for x, m in zip(s, self._mean)]
        sq = 0.0
        for j, row in enumerate(self._rows):
            v = 0.0
            for w, x in zip(row, d[j:]):
                v += w * x
            sq += v * v
        return max(box, math.sqrt(sq) / self.d_max)

    def distances(self, U: np.ndarray, since: np.ndarray) -> np.ndarray:
        """``distance`` of every row: U (K, m), since (K,) s; (K,)."""
        F = np.column_stack([np.asarray(U, float).reshape(len(since), -1), np.asarray(since, float)])
        centre, half = _scaling(self.low, self.high)
        S = (F - centre) / half
        box = np.max(np.abs(S), axis=1)
        maha = np.linalg.norm((S - self.mean) @ self.whiten.T, axis=1) / self.d_max
        return np.maximum(box, maha)

    def clamp(self, u: Sequence[float]) -> list[float]:
        """The inputs held within their training ranges (m,)."""
        return [lo if x < lo else hi if x > hi else x
                for x, lo, hi in zip(u, self._lo, self._hi)]

    def clamp_rows(self, U: np.ndarray) -> np.ndarray:
        """``clamp`` of every row of U (K, m)."""
        return np.clip(np.asarray(U, float), self.low[:-1], self.high[:-1])

    def arrays(self) -> dict[str, np.ndarray]:
        """What a bundle stores of it (with ``manifest``)."""
        return {"low": self.low, "high": self.high, "mean": self.mean, "whiten": self.whiten}

    def manifest(self) -> dict:
        return {"inputs": list(self.inputs), "d_max": self.d_max, "band_factor": self.band_factor}

    @classmethod
    def from_stored(cls, manifest: dict, arrays: dict[str, np.ndarray]) -> Envelope:
        """The envelope a bundle stored; a ``ValueError`` names what is malformed."""
        inputs = manifest.get("inputs")
        if not (isinstance(inputs, list) and all(isinstance(c, str) for c in inputs)
                and len(inputs) < MAX_FEATURES):
            raise ValueError(f"envelope inputs must be a list of channel names, got {inputs!r}")
        missing = [k for k in ("low", "high", "mean", "whiten") if k not in arrays]
        if missing:
            raise ValueError(f"envelope arrays missing: {', '.join(missing)}")
        d_max, factor = manifest.get("d_max"), manifest.get("band_factor", 1.0)
        if isinstance(d_max, bool) or not isinstance(d_max, (int, float)) \
                or isinstance(factor, bool) or not isinstance(factor, (int, float)):
            raise ValueError("envelope d_max and band_factor must be numbers")
        return cls(tuple(inputs), arrays["low"], arrays["high"], arrays["mean"], arrays["whiten"],
                   float(d_max), float(factor))
