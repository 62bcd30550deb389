"""The live edges: Zenoh in and out, MCAP recording. The logic is ``NodeCore``'s.

The subscriber callback only stamps and enqueues (bounded queue, overflow
counted); one worker thread drains the queue in batches (everything waiting, up
to ``BATCH_MAX``), runs the node logic once per batch (``NodeCore.handle_batch``,
as offline replay does), records every input, publishes and records every
output, flushes the recording once a second (a killed node loses at most the
last second) and publishes a health message per bed once a second.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from dataclasses import dataclass
from types import TracebackType
from typing import Any

import orjson

from node.contract import SENSOR_SUBSCRIPTION, health_key, liveliness_key
from node.live.zenoh import open_session, zenoh_config
from node.mcap import RecordingWriter
from node.mcap.rotation import RotatingRecorder
from node.models.bundle import Bundle
from node.runtime.core import NodeCore

log = logging.getLogger(__name__)

BATCH_MAX = 4096  # messages handled at once at most
LAG_KEPT = 4000  # latencies the health message's percentiles are taken over


@dataclass
class LiveStats:
    received: int = 0
    overflow: int = 0  # dropped because the queue was full
    published: int = 0


class LiveNode:
    """Subscribes to every test bed's sensors, predicts, publishes, records.

    A context manager: ``with LiveNode(...) as node:`` starts it and stops it (draining
    the queue, finishing the recording) on the way out.
    """

    def __init__(self, bundle: Bundle, record: str | RecordingWriter | RotatingRecorder,
                 listen: list[str] | None = None,
                 connect: list[str] | None = None, config_file: str | None = None,
                 queue_size: int = 1_000_000) -> None:
        self.core = NodeCore(bundle)
        # a path, or a recorder with RecordingWriter's write/flush/close (e.g. RotatingRecorder)
        self.writer = RecordingWriter(record) if isinstance(record, str) else record
        self.conf = zenoh_config(listen, connect, config_file)
        self.queue: queue.Queue[tuple[str, bytes, int]] = queue.Queue(maxsize=queue_size)
        self.stats = LiveStats()
        self._stop = threading.Event()
        self._publishers: dict[str, Any] = {}
        self._lag: list[float] = []

    def __enter__(self) -> LiveNode:
        self.start()
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.stop()

    def _on_sample(self, sample: Any) -> None:  # Zenoh thread: stamp and enqueue only
        try:
            self.queue.put_nowait((str(sample.key_expr), sample.payload.to_bytes(), time.time_ns()))
        except queue.Full:
            self.stats.overflow += 1

    def start(self) -> None:
        import zenoh
        self.session = open_session(self.conf)
        self._json = zenoh.Encoding.APPLICATION_JSON
        self._block = zenoh.CongestionControl.BLOCK
        self.token = self.session.liveliness().declare_token(liveliness_key(str(self.session.zid())))
        self.sub = self.session.declare_subscriber(SENSOR_SUBSCRIPTION, self._on_sample)
        self.thread = threading.Thread(target=self._work, name="ordervib-node", daemon=True)
        self.thread.start()

    def _publish(self, key: str, msg: dict | Any) -> None:
        pub = self._publishers.get(key)
        if pub is None:
            pub = self.session.declare_publisher(key, encoding=self._json, congestion_control=self._block)
            self._publishers[key] = pub
        data = orjson.dumps(msg)
        pub.put(data)
        self.writer.write(key, msg["t"], data, time.time_ns())
        self.stats.published += 1

    def _drain(self) -> list[tuple[str, bytes, int]]:
        """The messages waiting (at most ``BATCH_MAX``); waits a little for the first."""
        try:
            batch = [self.queue.get(timeout=0.05)]
        except queue.Empty:
            return []
        try:
            while len(batch) < BATCH_MAX:
                batch.append(self.queue.get_nowait())
        except queue.Empty:
            pass
        return batch

    def _handle(self, batch: list[tuple[str, bytes, int]]) -> None:
        """One batch: each input recorded, then the outputs it completed published and recorded."""
        keys, payloads, recv = zip(*batch, strict=True)
        self.stats.received += len(batch)
        result = self.core.handle_batch(keys, payloads)
        t = result.t.tolist()
        write = self.writer.write
        start = 0
        for i, outs in [*result.done, (len(batch) - 1, [])]:
            for j in range(start, i + 1):  # malformed: recorded at its receive time
                write(keys[j], t[j] if t[j] == t[j] else recv[j] / 1e9, payloads[j], recv[j])
            start = i + 1
            for key, msg in outs:
                self._publish(key, msg)
                self._lag.append((time.time_ns() - recv[i]) / 1e6)

    def _work(self) -> None:
        next_tick = time.monotonic() + 1.0
        while not (self._stop.is_set() and self.queue.empty()):
            batch = self._drain()
            if batch:
                self._handle(batch)
            if time.monotonic() >= next_tick:
                next_tick += 1.0
                self._tick()
        for k, msg in self.core.finish():
            self._publish(k, msg)

    def _tick(self) -> None:
        """Once a second: each bed's health message, and the recording flushed."""
        wall = time.time()
        lag = sorted(self._lag[-LAG_KEPT:])
        self._lag = self._lag[-LAG_KEPT:]
        p50 = lag[len(lag) // 2] if lag else None
        p99 = lag[int(0.99 * (len(lag) - 1))] if lag else None
        for bed, state in list(self.core.beds.items()):
            if state.latest_t is not None:  # a bed of malformed messages only has no sensor time
                self._publish(health_key(bed), self.core.health(bed, wall, self.stats.overflow, (p50, p99)))
        self.writer.flush()

    def stop(self) -> None:
        """Stop receiving, drain the queue, finish the recording, close the session."""
        self._stop.set()
        try:
            self.sub.undeclare()
        except Exception:  # noqa: BLE001 - the session may be gone already
            pass
        self.thread.join()
        self.writer.close()
        self.session.close()


def run_node(bundle: Bundle, record: str | RecordingWriter | RotatingRecorder, listen: list[str] | None,
             connect: list[str] | None, config_file: str | None, duration: float | None) -> LiveStats:
    """The node until SIGINT, SIGTERM or ``duration`` seconds; status lines are logged."""
    import signal
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    with LiveNode(bundle, record, listen, connect, config_file) as node:
        where = listen or connect or f"the endpoints of {config_file}"
        log.info("ordervib node on %s; recording to %s; Ctrl-C stops", where, record)
        stop.wait(duration)
    log.info("stopped: %d received, %d published, %d dropped; %s finished",
             node.stats.received, node.stats.published, node.stats.overflow, record)
    return node.stats
