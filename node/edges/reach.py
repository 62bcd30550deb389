"""Whether a Zenoh session reaches its ``connect`` endpoints: a warning while none answers.

A peer (or a client) whose connect endpoints answer nothing opens all the same: Zenoh keeps
trying in the background, and a node that reaches no one looked like a quiet test bed. ``Reach``
looks at the session's links (``session.info.links()``: a link's ``dst`` is the endpoint it
connected to), routers and peers when asked (the live node: once a second), and logs a warning
once none of the configured endpoints has answered for ``GRACE_S``, then again after twice the last
wait (at most ``BACKOFF_MAX_S``) while it lasts, and one line when one answers again. Its
``connected``, ``routers`` and ``peers`` go to the node's own health.
"""

from __future__ import annotations

import ipaddress
import json
import logging
from typing import Any

log = logging.getLogger(__name__)

GRACE_S = 2.0  # no endpoint answering this long: the first warning, s
BACKOFF_MAX_S = 60.0  # the longest wait between two warnings, s


def connect_endpoints(conf: Any) -> list[str]:
    """The endpoints a Zenoh config connects to (``connect/endpoints``: a list, or a list per mode)."""
    try:
        given = json.loads(conf.get_json("connect/endpoints"))
    except Exception:  # noqa: BLE001 - no such entry
        return []
    if isinstance(given, dict):  # {"router": [...], "peer": [...], ...}
        given = [e for ends in given.values() if isinstance(ends, list) for e in ends]
    return [str(e) for e in given] if isinstance(given, list) else []


def _where(endpoint: str) -> tuple[str, str, str]:
    """(protocol, host, port) of an endpoint, its metadata and config left out; host "" when
    not an IP address (a name resolves to an address a link's ``dst`` shows instead).

    >>> _where("tcp/127.0.0.1:7447?prio=1#iface=lo"), _where("tls/router.lan:7447"), _where("tcp/[::1]:1")
    (('tcp', '127.0.0.1', '7447'), ('tls', '', '7447'), ('tcp', '::1', '1'))
    """
    proto, _, address = endpoint.split("?", 1)[0].split("#", 1)[0].partition("/")
    host, colon, port = address.rpartition(":")
    if not colon:
        return proto, address, ""
    host = host.strip("[]")
    try:
        ipaddress.ip_address(host)
    except ValueError:
        host = ""
    return proto, host, port


def answers(endpoint: str, dst: str) -> bool:
    """Whether a link to ``dst`` (a link's destination, ``proto/ip:port``) is one to ``endpoint``.

    >>> answers("tcp/127.0.0.1:7447", "tcp/127.0.0.1:7447"), answers("tcp/localhost:7447", "tcp/[::1]:7447")
    (True, True)
    >>> answers("tcp/127.0.0.1:7447", "tcp/127.0.0.1:7448")
    False
    """
    want, got = _where(endpoint), _where(dst)
    return want[0] == got[0] and want[2] == got[2] and want[1] in ("", got[1])


class Reach:
    """A session's reach of its ``endpoints`` (see the module); ``check(info, now)`` with the
    session's ``info`` and a monotonic clock (s).

    >>> from types import SimpleNamespace as S
    >>> info = S(links=lambda: [], routers_zid=lambda: [], peers_zid=lambda: [])
    >>> r = Reach(["tcp/127.0.0.1:1"], started=0.0)
    >>> [r.check(info, t) for t in (1.0, 2.5, 3.0, 6.0, 6.5, 14.5)]  # at 2 s, then 4 s and 8 s later
    [False, True, False, False, True, True]
    >>> r.connected, Reach([], 0.0).connected
    (False, None)
    """

    def __init__(self, endpoints: list[str], started: float) -> None:
        self.endpoints = endpoints
        self.connected: bool | None = None if not endpoints else False
        self.routers = 0  # routers the session has now
        self.peers = 0  # peers the session has now
        self._since = started  # since when no endpoint answers, s
        self._next = started + GRACE_S  # the next warning, s
        self._wait = GRACE_S  # the wait before the next warning after that, s

    def check(self, info: Any, now: float) -> bool:
        """Look at the session now (monotonic s); whether a warning was logged."""
        self.routers = sum(1 for _ in info.routers_zid())
        self.peers = sum(1 for _ in info.peers_zid())
        if not self.endpoints:
            return False
        dsts = [str(link.dst) for link in info.links()]
        up = any(answers(e, d) for e in self.endpoints for d in dsts)
        if up:
            if self.connected is False and now >= self._since + GRACE_S:  # it had been said
                log.info("Zenoh: --connect %s answers now (%d routers, %d peers)",
                         ", ".join(self.endpoints), self.routers, self.peers)
            self.connected = True
            return False
        if self.connected:  # lost: say so after the grace again
            self._since, self._next, self._wait = now, now + GRACE_S, GRACE_S
        self.connected = False
        if now < self._next:
            return False
        self._wait = min(2 * self._wait, BACKOFF_MAX_S)
        self._next = now + self._wait
        log.warning("Zenoh: no --connect endpoint answers (%s) for %.0f s: the node reaches no "
                    "router or peer through them (%d routers, %d peers); retrying, next word in %.0f s",
                    ", ".join(self.endpoints), now - self._since, self.routers, self.peers, self._wait)
        return True
