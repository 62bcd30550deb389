"""Checks shared by the sub-commands on the files they are told to write."""

from __future__ import annotations

import os

from node.contract.errors import OrdervibError


def check_output_file(path: str, option: str, suffix: str | None = None) -> None:
    """One-line OrdervibError unless ``path`` can be a new file (right suffix, existing folder)."""
    if suffix is not None and not path.endswith(suffix):
        raise OrdervibError(f"{option} must name a {suffix} file, got {path!r}")
    if os.path.isdir(path):
        raise OrdervibError(f"{option} is a directory: {path}")
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        raise OrdervibError(f"output directory does not exist: {parent}")
