"""The live worker's fair intake: a bed catching up on a backlog does not hold the others back.

When the node falls behind (more messages waiting than one worker pass takes), the worker takes
what waits in Zenoh's FIFO into ``FairIntake``'s lanes, a lane per bed name's hash
(``LANES``): a bed's messages always go to the same lane, so each bed's messages keep their order;
the order between beds is free (the core keeps each bed's state apart, and the recording is
written in the order the worker handled them). Each pass then takes the lanes with the fewest
messages waiting first, whole, and the rest of the batch from the next: a test bed sending at its
nominal rate waits one pass, not behind a sibling bed that sends an hour of backlog at 20x
(issue 31), and beds at the same rate are handled bed by bed as they came (their slots complete
early, not all at the end as round robin would). The lane with the most waiting gets at least
1/``FULLEST_SHARE`` of every batch, so it is never starved. Pure data, no I/O, no clock.

>>> fi = FairIntake()
>>> fi.extend([("testbed/big/sensor/a", b"", i) for i in range(6)] + [("testbed/small/sensor/a", b"", 9)])
>>> [m[0].split("/")[1] for m in fi.take(3)]
['small', 'big', 'big']
>>> [m[2] for m in fi.take(10)], len(fi)
([2, 3, 4, 5], 0)
"""

from __future__ import annotations

import zlib
from collections import deque
from collections.abc import Iterable

Message = tuple[str, bytes, int]  # (key, payload, receive time ns), as the worker drains them

LANES = 64  # lanes the beds are hashed to: a few beds share one, any number of beds fit
FULLEST_SHARE = 8  # the fullest lane gets at least 1/8 of a batch (if it has so many waiting)
_PREFIX = "testbed/"
LANE_CACHE = 4096  # keys whose lane is remembered (the cache is cleared when it holds more)


def lane_of(key: str) -> int:
    """The lane of a key: the crc32 of its bed chunk (``testbed/<bed>/...``; the whole key for
    any other) modulo ``LANES``, the same in every process.

    >>> lane_of("testbed/tb01/sensor/nB") == lane_of("testbed/tb01/sensor/yB")
    True
    >>> 0 <= lane_of("odd key") < LANES
    True
    """
    if key.startswith(_PREFIX):
        end = key.find("/", len(_PREFIX))
        name = key[len(_PREFIX):end] if end >= 0 else key[len(_PREFIX):]
    else:
        name = key
    return zlib.crc32(name.encode("utf-8", "surrogatepass")) % LANES


class FairIntake:
    """Messages waiting in lanes (see the module): ``extend`` in arrival order, ``take`` a
    batch, shortest lanes first. Bounded by its owner (``len`` says how many wait)."""

    def __init__(self) -> None:
        self._lanes: dict[int, deque[Message]] = {}  # lane -> its messages waiting, in order
        self._lane_of: dict[str, int] = {}  # key -> lane (a cache of lane_of)
        self._n = 0

    def __len__(self) -> int:
        return self._n

    def extend(self, messages: Iterable[Message]) -> None:
        """Messages (key, payload, receive time ns) in the order they arrived."""
        lanes, cache = self._lanes, self._lane_of
        n = 0
        for m in messages:
            key = m[0]
            lane = cache.get(key)
            if lane is None:
                if len(cache) >= LANE_CACHE:
                    cache.clear()
                lane = cache[key] = lane_of(key)
            q = lanes.get(lane)
            if q is None:
                q = lanes[lane] = deque()
            q.append(m)
            n += 1
        self._n += n

    def take(self, n: int) -> list[Message]:
        """At most n messages: whole lanes from the shortest, the last one cut, with room kept
        for n / ``FULLEST_SHARE`` of the fullest lane (taken last); emptied lanes go.

        Each lane's messages come out in the order they went in."""
        out: list[Message] = []
        if n <= 0 or not self._n:
            return out
        lanes = self._lanes
        order = sorted(lanes, key=lambda k: len(lanes[k]))
        fullest = order[-1]
        keep = min(n // FULLEST_SHARE, len(lanes[fullest])) if len(order) > 1 else 0  # never starved
        for lane in order:  # the fullest last
            q = lanes[lane]
            room = n - len(out) - (keep if lane != fullest else 0)
            if room <= 0:
                continue
            if len(q) <= room:
                out.extend(q)
                del lanes[lane]
            else:
                out.extend(q.popleft() for _ in range(room))
        self._n -= len(out)
        return out
