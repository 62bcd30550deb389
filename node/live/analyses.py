"""The transitions' analyses of a live node, in a process of their own.

A transition's analysis (``monitor/transient``: the criticals' fits, 5 ms on average per target
and bed, up to 0.3 s) is Python and numpy that holds the interpreter's lock. On a thread of the
node it slowed the worker whenever transitions ended: 20 test beds ending one together meant 60
analyses, 1.3 s of CPU spread over 3 s of the lock, and the worker fell behind by up to half a
second (bench live, 280 s). Here each ``PendingTransient``'s ``job`` goes to one spawned
process at the lowest priority (``os.nice(19)``; ``message_of_job``: the same code, the same
message to the last bit), started at the first transition; the messages come back in the order
the transitions ended; it ends with the node, or within ``ORPHAN_CHECK_S`` of a node killed
outright (nodes that ended without stopping had left theirs running). If that process cannot be started
or dies, one warning is logged and the worker analyses the rest itself (the same messages,
later); nothing is lost.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import signal
import threading
import time
from collections import deque
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool

from node.runtime.transient_watch import PendingTransient, message_of_job

log = logging.getLogger(__name__)

WAITING_MAX = 1024  # analyses waiting at most; beyond, the worker analyses them itself (bounded memory)
NICE = 19  # the analysis process's priority: below the node's worker and Zenoh's threads
ORPHAN_CHECK_S = 0.5  # how often the analysis process looks whether its node still lives, s


def _child_start() -> None:
    """The analysis process: the lowest priority, deaf to Ctrl-C (the node's stop ends it), and
    gone within ``ORPHAN_CHECK_S`` of its node's death (a node killed outright left it running)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        os.nice(NICE)
    except OSError:  # (not allowed here: it runs at the node's priority)
        pass
    threading.Thread(target=_exit_with, args=(os.getppid(),), daemon=True, name="orphan-check").start()


def _exit_with(parent: int) -> None:
    """Ends this process once its parent is gone (it is then another process's child)."""
    while os.getppid() == parent:
        time.sleep(ORPHAN_CHECK_S)
    os._exit(0)


class TransientAnalyses:
    """Transitions in, their messages out in the same order, analysed off the caller's process.

    ``submit(key, pending)``; ``done(wait)``: the (key, message) of those finished, in the order
    submitted, stopping at the first unfinished (``wait``: all); a transition too short to analyse
    gives no message. ``close()`` ends the process. ``inline=True`` analyses at submit (no process).

    >>> a = TransientAnalyses(inline=True)
    >>> a.done(), a.waiting
    ([], 0)
    """

    def __init__(self, inline: bool = False, waiting_max: int = WAITING_MAX) -> None:
        self.inline = inline
        self.waiting_max = waiting_max
        self._pool: ProcessPoolExecutor | None = None
        self._queue: deque[tuple[str, PendingTransient, Future[dict | None]]] = deque()

    @property
    def waiting(self) -> int:
        return len(self._queue)

    def submit(self, key: str, pending: PendingTransient) -> None:
        future: Future[dict | None] | None = None
        if not self.inline and len(self._queue) < self.waiting_max:
            try:
                if self._pool is None:
                    self._pool = ProcessPoolExecutor(1, multiprocessing.get_context("spawn"),
                                                     initializer=_child_start)
                future = self._pool.submit(message_of_job, *pending.job())
            except (BrokenProcessPool, OSError, RuntimeError) as exc:
                self._fall_back(exc)
        if future is None:  # inline, too many waiting, or the process failed: here and now
            future = Future()
            future.set_result(pending.resolve())
        self._queue.append((key, pending, future))

    def done(self, wait: bool = False) -> list[tuple[str, dict]]:
        queue, out = self._queue, []
        while queue and (wait or queue[0][2].done()):
            key, pending, future = queue.popleft()
            try:
                msg = future.result()
            except BrokenProcessPool as exc:  # the process died: this one, and the rest, here
                self._fall_back(exc)
                msg = pending.resolve()
            if msg is not None:
                out.append((key, msg))
        return out

    def _fall_back(self, exc: BaseException) -> None:
        if not self.inline:
            log.warning("transient analyses: their process failed (%s); the worker analyses them itself",
                        type(exc).__name__)
        self.inline = True
        self.close()

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=False)
            self._pool = None
