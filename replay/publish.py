"""Publishing a recording's sensor messages to Zenoh, in their original timing (a test bed stand-in)."""

from __future__ import annotations

import logging
import time

from node.contract import OrdervibError, parse_sensor_key
from node.live.zenoh import DEFAULT_ENDPOINT, config_file_endpoints, open_session, zenoh_config
from node.mcap import iter_messages

log = logging.getLogger(__name__)

CLOSE_GRACE_S = 1.0  # wait before closing the session, s: close() drops what is still queued


def publish_recording(path: str, connect: str | None, speed: float, quiet: bool = False,
                      wait_s: float = 5.0, config_file: str | None = None) -> int:
    """Publish a recording's sensor messages in their original timing (``speed`` x; 0: flat out).

    Connects to ``connect``, else to the endpoints of ``config_file``, else to DEFAULT_ENDPOINT.
    Waits up to ``wait_s`` for a subscriber to match the first key; none: ``OrdervibError``,
    nothing published (a test bed stand-in that talks to nobody is no success).
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
    t_first: int | None = None
    start = time.monotonic()
    try:
        for m in iter_messages(path):
            if parse_sensor_key(m.topic) is None:
                continue
            pub = pubs.get(m.topic)
            if pub is None:
                pub = session.declare_publisher(m.topic, congestion_control=zenoh.CongestionControl.BLOCK)
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
                t_first = m.log_time if t_first is None else t_first
                due = start + (m.log_time - t_first) / 1e9 / speed
                delay = due - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
            pub.put(m.payload)
            sent += 1
    finally:
        time.sleep(CLOSE_GRACE_S)  # let the link drain: close() drops what is still queued
        session.close()
    if not quiet:
        log.info("published %d messages from %s in %.1f s", sent, path, time.monotonic() - start)
    return sent
