"""What a run's earlier plateaus say of this OC's plateau: a learned shift of the OC model's
prediction (``bench generalise``: the error left above the noise floor is mostly a level missed on the
plateau).

A rotor's 1x vector at a speed is its response to a few forcing vectors at once (the run's
imbalance, its thermal bow) and to its thermal state; the vector just before an OC switch, at
one speed, cannot tell them apart, so a model anchored on it alone misses the plateau's level.
The plateaus this run already held, at other speeds, do tell them apart: the new plateau's level
is, across training runs, nearly an affine function of them. ``PlateauShift`` holds two such
regressions fitted over the training runs (complex on the 1x vector, real on the amplitude):
the plateau's level from the vector before the switch and the earlier plateaus, ``coef``, and
from the vector before the switch alone, ``coef_pre``. Their difference in amplitude is what
the earlier plateaus add to what the switch alone tells; the model's prediction is moved by it,
faded in over ``RAMP_S`` after the switch (the transition's shape stays the model's). Where an
earlier plateau is unknown (the node restarted within the run, or the run skipped an OC) the
shift is 0: the model as it is.

Pure numbers; the run's plateaus are tracked by ``node.runtime.plateaus.RunPlateaus``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from node.contract import FS

# a visit's samples from this long after its switch on make its plateau level, s; the shift comes
# in linearly over RAMP_S after the switch, s (study: docs/tuning.md#plateau_shift)
SETTLE_S = 15.0
RAMP_S = 10.0
MAX_TERMS = 64  # earlier plateaus a shift may read (a schedule's OCs are bounded too)


@dataclass(frozen=True)
class PlateauShift:
    """The learned shift of one OC (see the module).

    Attributes:
        earlier: the schedule indices of the OCs whose plateau levels it reads, in order.
        coef: (len(earlier) + 2,) complex: on (level before the switch, the earlier plateaus, 1).
        coef_pre: (2,) complex: on (level before the switch, 1).
        vector: the levels are 1x vectors (the shift is a difference of moduli), else amplitudes.
        limit: the largest shift allowed, mm/s (beyond the training runs' own: extrapolation,
            the shift is clipped there).

    >>> s = PlateauShift((0,), (0.0, 2.0, 0.0), (1.0, 0.0), vector=False, limit=5.0)
    >>> s.shift(1.0, [3.0])  # the earlier plateau says 6, the switch alone 1
    5.0
    >>> s.shift(1.0, [float("nan")]), s.ramp(0), s.ramp(int(RAMP_S * FS) - 1)
    (0.0, 0.0025, 1.0)
    """

    earlier: tuple[int, ...]
    coef: tuple[complex, ...]
    coef_pre: tuple[complex, complex]
    vector: bool
    limit: float

    def __post_init__(self) -> None:
        n = len(self.earlier)
        if n > MAX_TERMS or len(self.coef) != n + 2 or len(self.coef_pre) != 2:
            raise ValueError("a plateau shift needs len(earlier) + 2 coefficients and 2 on the switch alone")
        if not all(isinstance(i, int) and 0 <= i for i in self.earlier):
            raise ValueError("a plateau shift's earlier OCs must be schedule indices")
        if not all(math.isfinite(abs(c)) for c in (*self.coef, *self.coef_pre)):
            raise ValueError("a plateau shift's coefficients must be finite")
        if not (math.isfinite(self.limit) and self.limit >= 0):
            raise ValueError("a plateau shift's limit must be a finite number >= 0")

    def shift(self, pre: complex, levels: Sequence[complex]) -> float:
        """The shift (mm/s) for a visit whose level over the second before the switch was ``pre``,
        the run's plateau levels per OC being ``levels`` (NaN: not held); 0 where any it reads
        is unknown."""
        nan = complex(math.nan)
        xs = [complex(pre), *(complex(levels[i]) if i < len(levels) else nan for i in self.earlier)]
        if not all(math.isfinite(x.real) and math.isfinite(x.imag) for x in xs):
            return 0.0
        c = self.coef
        full = c[-1]
        for k, x in enumerate(xs):
            full += c[k] * x
        alone = self.coef_pre[0] * xs[0] + self.coef_pre[1]
        s = abs(full) - abs(alone) if self.vector else full.real - alone.real
        return max(-self.limit, min(self.limit, s)) if math.isfinite(s) else 0.0

    @staticmethod
    def ramp(since: int) -> float:
        """The share of the shift at ``since`` samples after the switch (0 at the switch sample)."""
        return min(1.0, (since + 1) / (RAMP_S * FS))

    @staticmethod
    def ramps(n: int) -> np.ndarray:
        """``ramp`` of the first n samples of a visit (n,), the same numbers to the last bit.

        >>> bool((PlateauShift.ramps(500) == [PlateauShift.ramp(k) for k in range(500)]).all())
        True
        """
        return np.minimum(1.0, (np.arange(n) + 1) / (RAMP_S * FS))

    def to_dict(self) -> dict:
        """For the bundle's manifest (JSON: complex numbers as [re, im])."""
        return {"earlier": list(self.earlier), "coef": [[c.real, c.imag] for c in map(complex, self.coef)],
                "coef_pre": [[c.real, c.imag] for c in map(complex, self.coef_pre)],
                "vector": self.vector, "limit": self.limit}

    @classmethod
    def from_dict(cls, d: object, n_ocs: int) -> PlateauShift:
        """``to_dict``'s inverse, checked (``ValueError``, one line) against a schedule of ``n_ocs``.

        >>> s = PlateauShift((1, 0), (1j, 2.0, 0.5, -1.0), (1.0, 0j), True, 2.0)
        >>> PlateauShift.from_dict(s.to_dict(), 3) == s
        True
        """
        if not isinstance(d, dict) or set(d) != {"earlier", "coef", "coef_pre", "vector", "limit"}:
            raise ValueError("a plateau shift must be an object of earlier, coef, coef_pre, vector, limit")

        def cplx(v: object) -> complex:
            if (not isinstance(v, list) or len(v) != 2
                    or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)):
                raise ValueError(f"a plateau shift's coefficient must be [re, im], got {v!r}")
            return complex(float(v[0]), float(v[1]))

        earlier, coef, pre = d["earlier"], d["coef"], d["coef_pre"]
        if not isinstance(earlier, list) or len(earlier) > MAX_TERMS or not all(
                isinstance(i, int) and not isinstance(i, bool) and 0 <= i < n_ocs for i in earlier):
            raise ValueError("a plateau shift's earlier OCs must be indices into the schedule")
        if (not isinstance(coef, list) or len(coef) > MAX_TERMS + 2
                or not isinstance(pre, list) or len(pre) != 2):
            raise ValueError("a plateau shift's coefficients must be lists (coef_pre of two)")
        if not isinstance(d["vector"], bool) or not isinstance(d["limit"], (int, float)) \
                or isinstance(d["limit"], bool):
            raise ValueError("a plateau shift's vector must be true or false, its limit a number")
        return cls(tuple(earlier), tuple(cplx(c) for c in coef), (cplx(pre[0]), cplx(pre[1])), d["vector"],
                   float(d["limit"]))
