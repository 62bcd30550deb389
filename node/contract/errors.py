"""Errors that the command line reports as one line, without a traceback."""


class OrdervibError(Exception):
    """A user-facing failure: bad input file, bad option, refused model bundle."""
