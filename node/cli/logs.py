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
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from node.console.durations import duration_text

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
    """Progress of a long step, with its rate and the time left: a bar redrawn in place on a
    terminal, else a log line every ``step`` % or every ``every_s`` seconds, whichever first.

    Shown only when ``logger`` shows info records; call it with the fraction done (0..1), and
    optionally the count of things done and their unit (the rate is then things per second).
    The time left assumes the rest goes at the mean rate so far.

    >>> p = Progress("simulate", logging.getLogger("doctest.quiet"))  # warning level: shows nothing
    >>> p(0.5)
    """

    def __init__(self, label: str, logger: logging.Logger, step: int = 25, every_s: float = 30.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.label = label
        self.logger = logger
        self.step = step
        self.every_s = every_s
        self.clock = clock
        self.last = -1
        self._t0: float | None = None
        self._t_line = 0.0

    def text(self, fraction: float, done: int | None = None, unit: str = "") -> str:
        """The status after ``fraction`` (e.g. '40% (400 runs, 20 runs/s, 30 s left)')."""
        now = self.clock()
        t0 = self._t0 if self._t0 is not None else now
        elapsed = now - t0
        parts = []
        if done is not None and elapsed > 0:
            rate = done / elapsed
            shown = f"{rate:.0f}" if rate >= 10 else f"{rate:.2g}"
            parts.append(f"{done} {unit}, {shown} {unit}/s" if unit else f"{done}, {shown}/s")
        if 0 < fraction < 1 and elapsed > 0:
            parts.append(f"{duration_text(elapsed * (1 - fraction) / fraction)} left")
        elif fraction >= 1:
            parts.append(f"took {duration_text(elapsed)}")
        pct = int(100 * min(max(fraction, 0.0), 1.0))
        return f"{pct}%" + (f" ({', '.join(parts)})" if parts else "")

    def __call__(self, fraction: float, done: int | None = None, unit: str = "") -> None:
        if not self.logger.isEnabledFor(logging.INFO):
            return
        now = self.clock()
        if self._t0 is None:
            self._t0 = self._t_line = now
        pct = int(100 * min(max(fraction, 0.0), 1.0))
        last, self.last = self.last, pct
        stream = sys.stderr
        if stream is not None and stream.isatty():
            if pct == last and pct < 100:
                return
            bar = "#" * (pct // 4)
            stream.write(f"\r{self.label}: [{bar:<25}] {self.text(fraction, done, unit):<48}"
                         + ("\n" if pct == 100 else ""))
            stream.flush()
            StderrHandler.bar_open = pct < 100
        elif (pct // self.step > max(last, 0) // self.step and pct != last) or \
                (now - self._t_line >= self.every_s and pct < 100):
            self._t_line = now
            self.logger.info("%s: %s", self.label, self.text(fraction, done, unit))
