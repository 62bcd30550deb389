"""The test session runs the modules the product runs: the compiled per-sample modules when they
are built and current (``node.native``), else the pure Python ones. Compiled, their doctests
cannot be collected from the extension modules: ``tests/test_native.py`` runs them from the
sources in a pure Python subprocess, and replays a recording both ways to the bit."""

from node import native

# paths relative to this directory; empty when the pure Python modules run
collect_ignore = ([str(native.source(m).relative_to(native.ROOT)) for m in native.COMPILED]
                  if native.state() == "compiled" else [])
