"""What the blank cells of a CSV column mean: pure rules on the column's blank mask, no I/O.

A test cell's CSV export puts channels of several rates in one table: a 10 Hz channel in a
100 Hz file has a value on every 10th row and nothing between. Those blanks are no dropouts:
the channel was not sampled there. ``column_samples`` picks the rows that are the column's
samples, by the map's ``blank`` setting:

- ``not-sampled``: every non-blank row (the blanks are no samples);
- ``null``: every row (a blank is a dropout, written null);
- ``auto`` (the default): when the non-blank rows repeat every k-th row (k >= 2, the column's own
  rate; at least 90 % of the steps exactly k, every one a multiple of k), the rows of that
  pattern (a blank on one of them is a dropout); else every row, as ``null``.

>>> blank = np.ones(40, bool); blank[3::10] = False
>>> rows, note, warn = column_samples(blank, "auto")
>>> rows.tolist(), warn
([3, 13, 23, 33], False)
>>> column_samples(np.array([False, True, False, False]), "auto")[0] is None
True
"""

from __future__ import annotations

import numpy as np

MIN_REGULAR = 0.9  # share of the steps between filled rows that must be the column's own step
MANY_BLANK = 0.5  # a column blank on more than this share of its rows, read as dropouts: warned


def own_step(filled: np.ndarray) -> int | None:
    """The column's own step in rows (>= 2) when its filled rows (bool (n,)) repeat regularly
    (see the module), else None."""
    idx = np.flatnonzero(filled)
    if len(idx) < 3:
        return None
    d = np.diff(idx)
    k = int(np.bincount(d).argmax())
    if k < 2 or np.any((idx - idx[0]) % k) or np.mean(d == k) < MIN_REGULAR:
        return None
    return k


def column_samples(blank: np.ndarray, mode: str) -> tuple[np.ndarray | None, str, bool]:
    """(the rows that are the column's samples, None for every row; a note for the log, "" if
    none; whether the note is a warning) for a column's blank cells (bool (n,)) and ``mode``."""
    n, nb = len(blank), int(blank.sum())
    if nb == 0 or mode == "null":
        return None, "", False
    filled = ~blank
    if mode == "not-sampled":
        rows = np.flatnonzero(filled)
        return rows, f"{len(rows)} of its {n} rows sampled (blank = \"not-sampled\")", False
    k = own_step(filled)
    if k is None:
        if nb > MANY_BLANK * n:
            return None, (f"{nb} of its {n} cells are blank, written null as dropouts: give blank = "
                          "\"not-sampled\" in the map if the channel was not sampled there"), True
        return None, "", False
    idx = np.flatnonzero(filled)
    rows = np.arange(idx[0], idx[-1] + 1, k)
    drop = int(blank[rows].sum())
    return rows, (f"a value every {k} rows (its own rate): the blank rows between are no samples"
                  + (f"; {drop} blank on its own rows written null" if drop else "")), False
