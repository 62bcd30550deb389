"""The beds' health rotation: at most ``HEALTH_MAX_PER_S`` health messages a second, whatever the beds.

Each bed's ``testbed/<bed>/monitor/health`` goes out in turn: at each of the node's one-second
ticks whose rotation is done, every bed in the rotation (tracked, with a sensor time, heard from
within the health silence) is queued once; the worker publishes from that queue as long as fewer
than ``max_per_s`` health messages went out within the last second (a sliding window, counted
after each put: any second of the recording's publish times holds ``max_per_s`` at most). With N
beds in the rotation each bed's health goes out about every ``ceil(N / max_per_s)`` s: once a
second up to 100 beds, every 3 s at the 256 beds a node tracks by default. A bed's last health
(``expired``) takes its place in the same window. Pure data, no I/O: the caller gives the clock
(monotonic s).

>>> r = HealthRotation(max_per_s=3)
>>> r.refill(["a", "b", "c", "d", "e"]), r.period_s(5)
(5, 2)
>>> r.take(10, now=0.0)
['a', 'b', 'c']
>>> r.note(3, now=0.0); r.take(10, now=0.5), r.take(10, now=1.0)
([], ['d', 'e'])
>>> r.refill(["a"]), r.refill(["a"])  # (the rotation is not done before its queue is empty)
(1, 0)
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable

HEALTH_MAX_PER_S = 100  # beds' health messages a second at most, every bed together
HEALTH_SILENCE_S = 30.0  # a bed silent this long (receive time) leaves the rotation, by default, s
HEALTH_SILENCE_MAX_S = 3600.0  # the largest silence allowed (--health-silence), s
WINDOW_S = 1.0  # the rate's window, s


class HealthRotation:
    """Which beds' health goes out now (see the module): ``refill`` at a tick, ``take`` before
    publishing, ``note`` after."""

    def __init__(self, max_per_s: int = HEALTH_MAX_PER_S) -> None:
        if max_per_s < 1:
            raise ValueError(f"max_per_s must be >= 1, got {max_per_s}")
        self.max_per_s = max_per_s
        self.due: deque[str] = deque()  # beds whose turn of this rotation is still to come
        self._sent: deque[float] = deque(maxlen=max_per_s)  # when the last ones went out, s

    def refill(self, beds: Iterable[str]) -> int:
        """A new rotation of ``beds`` when the last one is done (its queue empty); how many queued."""
        if self.due:
            return 0
        self.due.extend(beds)
        return len(self.due)

    def room(self, now: float) -> int:
        """Health messages that may go out at ``now`` (s) within the rate."""
        sent = self._sent
        while sent and now - sent[0] >= WINDOW_S:
            sent.popleft()
        return self.max_per_s - len(sent)

    def take(self, n: int, now: float) -> list[str]:
        """The next beds of the rotation, at most ``n`` and the room at ``now``; ``note`` how many
        went out once they did."""
        due = self.due
        return [due.popleft() for _ in range(min(n, self.room(now), len(due)))]

    def note(self, n: int, now: float) -> None:
        """``n`` health messages went out, the last at ``now`` (s): they count until ``now`` + 1 s."""
        self._sent.extend([now] * n)

    def period_s(self, beds: int) -> int:
        """How often each of ``beds`` beds in the rotation has its health, s (ticks of a second)."""
        return max(1, -(-beds // self.max_per_s))


def most_in_a_second(times_ns: list[int]) -> int:
    """The most of ``times_ns`` (ns, any order) within any one second [t, t + 1 s): how a
    recording's health publish times are held to ``HEALTH_MAX_PER_S`` (``bench hostile``, tests).

    >>> most_in_a_second([0, 500_000_000, 999_999_999, 1_000_000_000, 1_500_000_000])
    3
    """
    ts, most, lo = sorted(times_ns), 0, 0
    for hi, t in enumerate(ts):
        while t - ts[lo] >= 1_000_000_000:
            lo += 1
        most = max(most, hi - lo + 1)
    return most
