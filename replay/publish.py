"""Publishing a recording's sensor messages to Zenoh, in their original timing (a test bed stand-in)."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

from node.contract import OrdervibError, parse_sensor_key
from node.edges.zenoh import (
    DEFAULT_ENDPOINT,
    config_file_endpoints,
    json_publisher,
    open_session,
    zenoh_config,
)
from node.mcap import iter_messages, message_time_span

log = logging.getLogger(__name__)

CLOSE_GRACE_S = 1.0  # wait before closing the session, s: close() drops what is still queued


class GapShortener:
    """Recording time (ns) -> publishing time (ns since the first message), each gap between
    consecutive messages longer than ``max_gap_s`` shortened to it (None: timing kept).

    >>> g = GapShortener(1.0)
    >>> [g.due(t) for t in (0, 500_000_000, 10_500_000_000, 11_000_000_000)], g.gaps, g.skipped_s
    ([0, 500000000, 1500000000, 2000000000], 1, 9.0)
    """

    def __init__(self, max_gap_s: float | None) -> None:
        self._max = None if max_gap_s is None else int(round(max_gap_s * 1e9))
        self._first: int | None = None
        self._last: int | None = None
        self._skipped = 0
        self.gaps = 0

    @property
    def skipped_s(self) -> float:
        return self._skipped / 1e9

    def due(self, t_ns: int) -> int:
        if self._first is None:
            self._first = self._last = t_ns
        assert self._last is not None
        if self._max is not None and t_ns - self._last > self._max:
            self._skipped += t_ns - self._last - self._max
            self.gaps += 1
        self._last = max(self._last, t_ns)
        return t_ns - self._first - self._skipped


def publish_recording(path: str, connect: str | None, speed: float, quiet: bool = False,
                      wait_s: float = 5.0, config_file: str | None = None, max_gap_s: float | None = None,
                      progress: Callable[[float, int], None] | None = None,
                      pace: tuple[Callable[[], float], Callable[[float], None]] = (time.monotonic, time.sleep)
                      ) -> int:
    """Publish a recording's sensor messages in their original timing (``speed`` x; 0: flat out).

    Connects to ``connect``, else to the endpoints of ``config_file``, else to DEFAULT_ENDPOINT.
    Waits up to ``wait_s`` for a subscriber to match the first key; none: ``OrdervibError``,
    nothing published (a test bed stand-in that talks to nobody is no success).
    max_gap_s: in real timing, a gap longer than this between messages (the engine standing
    between runs) is shortened to it (``GapShortener``). progress: called now and then with the
    fraction of the recording's time span published (when its summary tells the span) and the
    messages sent. pace: the clock (s) and the sleep that pace the messages (a test gives a
    virtual pair to read the schedule without waiting for it).
    """
    endpoints: list[str] | None
    if connect:
        endpoints = [connect]
    else:
        endpoints = None if config_file_endpoints(config_file) else [DEFAULT_ENDPOINT]
    conf = zenoh_config(None, endpoints, config_file)
    session = open_session(conf)
    import zenoh
    pubs: dict[str, zenoh.Publisher] = {}
    sent = 0
    clock = GapShortener(max_gap_s)
    span = message_time_span(path) if progress is not None else None
    now, sleep = pace
    start = time.monotonic()
    paced_from = now()
    try:
        for m in iter_messages(path):
            if parse_sensor_key(m.topic) is None:
                continue
            pub = pubs.get(m.topic)
            if pub is None:
                pub = json_publisher(session, m.topic, congestion_control=zenoh.CongestionControl.BLOCK)
                pubs[m.topic] = pub
                if len(pubs) == 1:  # wait until a subscriber matches before the first put
                    deadline = time.monotonic() + wait_s
                    while not pub.matching_status.matching and time.monotonic() < deadline:
                        time.sleep(0.02)
                    if not pub.matching_status.matching:
                        where = connect or (endpoints[0] if endpoints else f"the endpoints of {config_file}")
                        raise OrdervibError(f"no subscriber matched {m.topic} on {where} within "
                                            f"{wait_s:g} s: nothing published (is the node running? "
                                            "--wait S waits longer)")
            if speed > 0:
                due = paced_from + clock.due(m.log_time) / 1e9 / speed
                delay = due - now()
                if delay > 0:
                    sleep(delay)
            pub.put(m.payload)
            sent += 1
            if progress is not None and span is not None and sent % 1000 == 0:
                progress((m.log_time - span[0]) / max(span[1] - span[0], 1), sent)
    finally:
        time.sleep(CLOSE_GRACE_S)  # let the link drain: close() drops what is still queued
        session.close()
    if progress is not None and span is not None:
        progress(1.0, sent)
    if not quiet:
        if clock.gaps:
            log.info("shortened %d gap(s) longer than %g s to it: %.0f s of standing skipped", clock.gaps,
                     max_gap_s, clock.skipped_s)
        log.info("published %d messages from %s in %.1f s", sent, path, time.monotonic() - start)
    return sent
