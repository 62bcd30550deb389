"""Status output of the commands: the ``logging`` set-up of ``ordervib`` and a progress display.

Modules log through ``logging.getLogger(__name__)``; while a command runs, records of the
project's packages at the chosen level and above go to stderr, one line each, as the plain
message (a ``warning:`` or ``error:`` prefix for those levels). ``print`` is kept for a
command's result on stdout.

>>> def record(level: int, msg: str) -> logging.LogRecord:
...     return logging.LogRecord("node.x", level, __file__, 1, msg, None, None)
>>> LineFormatter().format(record(logging.INFO, "read x.mcap: 3 run(s)"))
'read x.mcap: 3 run(s)'
>>> LineFormatter().format(record(logging.WARNING, "late sample"))
'warning: late sample'
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Iterator
from contextlib import contextmanager

LEVELS: dict[str, int] = {"debug": logging.DEBUG, "info": logging.INFO, "warning": logging.WARNING,
                          "error": logging.ERROR}
PACKAGES = ("node", "replay", "simulator", "bench")  # loggers whose level --log-level sets


class LineFormatter(logging.Formatter):
    """The message alone for debug and info; ``warning: message`` and ``error: message`` above."""

    def format(self, record: logging.LogRecord) -> str:
        text = super().format(record)
        return text if record.levelno < logging.WARNING else f"{record.levelname.lower()}: {text}"


class StderrHandler(logging.Handler):
    """One line per record to the *current* ``sys.stderr`` (so later redirections are followed).

    Ends a progress bar left open on the terminal first, so a record never lands inside it.
    """

    bar_open = False  # a '\r' progress bar is on the terminal's last line

    def emit(self, record: logging.LogRecord) -> None:
        stream = sys.stderr
        if stream is None:
            return
        try:
            line = self.format(record)
            if StderrHandler.bar_open:
                StderrHandler.bar_open = False
                line = "\n" + line
            stream.write(line + "\n")
            stream.flush()
        except Exception:
            self.handleError(record)


@contextmanager
def command_logging(level: str | None, quiet: bool = False) -> Iterator[None]:
    """Send the project's log records to stderr while the block runs; restores the set-up after.

    level: one of LEVELS; None keeps the level of an enclosing command (``ordervib demo`` runs
    others), else info. quiet (a command's ``--quiet``) raises it to at least warning.
    """
    root = logging.getLogger()
    outer = next((h for h in root.handlers if isinstance(h, StderrHandler)), None)
    loggers = [logging.getLogger(name) for name in PACKAGES]
    saved = [lg.level for lg in loggers]
    if level is None and outer is not None:
        number = loggers[0].getEffectiveLevel()
    else:
        number = LEVELS[level or "info"]
    if quiet:
        number = max(number, logging.WARNING)
    handler = outer or StderrHandler()
    if outer is None:
        handler.setFormatter(LineFormatter())
        root.addHandler(handler)
    for lg in loggers:
        lg.setLevel(number)
    try:
        yield
    finally:
        for lg, lv in zip(loggers, saved):
            lg.setLevel(lv)
        if outer is None:
            root.removeHandler(handler)


class Progress:
    """Percentage of a long step: a bar redrawn in place on a terminal, else a log line every ``step`` %.

    Shown only when ``logger`` shows info records; call it with the fraction done (0..1).

    >>> p = Progress("simulate", logging.getLogger("doctest.quiet"))  # warning level: shows nothing
    >>> p(0.5)
    """

    def __init__(self, label: str, logger: logging.Logger, step: int = 25) -> None:
        self.label = label
        self.logger = logger
        self.step = step
        self.last = -1

    def __call__(self, fraction: float) -> None:
        pct = int(100 * min(max(fraction, 0.0), 1.0))
        if pct == self.last or not self.logger.isEnabledFor(logging.INFO):
            return
        last, self.last = self.last, pct
        stream = sys.stderr
        if stream is not None and stream.isatty():
            bar = "#" * (pct // 4)
            stream.write(f"\r{self.label}: [{bar:<25}] {pct:3d}%" + ("\n" if pct == 100 else ""))
            stream.flush()
            StderrHandler.bar_open = pct < 100
        elif pct // self.step > max(last, 0) // self.step:
            self.logger.info("%s: %d%%", self.label, pct)
