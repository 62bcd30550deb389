"""The test session runs the pure Python modules (``node.native``): the doctests are collected
from the sources, and a compiled module may not be patched. ``tests/test_native.py`` runs the
compiled ones beside them in subprocesses and asserts identical outputs."""

import os

os.environ["ORDERVIB_PURE"] = "1"  # before anything imports node; inherited by the node subprocesses
