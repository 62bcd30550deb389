"""Zenoh sessions for the node and its clients: peer mode, endpoints, an optional config file."""

from __future__ import annotations

import json
import re

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
    where = f"--zenoh-config {config_file}" if config_file else "the default"
    try:
        conf = zenoh.Config.from_file(config_file) if config_file else zenoh.Config()
        if not (mode == "peer" and conf.get_json("mode") == json.dumps("client")):
            conf.insert_json5("mode", json.dumps(mode))
        conf.insert_json5("scouting/multicast/enabled", "false")
    except Exception as exc:  # zenoh raises its own ZError, a Rust debug dump
        raise OrdervibError(f"{where}: not a usable Zenoh configuration: {zenoh_words(exc)}") from None
    for option, endpoints in (("listen", listen), ("connect", connect)):
        if not endpoints:
            continue
        for endpoint in endpoints:  # one at a time, to name the bad one
            try:
                conf.insert_json5(f"{option}/endpoints", json.dumps([endpoint]))
            except Exception:
                raise OrdervibError(f"--{option} {endpoint!r}: not a Zenoh endpoint "
                                    f"(<protocol>/<address>, e.g. {DEFAULT_ENDPOINT})") from None
        conf.insert_json5(f"{option}/endpoints", json.dumps(endpoints))
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
        raise OrdervibError(f"--zenoh-config {config_file}: not a usable Zenoh configuration: "
                            f"{zenoh_words(exc)}") from None


def json_publisher(session, key: str, **options):
    """A publisher on ``key`` whose samples say they are JSON: Zenoh encoding
    ``application/json`` (docs/contract.md section 2; a bare ``put`` says ``zenoh/bytes``).
    ``options`` go to ``declare_publisher`` (congestion control, priority, ...)."""
    import zenoh
    return session.declare_publisher(key, encoding=zenoh.Encoding.APPLICATION_JSON, **options)


def zenoh_words(exc: BaseException) -> str:
    """A Zenoh error in one line of its own words: the message inside a Rust debug dump, without
    the build machine's source paths.

    >>> zenoh_words(Exception('Json5Err(Message { msg: "bad thing: x at /cargo/registry/a/b.rs:615.", '
    ...                       'location: None }) at /cargo/registry/c.rs:86.'))
    'bad thing: x'
    >>> zenoh_words(Exception(' --> 1:8\\n  |\\n1 | {mode: \\n  = expected a value at /x/lib.rs:1486.'))
    'line 1, column 8: expected a value'
    """
    text = str(exc)
    inner = re.search(r'msg: "((?:[^"\\]|\\.)*)"', text)
    if inner:
        text = inner.group(1)
    text = re.sub(r"\s+at /\S+?\.rs:\d+\.?", "", text)
    parse = re.search(r"-->\s*(\d+):(\d+).*?=\s*(.+)", text, re.S)
    if parse:
        text = f"line {parse.group(1)}, column {parse.group(2)}: {parse.group(3)}"
    return " ".join(text.split()) or type(exc).__name__


def open_session(conf):
    """A Zenoh session of ``conf``; a failure (an endpoint it cannot listen on, say) is an
    ``OrdervibError`` in one line that names the endpoints and the options that set them."""
    import zenoh
    try:
        return zenoh.open(conf)
    except Exception as exc:
        ends = []
        for option in ("listen", "connect"):
            try:
                given = json.loads(conf.get_json(f"{option}/endpoints"))
            except Exception:
                given = None
            if isinstance(given, list) and given:
                ends.append(f"{option} {', '.join(map(str, given))}")
        where = f" ({'; '.join(ends)})" if ends else ""
        raise OrdervibError(f"cannot open the Zenoh session{where}: {zenoh_words(exc)} "
                            "(check --listen, --connect and --zenoh-config)") from None
