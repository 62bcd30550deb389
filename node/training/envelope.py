"""Each OC model's envelope (``node.models.envelope``) from its training segments, and its band
factor from the cross-validation.

The envelope covers the samples the model was fitted on, from the OC switch on: its inputs
and the seconds since the switch. How much wider the residual band must be outside is what the
cross-validation shows: each fold's envelope is fitted on the runs the fold trains on, and the
held-out runs' samples beyond it are the new runs' samples outside; their mean squared
standardized residual, against 1 inside the calibration, gives the factor (``band_factors``:
per OC where the CV held at least ``MIN_OUTSIDE`` such samples, else pooled over the target's
OCs).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from node.contract import FS
from node.models.envelope import OUTSIDE, Envelope
from node.training.ocdata import OCData

MIN_OUTSIDE = int(FS)  # CV samples outside (1 s) an OC needs for a band factor of its own


def segment_features(d: OCData, row: int, inputs: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    """A segment's model inputs (K, m) and seconds since the switch (K,), from the switch on."""
    cols = [d.candidates.index(c) for c in inputs]
    X = d.X[row][d.start[row]:, cols]
    return X, np.arange(len(X)) / FS


def fit_envelope(d: OCData, rows: Sequence[int], inputs: Sequence[str]) -> Envelope:
    """The envelope of the segments ``rows`` in the model's ``inputs``."""
    parts = [segment_features(d, i, inputs) for i in rows]
    return Envelope.fit(inputs, np.concatenate([X for X, _ in parts]), np.concatenate([t for _, t in parts]))


def cv_outside(d: OCData, folds: Sequence[int], inputs: Sequence[str],
               residuals: Sequence[np.ndarray], sigma: float) -> tuple[float, int]:
    """Sum of the squared standardized CV residuals of the held-out samples outside their fold's
    envelope, and their count. residuals: the held-out segments' residuals (from the switch),
    in fold order (``d.held_out`` of each fold in turn), as the CV gives them."""
    rows = [i for f in folds for i in d.held_out(f)]
    if len(rows) != len(residuals):
        raise ValueError("one residual series per held-out segment, in fold order")
    by_row = dict(zip(rows, residuals))
    total, n = 0.0, 0
    for f in folds:
        fitted = d.fitted_on(f)
        if not fitted:
            continue
        try:
            env = fit_envelope(d, fitted, inputs)
        except (ValueError, np.linalg.LinAlgError):
            continue
        for i in d.held_out(f):
            X, t = segment_features(d, i, inputs)
            r = by_row[i][:len(t)]
            out = (env.distances(X[:len(r)], t[:len(r)]) > OUTSIDE) & np.isfinite(r)
            total += float(np.sum((r[out] / sigma) ** 2))
            n += int(out.sum())
    return total, n


def band_factors(stats: Sequence[tuple[float, int] | None]) -> list[float]:
    """Per OC the band factor (>= 1) from its ``cv_outside`` (sum, count): its own where the count
    reaches ``MIN_OUTSIDE``, else the OCs' pooled one, else 1.

    >>> [round(f, 3) for f in band_factors([(400.0, 100), (10.0, 5), None])]  # 4 sigma^2: twice
    [2.0, 1.976, 1.0]
    """
    total = sum(s for s, _ in filter(None, stats))
    count = sum(n for _, n in filter(None, stats))
    pooled = math.sqrt(total / count) if count >= MIN_OUTSIDE else 1.0
    out = []
    for st in stats:
        if st is None:
            out.append(1.0)
        elif st[1] >= MIN_OUTSIDE:
            out.append(max(1.0, math.sqrt(st[0] / st[1])))
        else:
            out.append(max(1.0, pooled))
    return out
