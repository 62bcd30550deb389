"""The node's inbox (Zenoh callback thread -> worker): nothing lost or reordered, bounded, and a
waiting worker woken by the next put, not by its timeout."""

from __future__ import annotations

import threading
import time

from node.live.inbox import Inbox


def test_a_producer_thread_and_the_worker_lose_and_reorder_nothing() -> None:
    box: Inbox[int] = Inbox(maxsize=10**6)
    n = 200_000

    def produce() -> None:
        for i in range(n):
            assert box.put(i)
            if i % 5000 == 0:
                time.sleep(0.001)  # let the worker run dry and wait now and then

    t = threading.Thread(target=produce)
    t.start()
    got: list[int] = []
    while len(got) < n:
        got += box.take(4096, timeout=1.0)
    t.join()
    assert got == list(range(n)) and not box


def test_a_full_inbox_refuses_without_blocking_and_takes_again_once_drained() -> None:
    box: Inbox[str] = Inbox(maxsize=3)
    assert [box.put(x) for x in "abcd"] == [True, True, True, False]
    assert box.take(2, timeout=0.0) == ["a", "b"]
    assert box.put("e") and box.take(10, timeout=0.0) == ["c", "e"]


def test_a_waiting_worker_wakes_at_the_put_not_at_its_timeout() -> None:
    box: Inbox[int] = Inbox(maxsize=10)
    waits = []
    for i in range(20):
        threading.Timer(0.01, box.put, args=(i,)).start()
        t0 = time.monotonic()
        assert box.take(10, timeout=30.0) == [i]
        waits.append(time.monotonic() - t0)
    assert max(waits) < 10.0  # a missed wake-up would wait out the 30 s
