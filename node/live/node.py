"""The live edges: Zenoh in and out, MCAP recording. The logic is ``NodeCore``'s.

The subscriber callback only stamps and enqueues (bounded queue, overflow
counted); one worker thread records every input, runs the node logic,
publishes and records every output, flushes the recording once a second (a
killed node loses at most the last second) and publishes a health message
per bed once a second.
"""

from __future__ import annotations

import queue
import sys
import threading
import time
from dataclasses import dataclass

import orjson

from node.contract import SENSOR_SUBSCRIPTION, health_key, liveliness_key
from node.live.zenoh import open_session, zenoh_config
from node.mcap import RecordingWriter
from node.mcap.rotation import RotatingRecorder
from node.models.bundle import Bundle
from node.runtime.core import NodeCore


@dataclass
class LiveStats:
    received: int = 0
    overflow: int = 0  # dropped because the queue was full
    published: int = 0


class LiveNode:
    """Subscribes to every test bed's sensors, predicts, publishes, records."""

    def __init__(self, bundle: Bundle, record: str | RecordingWriter | RotatingRecorder,
                 listen: list[str] | None = None,
                 connect: list[str] | None = None, config_file: str | None = None,
                 queue_size: int = 1_000_000) -> None:
        self.core = NodeCore(bundle)
        # a path, or a recorder with RecordingWriter's write/flush/close (e.g. RotatingRecorder)
        self.writer = RecordingWriter(record) if isinstance(record, str) else record
        self.conf = zenoh_config(listen, connect, config_file)
        self.queue: queue.Queue = queue.Queue(maxsize=queue_size)
        self.stats = LiveStats()
        self._stop = threading.Event()
        self._publishers: dict[str, object] = {}
        self._lag: list[float] = []

    def _on_sample(self, sample) -> None:  # Zenoh thread: stamp and enqueue only
        try:
            self.queue.put_nowait((str(sample.key_expr), sample.payload.to_bytes(), time.time_ns()))
        except queue.Full:
            self.stats.overflow += 1

    def start(self) -> None:
        import zenoh
        self.session = open_session(self.conf)
        self._zenoh = zenoh
        self.token = self.session.liveliness().declare_token(liveliness_key(str(self.session.zid())))
        self.sub = self.session.declare_subscriber(SENSOR_SUBSCRIPTION, self._on_sample)
        self.thread = threading.Thread(target=self._work, name="ordervib-node", daemon=True)
        self.thread.start()

    def _publish(self, key: str, msg: dict) -> None:
        pub = self._publishers.get(key)
        if pub is None:
            pub = self.session.declare_publisher(key, congestion_control=self._zenoh.CongestionControl.BLOCK)
            self._publishers[key] = pub
        data = orjson.dumps(msg)
        pub.put(data)
        self.writer.write(key, msg["t"], data, time.time_ns())
        self.stats.published += 1

    def _handle(self, key: str, payload: bytes, recv_ns: int) -> None:
        self.stats.received += 1
        try:
            t = orjson.loads(payload)["t"]
            t = float(t)
        except (orjson.JSONDecodeError, TypeError, KeyError, ValueError):
            t = recv_ns / 1e9  # malformed: recorded at its receive time, skipped by the logic
        self.writer.write(key, t, payload, recv_ns)
        for k, msg in self.core.handle(key, payload):
            self._publish(k, msg)
            self._lag.append((time.time_ns() - recv_ns) / 1e6)

    def _work(self) -> None:
        next_tick = time.monotonic() + 1.0
        while not (self._stop.is_set() and self.queue.empty()):
            try:
                item = self.queue.get(timeout=0.05)
                self._handle(*item)
            except queue.Empty:
                pass
            if time.monotonic() >= next_tick:
                next_tick += 1.0
                self._tick()
        for k, msg in self.core.finish():
            self._publish(k, msg)

    def _tick(self) -> None:
        now = time.time()
        lag = sorted(self._lag[-4000:])
        extra = {"received": self.stats.received, "dropped": self.stats.overflow,
                 "lag_ms_p50": lag[len(lag) // 2] if lag else None,
                 "lag_ms_p99": lag[int(0.99 * (len(lag) - 1))] if lag else None}
        self._lag = self._lag[-4000:]
        for bed in list(self.core.stats.beds):
            self._publish(health_key(bed), self.core.health(bed, now, extra))
        self.writer.flush()

    def stop(self) -> None:
        """Stop receiving, drain the queue, finish the recording, close the session."""
        self._stop.set()
        try:
            self.sub.undeclare()
        except Exception:
            pass
        self.thread.join()
        self.writer.close()
        self.session.close()


def run_node(bundle: Bundle, record: str | RecordingWriter | RotatingRecorder, listen, connect,
             config_file, duration: float | None, quiet: bool = False) -> LiveStats:
    import signal
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    node = LiveNode(bundle, record, listen, connect, config_file)
    node.start()
    if not quiet:
        where = listen or connect or f"the endpoints of {config_file}"
        print(f"ordervib node on {where}; recording to {record}; Ctrl-C stops",
              file=sys.stderr, flush=True)
    stop.wait(duration)
    node.stop()
    if not quiet:
        print(f"stopped: {node.stats.received} received, {node.stats.published} published, "
              f"{node.stats.overflow} dropped; {record} finished", file=sys.stderr)
    return node.stats
