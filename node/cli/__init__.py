"""The ``ordervib`` console command: a thin dispatcher over ``node.cli``.

Every expected failure (bad file, bad option, bad data) ends with one line on
stderr and a non-zero exit status; tracebacks are reserved for bugs. Status goes
through ``logging`` to stderr (``--log-level``, see ``node.cli.logs``); a command's
result is printed on stdout.
"""

from __future__ import annotations

import argparse
import importlib
import os
import signal
import sys
import threading
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import NoReturn

from node import __version__
from node.cli.logs import LEVELS, command_logging
from node.contract.errors import OrdervibError

# Sub-command modules, in the order they appear in ``ordervib --help``.
COMMAND_MODULES: tuple[str, ...] = (
    "node.cli.simulate",
    "node.cli.train",
    "node.cli.evaluate",
    "node.cli.predict",
    "node.cli.report",
    "node.cli.schedule",
    "node.cli.replay",
    "node.cli.run",
    "node.cli.demo",
    "node.cli.view",
    "node.cli.recover",
    "node.cli.ingest",
    "node.cli.router",
    "node.cli.native",
)


class _Parser(argparse.ArgumentParser):
    """argparse that reports a bad option in one line, under its own name (``ordervib`` or
    ``ordervib <sub-command>``), and exits with status 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message}\n")


class _Refused(Exception):
    """A sub-command's parse failed (raised by ``_CommandParser.error`` while it looks)."""

    def __init__(self, message: str) -> None:
        super().__init__(message)
        self.message = message


class _CommandParser(_Parser):
    """A sub-command's parser: an argument it does not know is named under its own prefix.

    Plain argparse leaves the arguments a sub-parser does not know to the top parser, which
    reports them under ``ordervib:``, and only after the sub-parser has reported the required
    arguments missing (an unknown flag before a required one reads as "required"). Here the
    sub-parser takes all of its arguments: any left over is an error of its own, named first.
    """

    _looking = False

    def error(self, message: str) -> NoReturn:
        if self._looking:
            raise _Refused(message)
        super().error(message)

    def parse_known_args(self, args: Sequence[str] | None = None,  # type: ignore[override]
                         namespace: argparse.Namespace | None = None
                         ) -> tuple[argparse.Namespace, list[str]]:
        self._looking = True
        try:
            ns, extras = super().parse_known_args(args, namespace)
            refused = None
        except _Refused as exc:
            ns, extras, refused = argparse.Namespace(), self._unknown(args), exc.message
        finally:
            self._looking = False
        if extras:
            self.error(f"unrecognized arguments: {' '.join(extras)}")
        if refused is not None:
            self.error(refused)
        return ns, []

    def _unknown(self, args: Sequence[str] | None) -> list[str]:
        """The arguments of ``args`` this parser does not know, found with no argument required
        (a parse that failed for another reason: none)."""
        required = [(a, a.required) for a in self._actions]
        try:
            for a, _ in required:
                a.required = False
            return super().parse_known_args(args, argparse.Namespace())[1]
        except _Refused:
            return []
        finally:
            for a, was in required:
                a.required = was


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="ordervib", description="Tracked-order vibration monitoring node.")
    parser.add_argument("--version", action="version", version=f"ordervib {__version__}")
    log_help = "status shown on stderr (default info; a command's --quiet means warning)"
    parser.add_argument("--log-level", choices=tuple(LEVELS), default=None, help=log_help)
    # the same option after the sub-command; SUPPRESS: absent there, it keeps the value given before
    common = _CommandParser(add_help=False)
    common.add_argument("--log-level", choices=tuple(LEVELS), default=argparse.SUPPRESS, help=log_help)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_CommandParser)
    for mod_name in COMMAND_MODULES:
        try:
            mod = importlib.import_module(mod_name)
        except ModuleNotFoundError as exc:  # a command whose module is not there yet
            if exc.name == mod_name:
                continue
            raise
        p = sub.add_parser(mod.NAME, help=mod.HELP, description=mod.HELP, parents=[common])
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "_run", None):
        parser.print_help()
        return 2
    try:
        with command_logging(args.log_level, getattr(args, "quiet", False)), _sigterm_interrupts():
            return int(args._run(args) or 0)
    except OrdervibError as exc:
        print(f"ordervib {args.command}: {exc}", file=sys.stderr)
        return 2
    except (FileNotFoundError, IsADirectoryError, PermissionError) as exc:
        print(f"ordervib {args.command}: {exc.strerror}: {exc.filename}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # output piped into a reader that stopped (e.g. head)
        sys.stderr.close()
        return 0
    except Terminated:
        print(f"ordervib {args.command}: terminated (SIGTERM)", file=sys.stderr)
        return 128 + signal.SIGTERM
    except KeyboardInterrupt:
        print(f"ordervib {args.command}: interrupted", file=sys.stderr)
        return 130


def console() -> None:
    """The ``ordervib`` executable: ``main`` and exit with its status.

    An interrupted command (Ctrl-C, SIGTERM) has already stopped its workers, removed its
    temporary files and printed its one line: it then leaves without the interpreter's exit
    hooks, which can only add noise (a stopped process pool's wake-up pipe, CPython 3.11).
    """
    code = main()
    if code in (130, 128 + signal.SIGTERM):
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):
                pass
        os._exit(code)
    sys.exit(code)


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread so that a command cleans up as after Ctrl-C."""


def _raise_terminated(signum: int, frame: object) -> None:
    raise Terminated()


@contextmanager
def _sigterm_interrupts() -> Iterator[None]:
    """While a command runs, SIGTERM interrupts it like Ctrl-C (its workers and temporary
    files are cleaned up on the way out); the previous handler is restored after."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)

