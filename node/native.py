"""The per-sample path compiled by mypyc: the very same source, as C extension modules.

The node's runtime (``node.runtime``: aligner, OC detection, pipelines, guards, alarms,
transients), the contract's slotting, payload decoding and keys, the MCAP writer and the fleet
baselines run once per message or per sample, in plain Python: most of a
message's cost is the interpreter's own (attribute and dict lookups, boxed floats, calls), not
numpy's. mypyc compiles these typed modules, unchanged, into extension modules (``build``): the
node's logic costs a third less a message (``bench worker-speed``) and offline replay's logic runs
1.46x as fast (``bench replay-speed``), with outputs identical to the bit (CPython's floats are C doubles
either way; ``tests/test_native.py`` replays the sample runs both ways). No rule is written twice:
there is one source, and the pure Python modules stay the reference.

The compiled modules sit beside their sources (``<module>.cpython-*.so``, never committed) with a
stamp: the SHA-256 of the sources they were built from (``STAMP``). On import of ``node``
(``guard``), compiled modules whose sources changed since (stale), or any when ``ORDERVIB_PURE``
is set, are not used: every module of ``COMPILED`` then loads from its ``.py`` (all or none: the
compiled modules call each other directly). ``state()`` says which ran; the node logs it at start.

    ordervib native build      # compile (needs gcc, the Python headers and mypy; ~80 s)
    ordervib native state      # compiled, or why not: absent / stale / off
    ordervib native clean      # remove the compiled modules and the stamp

>>> "node.runtime.align" in COMPILED and "node.live.node" not in COMPILED
True
"""

from __future__ import annotations

import hashlib
import importlib.abc
import importlib.machinery
import importlib.util
import json
import logging
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType
from typing import Literal

log = logging.getLogger(__name__)

ROOT = Path(__file__).resolve().parent.parent  # holds the node package
STAMP = Path(__file__).resolve().parent / ".native-stamp.json"
PURE_ENV = "ORDERVIB_PURE"  # set (to anything but "" or "0"): the pure Python modules, always
STAMP_VERSION = 1

# The modules compiled: the per-message and per-sample path. Left out: modules whose classes are
# introspected (the contract's message schemas: typing.get_type_hints), that hold a complex
# default (node.models.curve: mypyc 2.4 fails on it at import), whose frozen dataclasses go to
# other processes (node.models.envelope: a compiled one does not unpickle), or do I/O and
# threads (node.live, node.edges).
COMPILED: tuple[str, ...] = (
    "node.contract.keys",
    "node.contract.payload",
    "node.contract.slotting",
    "node.contract.vector",
    "node.mcap.writer",
    "node.models.baseline",
    "node.runtime.alarms",
    "node.runtime.align",
    "node.runtime.chirp",
    "node.runtime.clock",
    "node.runtime.core",
    "node.runtime.guard",
    "node.runtime.history",
    "node.runtime.ocdetect",
    "node.runtime.pipeline",
    "node.runtime.plateaus",
    "node.runtime.ramp_analyser",
    "node.runtime.rows",
    "node.runtime.runcurve",
    "node.runtime.transient",
    "node.runtime.transient_watch",
)

State = Literal["compiled", "stale", "off", "absent"]


def source(module: str, root: Path = ROOT) -> Path:
    """A module's source file: ``node.runtime.align`` -> ROOT/node/runtime/align.py."""
    return root.joinpath(*module.split(".")).with_suffix(".py")


def extensions(module: str, root: Path = ROOT) -> list[Path]:
    """A module's compiled files beside its source (the module and its ``__mypyc`` library)."""
    src = source(module, root)
    return sorted(p for suffix in importlib.machinery.EXTENSION_SUFFIXES
                  for p in (src.with_suffix(suffix), src.with_name(src.stem + "__mypyc" + suffix))
                  if p.exists())


def digest(modules: Sequence[str] = COMPILED, root: Path = ROOT) -> str:
    """SHA-256 over the modules' names and sources (what a build compiled)."""
    h = hashlib.sha256()
    for m in modules:
        h.update(m.encode() + b"\0")
        h.update(source(m, root).read_bytes())
    return h.hexdigest()


def read_stamp(path: Path = STAMP) -> dict | None:
    """The stamp a build wrote, None when absent or unreadable."""
    try:
        stamp = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return stamp if isinstance(stamp, dict) and stamp.get("version") == STAMP_VERSION else None


def judge(modules: Sequence[str] = COMPILED, root: Path = ROOT, stamp_path: Path = STAMP,
          env: dict[str, str] | None = None) -> State:
    """Whether the compiled modules should run: ``absent`` (none built), ``off`` (``PURE_ENV``
    set), ``stale`` (no stamp, another module list, or a source changed since the build), else
    ``compiled``."""
    if not any(extensions(m, root) for m in modules):
        return "absent"
    if (env if env is not None else os.environ).get(PURE_ENV, "") not in ("", "0"):
        return "off"
    stamp = read_stamp(stamp_path)
    if stamp is None or stamp.get("modules") != list(modules):
        return "stale"
    if stamp.get("sources") != digest(modules, root):
        return "stale"
    return "compiled"


class PureFinder(importlib.abc.MetaPathFinder):
    """Loads each of ``modules`` from its ``.py`` source, whatever lies beside it."""

    def __init__(self, modules: Sequence[str], root: Path = ROOT) -> None:
        self.modules = frozenset(modules)
        self.root = root

    def find_spec(self, fullname: str, path: Sequence[str] | None = None,
                  target: ModuleType | None = None) -> importlib.machinery.ModuleSpec | None:
        if fullname not in self.modules:
            return None
        return importlib.util.spec_from_file_location(fullname, source(fullname, self.root))


_state: State | None = None


def guard() -> State:
    """Decide once per process (``node/__init__``) whether the compiled modules run; when they
    must not, every module of ``COMPILED`` loads from source from now on."""
    global _state
    if _state is None:
        _state = judge()
        if _state in ("stale", "off"):
            sys.meta_path.insert(0, PureFinder(COMPILED))
        if _state == "stale":
            log.warning("the compiled modules are stale (a source changed since they were built): "
                        "the pure Python modules run; rebuild with ordervib native build")
    return _state


def state() -> State:
    """Which modules run in this process: ``compiled`` or the pure Python ones (``absent``,
    ``off``, ``stale``; see ``judge``)."""
    return guard()


def clean(modules: Sequence[str] = COMPILED, root: Path = ROOT, stamp_path: Path = STAMP) -> int:
    """Remove the compiled modules and the stamp; how many files went."""
    gone = [p for m in modules for p in extensions(m, root)] + ([stamp_path] if stamp_path.exists() else [])
    for p in gone:
        p.unlink()
    return len(gone)


def build(modules: Sequence[str] = COMPILED, root: Path = ROOT, stamp_path: Path = STAMP,
          opt_level: str = "3") -> float:
    """Compile the modules in place with mypyc (each its own extension: ``separate``), then write
    the stamp of the sources compiled; seconds taken. Raises ``RuntimeError`` in one line when
    mypyc or a compiler is missing or the build fails (the pure Python modules then run)."""
    try:
        from mypyc.build import mypycify
        from setuptools import Distribution
    except ImportError as exc:
        raise RuntimeError(f"mypyc or setuptools is not installed ({exc}): pip install mypy setuptools") \
            from None
    t0 = time.monotonic()
    before = digest(modules, root)
    clean(modules, root, stamp_path)
    cwd = os.getcwd()
    os.chdir(root)  # mypycify takes paths relative to the project; build_ext --inplace writes beside them
    try:
        paths = [str(source(m, root).relative_to(root)) for m in modules]
        dist = Distribution({"name": "ordervib-native", "ext_modules": mypycify(paths, opt_level=opt_level,
                                                                                   separate=True)})
        dist.script_args = ["-q", "build_ext", "--inplace", "--build-temp", "build/native-temp"]
        dist.parse_command_line()
        dist.run_commands()
    except (SystemExit, Exception) as exc:  # setuptools ends a failed compile with SystemExit
        clean(modules, root, stamp_path)
        raise RuntimeError(f"the mypyc build failed ({type(exc).__name__}: {exc}); the pure Python "
                           "modules run") from None
    finally:
        os.chdir(cwd)
    if digest(modules, root) != before:  # a source changed while it compiled: do not claim it
        clean(modules, root, stamp_path)
        raise RuntimeError("a source changed during the build; build again")
    stamp_path.write_text(json.dumps({"version": STAMP_VERSION, "modules": list(modules), "sources": before,
                                      "python": sys.version.split()[0]}, indent=1))
    return time.monotonic() - t0
