"""``ordervib router``: a Zenoh router for a fleet (the Python package's own router mode).

One router, N nodes (``ordervib run --connect ROUTER --beds PATTERN``, disjoint patterns) and
the test beds connected to it: the router relays each bed's sensors to the node whose pattern
matches, and the nodes' outputs to whoever subscribes (``ordervib view --connect ROUTER``).
The Python wheel ships no ``zenohd``; a session opened in router mode routes the same way.
"""

from __future__ import annotations

import argparse
import json
import logging
import signal
import threading

from node.contract import OrdervibError

log = logging.getLogger(__name__)

NAME = "router"
HELP = "a Zenoh router for test beds, nodes (run --beds) and views to connect to"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--listen", action="append", metavar="ENDPOINT",
                   help="endpoint to listen on (repeatable; replaces the --zenoh-config file's; "
                        "default tcp/0.0.0.0:7447 when neither gives one)")
    p.add_argument("--zenoh-config", metavar="FILE.json5",
                   help="Zenoh configuration file (TLS, access control; see docs/zenoh/)")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S seconds")


def router_config(args: argparse.Namespace):
    """The router's Zenoh config and where it listens: --listen, else the --zenoh-config file's
    endpoints (docs/zenoh/acl-router.json5: TLS only), else tcp/0.0.0.0:7447."""
    from node.edges.zenoh import config_file_endpoints, zenoh_config

    listen = args.listen
    if not (listen or config_file_endpoints(args.zenoh_config)):
        listen = ["tcp/0.0.0.0:7447"]
    conf = zenoh_config(listen, None, args.zenoh_config, mode="router")
    return conf, listen or json.loads(conf.get_json("listen/endpoints"))


def run(args: argparse.Namespace) -> int:
    from node.edges.zenoh import open_session

    if args.duration is not None and not args.duration > 0:
        raise OrdervibError("--duration must be > 0")
    conf, listen = router_config(args)
    session = open_session(conf)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    try:
        log.info("ordervib router %s on %s; Ctrl-C stops", session.zid(), ", ".join(listen))
        stop.wait(args.duration)
    finally:
        session.close()
    return 0
