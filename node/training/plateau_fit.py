"""Learning each OC's plateau shift (``node.models.plateau``) and settle anchor, and whether they help.

Per OC, from the training runs' visits (``plateau_visits``: the level before the switch, the
run's earlier plateaus, the visit's own plateau): two ridge regressions of the plateau, on the
level before the switch and the earlier plateaus, and on the level before the switch alone
(``fit_shift``). Whether the OC model's prediction is shifted is decided by the OC's own
cross-validation: the shift fitted on each fold's other runs moves the chosen model's
held-out predictions of that fold, and it is kept when their pooled eps falls by
``PLATEAU_GAIN`` (``choose_shift``), so an OC whose plateau the earlier ones do not tell keeps its
model as it is.

The settle anchor (``node.models.settle``) is learnt the same way from the chosen model's
held-out visits alone: its gain by ``fit_settle``, kept by ``choose_settle`` where the OC's CV
says it helps.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from node.contract import phase_channel
from node.contract.vector import order_vector
from node.models.plateau import PlateauShift
from node.models.settle import AT, MAX_GAIN, WINDOW, SettleAnchor
from node.runtime.plateaus import plateau_visits
from node.sysid.metrics import pooled_eps
from node.training.runs import Run

RIDGE = 1e-2  # the regressions' ridge, relative to the mean squared level of the regressors
PLATEAU_GAIN = 0.01  # the shift must lower the OC's CV eps by this share to be kept
MIN_RUNS = 4  # visits (runs) an OC's shift is fitted on, at least
LIMIT_FACTOR = 2.0  # the shift is clipped at this times the largest the training visits gave
# (study: docs/tuning.md#plateau_shift)

Visit = tuple[complex, list[complex], complex]  # level before the switch, plateaus then, its own


def run_levels(run: Run, target: str, vector: bool) -> np.ndarray:
    """The measured level of each sample (K,) complex: the 1x vector (amplitude and phase as
    measured, NaN where either is not; ``order_vector`` sample by sample, as the node computes
    it) or the amplitude."""
    y = run.column(target)
    if not vector:
        return y.astype(complex)
    ph = run.column(phase_channel(target))
    return np.array([order_vector(a, p) for a, p in zip(y.tolist(), ph.tolist(), strict=True)], complex)


def visit_tables(runs: Sequence[Run], codes: Sequence[np.ndarray], target: str, n_ocs: int,
                 vector: bool) -> list[dict[int, Visit]]:
    """Per run, its visits by start (``plateau_visits``) from its OC labels ``codes``."""
    return [plateau_visits(run_levels(r, target, vector), c, n_ocs) for r, c in zip(runs, codes, strict=True)]


def fit_shift(visits: Sequence[Visit], vector: bool) -> PlateauShift | None:
    """The shift fitted on ``visits`` of one OC (None: fewer than ``MIN_RUNS`` usable visits or
    no earlier plateau held in all of them).

    >>> pre, first = np.tile([1.0, -1.0], 4), np.repeat([1.0, -1.0], 2).repeat(2)  # apart, mean 0
    >>> own = 0.5 * pre + 2.0 * first + 1.0  # the plateau: the switch and the run's first plateau
    >>> s = fit_shift([(complex(p), [complex(f)], complex(o)) for p, f, o in zip(pre, first, own)], False)
    >>> s.earlier, round(s.shift(0.0, [1.0]), 1)  # what the first plateau adds to the switch's word
    ((0,), 2.0)
    """
    ok = [v for v in visits if _finite(v[0]) and _finite(v[2])]
    if len(ok) < MIN_RUNS:
        return None
    n = len(ok[0][1])
    earlier = tuple(o for o in range(n) if all(_finite(v[1][o]) for v in ok))
    if not earlier:
        return None
    X = np.array([[v[0], *(v[1][o] for o in earlier)] for v in ok], complex)
    y = np.array([v[2] for v in ok], complex)
    if not vector:
        X, y = X.real.astype(complex), y.real.astype(complex)
    coef = _ridge(X, y)
    coef_pre = _ridge(X[:, :1], y)
    pre = (complex(coef_pre[0]), complex(coef_pre[1]))
    # unclipped first: the training visits' own shifts set the limit
    free = PlateauShift(earlier, tuple(complex(c) for c in coef), pre, vector, 1e300)
    biggest = max(abs(free.shift(v[0], v[1])) for v in ok)
    return PlateauShift(free.earlier, free.coef, free.coef_pre, vector, LIMIT_FACTOR * biggest)


def _ridge(X: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Least squares of y (n,) on X (n, m) and an intercept (last), the columns of X shrunk by
    ``RIDGE`` x their mean squared magnitude: (m + 1,) complex."""
    A = np.column_stack([X, np.ones(len(y), complex)])
    pen = np.zeros(A.shape[1])
    pen[:-1] = RIDGE * float(np.mean(np.abs(X) ** 2))
    return np.linalg.solve(A.conj().T @ A + np.diag(pen), A.conj().T @ y)


def _finite(z: complex) -> bool:
    return math.isfinite(z.real) and math.isfinite(z.imag)


def shifted(pred: np.ndarray, s: float) -> np.ndarray:
    """The prediction (K,) of a visit from its switch on, moved by the shift s faded in
    (``PlateauShift.ramp``), as the node adds it sample by sample."""
    if s == 0.0:
        return pred
    return pred + PlateauShift.ramps(len(pred)) * s


def choose_shift(visits: Sequence[Visit | None], held_out: Sequence[Sequence[int]],
                 fitted_on: Sequence[Sequence[int]], pairs: Sequence[tuple[np.ndarray, np.ndarray]],
                 vector: bool) -> tuple[PlateauShift | None, list[tuple[np.ndarray, np.ndarray]]]:
    """The OC's shift if its cross-validation says it helps, and the held-out pairs it gives.

    visits: per segment row of the OC, its visit (None: not known); held_out / fitted_on: per
    fold, the rows it holds out and fits on; pairs: the chosen model's held-out (measured,
    predicted) per row, in the folds' order of ``held_out``. Returns (the shift fitted on every
    row, the pairs shifted) or (None, ``pairs``)."""
    usable = [v for v in visits if v is not None]
    if len(usable) < MIN_RUNS:
        return None, list(pairs)
    moved: list[tuple[np.ndarray, np.ndarray]] = []
    k = 0
    for out, fit in zip(held_out, fitted_on, strict=True):
        s = fit_shift([visits[i] for i in fit if visits[i] is not None], vector)  # type: ignore[misc]
        for i in out:
            y, p = pairs[k]
            v = visits[i]
            moved.append((y, p if s is None or v is None else shifted(p, s.shift(v[0], v[1]))))
            k += 1
    if not pooled_eps(moved) < (1.0 - PLATEAU_GAIN) * pooled_eps(pairs):
        return None, list(pairs)
    return fit_shift(usable, vector), moved


def fit_settle(pairs: Sequence[tuple[np.ndarray, np.ndarray]]) -> SettleAnchor | None:
    """The settle anchor's gain fitted on held-out visits ``pairs`` ((measured, predicted) from
    the switch on): least squares of each visit's residuals from ``AT_S`` on on its mean residual
    over the window before, clipped to [0, ``MAX_GAIN``]; None without a visit that reaches it.

    >>> y, p = np.full(700, 3.0), np.full(700, 2.0)
    >>> p[AT:] = 2.5  # the model makes good half its miss itself: half the window's is left
    >>> fit_settle([(y, p)]).gain
    0.5
    """
    return _gain(_settle_terms(pairs))


def _settle_terms(pairs: Sequence[tuple[np.ndarray, np.ndarray]]) -> list[tuple[float, float]]:
    """Each visit's share of ``fit_settle``'s normal equation: (window mean x the residuals' sum
    after ``AT_S``, window mean squared x their count); (0, 0) for a visit that says nothing."""
    out = []
    for y, p in pairs:
        if len(p) <= AT:
            out.append((0.0, 0.0))
            continue
        m = SettleAnchor(1.0).offset((y[AT - WINDOW:AT] - p[AT - WINDOW:AT]).tolist())
        r = y[AT:] - p[AT:]
        ok = np.isfinite(r)
        if m == 0.0 or not ok.any():
            out.append((0.0, 0.0))
            continue
        out.append((m * float(r[ok].sum()), m * m * int(ok.sum())))
    return out


def _gain(terms: Sequence[tuple[float, float]]) -> SettleAnchor | None:
    """The anchor of the visits' summed terms (``_settle_terms``), in order."""
    num = den = 0.0
    for a, b in terms:
        num += a
        den += b
    if not den > 0:
        return None
    return SettleAnchor(float(min(MAX_GAIN, max(0.0, num / den))))


def choose_settle(held_out: Sequence[Sequence[int]], pairs: Sequence[tuple[np.ndarray, np.ndarray]]
                  ) -> tuple[SettleAnchor | None, list[tuple[np.ndarray, np.ndarray]]]:
    """The OC's settle anchor if its cross-validation says it helps, and the held-out pairs it
    gives: each fold's visits moved by the gain fitted on the other folds' (``fit_settle``), kept
    when their pooled eps falls by ``PLATEAU_GAIN``. held_out: per fold, its rows (``pairs`` are
    in that order). Returns (the anchor fitted on every pair, the pairs moved) or (None,
    ``pairs``)."""
    bounds = np.cumsum([0, *(len(h) for h in held_out)])
    terms = _settle_terms(pairs)  # each visit's once; a fold's gain sums the others'
    moved: list[tuple[np.ndarray, np.ndarray]] = []
    for j in range(len(held_out)):
        a = _gain([t for k, t in enumerate(terms) if not bounds[j] <= k < bounds[j + 1]])
        for y, p in pairs[bounds[j]:bounds[j + 1]]:
            moved.append((y, p if a is None else a.moved(y, p)))
    final = _gain(terms)
    if final is None or final.gain == 0.0 or not pooled_eps(moved) < (1.0 - PLATEAU_GAIN) * pooled_eps(pairs):
        return None, list(pairs)
    return final, moved
