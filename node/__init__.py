"""ordervib node: identification methods, switching model runtime and I/O edges."""

from node import native

__version__ = "0.1.0"

native.guard()  # the compiled per-sample modules, unless stale or turned off (node.native)
