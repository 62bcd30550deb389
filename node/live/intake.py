"""The live worker's fair intake: a bed catching up on a backlog does not hold the others back.

When the node falls behind (more messages waiting than one worker pass takes), the worker takes what
waits in Zenoh's FIFO into ``FairIntake``'s lanes, a lane per bed name (the key's second chunk,
``lane_name``; at most ``LANES_MAX``, the rest in one overflow lane): a bed's waiting messages are all
in one lane, so each bed's messages keep their order; the order between beds is free (the core keeps
each bed's state apart, and the recording is written in the order the worker handled them). Each
pass takes the lanes whole in the order their oldest messages arrived, but the big ones (more than
half a batch and ``BIG_RATIO`` x the median lane waiting) after the others: a test bed sending at
its nominal rate waits one pass, not behind a sibling bed that sends an hour of backlog at 20x
(``bench hostile``), while beds at the same rate, all behind alike, go oldest first, as they came. The big
lanes get at least 1/``FULLEST_SHARE`` of every batch, so a backlog is never starved. Pure data,
no I/O, no clock.

>>> fi = FairIntake()
>>> fi.extend([("testbed/big/sensor/a", b"", i) for i in range(6)] + [("testbed/small/sensor/a", b"", 9)])
>>> [lane_name(m[0]) for m in fi.take(3)]
['small', 'big', 'big']
>>> [m[2] for m in fi.take(10)], len(fi)
([2, 3, 4, 5], 0)
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable

from node.contract import bed_of

Message = tuple[str, bytes, int]  # (key, payload, receive time ns), as the worker drains them

LANES_MAX = 256  # lanes of their own (the node's --max-beds by default); more beds share one
OVERFLOW = "\x00overflow"  # the lane of beds beyond LANES_MAX (no bed name holds a NUL)
# A lane is big (taken after the others) with more than 1/SMALL_SHARE of a batch and more than
# BIG_RATIO x the median lane waiting: beds at one rate, all behind alike, go oldest first
SMALL_SHARE, BIG_RATIO = 2, 4
FULLEST_SHARE = 8  # the others get at least 1/8 of a batch (if they have so many waiting)
NAME_CACHE = 4096  # keys whose lane name is remembered (the cache is cleared when it holds more)


def lane_name(key: str) -> str:
    """A key's lane: its test bed (``node.contract.bed_of``, the contract's one parse), or the
    whole key for a key of no bed.

    >>> lane_name("testbed/tb01/sensor/nB"), lane_name("odd key")
    ('tb01', 'odd key')
    """
    return bed_of(key) or key


class FairIntake:
    """Messages waiting in lanes (see the module): ``extend`` in arrival order, ``take`` a
    batch, small lanes first. Bounded by its owner (``len`` says how many wait)."""

    def __init__(self, lanes_max: int = LANES_MAX) -> None:
        if lanes_max < 1:
            raise ValueError(f"lanes_max must be >= 1, got {lanes_max}")
        self.lanes_max = lanes_max  # lanes of their own at most (with the overflow lane's, one more)
        self._lanes: dict[str, deque[Message]] = {}  # bed name (or OVERFLOW) -> its messages, in order
        self._names: dict[str, str] = {}  # key -> lane name (a cache of lane_name)
        self._n = 0

    def __len__(self) -> int:
        return self._n

    def extend(self, messages: Iterable[Message]) -> None:
        """Messages (key, payload, receive time ns) in the order they arrived.

        A bed without a lane gets one unless ``lanes_max`` are in use or the overflow lane holds
        messages (its own may be among them: they must go first); else it goes to the overflow
        lane. So a bed's waiting messages are always in one lane."""
        lanes, names, most = self._lanes, self._names, self.lanes_max
        n = 0
        for m in messages:
            key = m[0]
            name = names.get(key)
            if name is None:
                if len(names) >= NAME_CACHE:
                    names.clear()
                name = names[key] = lane_name(key)
            q = lanes.get(name)
            if q is None:
                if len(lanes) >= most or OVERFLOW in lanes:
                    name = OVERFLOW
                    q = lanes.get(name)
                if q is None:
                    q = lanes[name] = deque()
            q.append(m)
            n += 1
        self._n += n

    def take(self, n: int) -> list[Message]:
        """At most n messages, the lanes in the order their oldest messages arrived, each whole
        (the last one cut), except the big ones (more than ``n // SMALL_SHARE`` and more than
        ``BIG_RATIO`` x the median lane waiting), which come after the others. Of n,
        n // ``FULLEST_SHARE`` is kept for the big ones when there are any (a backlog is never
        starved). Emptied lanes go.

        Each lane's messages come out in the order they went in."""
        out: list[Message] = []
        if n <= 0 or not self._n:
            return out
        lanes = self._lanes
        order = sorted(lanes, key=lambda k: lanes[k][0][2])  # by the oldest receipt waiting
        sizes = sorted(map(len, lanes.values()))
        most = max(n // SMALL_SHARE, BIG_RATIO * sizes[(len(sizes) - 1) // 2])  # the lower median
        big = [k for k in order if len(lanes[k]) > most]
        keep = min(n // FULLEST_SHARE, len(lanes[big[0]])) if big and len(big) < len(order) else 0
        for lane in [k for k in order if len(lanes[k]) <= most] + big:
            q = lanes[lane]
            room = n - len(out) - (keep if len(q) <= most else 0)
            if room <= 0:
                continue
            if len(q) <= room:
                out.extend(q)
                del lanes[lane]
            else:
                out.extend(q.popleft() for _ in range(room))
        self._n -= len(out)
        return out
