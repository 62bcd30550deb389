"""Zenoh sessions for the node and its clients: peer mode, endpoints, an optional config file."""

from __future__ import annotations

import json

from node.contract import OrdervibError

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"


def zenoh_config(listen: list[str] | None = None, connect: list[str] | None = None,
                 config_file: str | None = None, mode: str = "peer"):
    """A Zenoh config (``mode`` peer, or router for ``ordervib router``): listen/connect
    endpoints, no multicast scouting.

    ``config_file`` (JSON5, Zenoh's own format) carries TLS and access control
    for a real deployment; the endpoint options are applied on top of it. A file that says
    ``mode: "client"`` keeps it where ``mode`` is peer: a client talks to its router only, so
    the router's access control sees all its traffic (docs/zenoh/acl-*.json5).
    """
    import zenoh
    try:
        conf = zenoh.Config.from_file(config_file) if config_file else zenoh.Config()
        if not (mode == "peer" and conf.get_json("mode") == json.dumps("client")):
            conf.insert_json5("mode", json.dumps(mode))
        conf.insert_json5("scouting/multicast/enabled", "false")
        if listen:
            conf.insert_json5("listen/endpoints", json.dumps(listen))
        if connect:
            conf.insert_json5("connect/endpoints", json.dumps(connect))
    except Exception as exc:  # zenoh raises its own ZError for a bad config
        raise OrdervibError(f"bad Zenoh configuration: {exc}") from None
    return conf


def config_file_endpoints(config_file: str | None) -> bool:
    """Whether a Zenoh config file sets listen or connect endpoints of its own."""
    if not config_file:
        return False
    import zenoh
    try:
        conf, default = zenoh.Config.from_file(config_file), zenoh.Config()
        return any(conf.get_json(k) != default.get_json(k)
                   for k in ("listen/endpoints", "connect/endpoints"))
    except Exception as exc:
        raise OrdervibError(f"bad Zenoh configuration: {exc}") from None


def json_publisher(session, key: str, **options):
    """A publisher on ``key`` whose samples say they are JSON: Zenoh encoding
    ``application/json`` (INTERFACE.md section 2; a bare ``put`` says ``zenoh/bytes``).
    ``options`` go to ``declare_publisher`` (congestion control, priority, ...)."""
    import zenoh
    return session.declare_publisher(key, encoding=zenoh.Encoding.APPLICATION_JSON, **options)


def open_session(conf):
    import zenoh
    try:
        return zenoh.open(conf)
    except Exception as exc:
        raise OrdervibError(f"cannot open the Zenoh session: {exc}") from None
