"""The last rows of a stream, kept as Python rows and packed into arrays a block at a time.

A pipeline keeps its measured past (``history_s`` of samples) to seed an OC's model at a switch.
Held as a deque of tuples, the switch converted it all at once (``np.asarray`` of 2,400 rows of
20 channels: 2.3 ms); with 20 test beds switching together that held the live worker 0.25 s
(``bench live``). ``RecentRows`` packs every ``block`` rows into an array as they come, so a switch
packs only the rows since the last block: the same numbers, the work spread over the samples.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence

import numpy as np

BLOCK = 200  # rows packed at once (5 s at 40 Hz)


class RecentRows:
    """The last ``maxlen`` rows of ``width`` floats pushed, as a ``(rows, width)`` array on demand.

    ``push`` is a list append (and every ``block`` rows one ``np.asarray`` of them); ``array``
    gives exactly what ``np.asarray`` of a ``deque(maxlen=maxlen)`` of the same rows gives.

    >>> r = RecentRows(maxlen=3, block=2)
    >>> for i in range(5):
    ...     r.push((float(i), 10.0 * i))
    >>> r.array()
    array([[ 2., 20.],
           [ 3., 30.],
           [ 4., 40.]])
    >>> len(r), bool(RecentRows(3))
    (3, False)
    """

    def __init__(self, maxlen: int, block: int = BLOCK) -> None:
        if maxlen < 0 or block < 1:
            raise ValueError(f"maxlen must be >= 0 and block >= 1, got {maxlen}, {block}")
        self.maxlen = maxlen
        self.block = block
        # packed blocks, oldest first: enough of them to hold maxlen rows beside the open block
        self._blocks: deque[np.ndarray] = deque(maxlen=-(-maxlen // block))  # maxlen 0: none kept
        self._open: list[Sequence[float]] = []

    def push(self, row: Sequence[float]) -> None:
        """One row (its width the same every time)."""
        if not self.maxlen:
            return
        rows = self._open
        rows.append(row)
        if len(rows) == self.block:
            self._blocks.append(np.asarray(rows, dtype=np.float64))
            self._open = []

    def __len__(self) -> int:
        return min(self.maxlen, len(self._blocks) * self.block + len(self._open))

    def clear(self) -> None:
        self._blocks.clear()
        self._open = []

    def array(self) -> np.ndarray:
        """The last rows pushed (at most ``maxlen``), oldest first, ``(rows, width)`` float64."""
        parts = list(self._blocks)
        if self._open:
            parts.append(np.asarray(self._open, dtype=np.float64))
        if not parts:
            return np.zeros((0, 0))
        full = parts[0] if len(parts) == 1 else np.concatenate(parts)
        return full[-self.maxlen:]
