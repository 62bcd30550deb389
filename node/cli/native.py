"""``ordervib native``: build, show or remove the compiled per-sample modules (``node.native``)."""

from __future__ import annotations

import argparse
import logging

from node import native
from node.contract.errors import OrdervibError

NAME = "native"
HELP = "compile the per-sample modules with mypyc (build), say whether they run (state), remove them (clean)"

log = logging.getLogger(__name__)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("action", choices=["build", "state", "clean"])
    p.add_argument("--if-needed", action="store_true",
                   help="build: only when the compiled modules are absent or stale")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")


def run(args: argparse.Namespace) -> int:
    if args.action == "state":
        print(native.judge())
        return 0
    if args.action == "clean":
        log.info("removed %d file(s)", native.clean())
        return 0
    if args.if_needed and native.judge() in ("compiled", "off"):
        return 0
    log.info("compiling %d modules with mypyc (about 80 s) ...", len(native.COMPILED))
    try:
        took = native.build()
    except RuntimeError as exc:
        raise OrdervibError(str(exc)) from None
    log.info("compiled %d modules in %.0f s; they run from the next process on", len(native.COMPILED), took)
    return 0
