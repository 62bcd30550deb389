"""ordervib's own files (the engine-history state, a model bundle's manifest and arrays, a
model's kept training runs): read as untrusted input, parsed and checked in one place, every
fault a one-line ``OrdervibError`` naming the file and what is wrong.

- Only regular files are read (a FIFO would hang the reader, a device never ends), and only
  up to a size bound (``read_bounded``).
- JSON is bounded before it is parsed (``parse_json``): nesting depth (``MAX_DEPTH``) and
  integer digits (``MAX_INT_DIGITS``); Python's parser would raise RecursionError, or
  spend quadratic time on a huge integer (and refuse one of 4,300 digits with a traceback).
- npz archives are read member by member (``read_npz``): the names are checked against the
  caller's expected ones and every member's ``.npy`` header (dtype, shape) and declared
  size against bounds *before* anything is decompressed; only float64 arrays, never pickles.
"""

from __future__ import annotations

import io
import json
import math
import os
import re
import stat
import zipfile
import zlib
from collections.abc import Callable
from typing import Any

import numpy as np

from node.contract.errors import OrdervibError

MAX_DOCUMENT_BYTES = 16 << 20  # a JSON file: the demo's manifests are 30 kB, an engine state < 1 kB
MAX_DEPTH = 32  # JSON nesting: a manifest nests 7 deep (an average model's members a few more)
MAX_INT_DIGITS = 20  # an int64 has 19 digits; no count, size or time ordervib writes is longer
MAX_NPZ_MEMBERS = 100_000  # the demo's bundles hold 189 arrays
READ_CHUNK = 1 << 20
NPZ_OVERHEAD = 16 << 20  # an npz file's own records beyond its arrays' bytes: 160 per member

_KEY_BEFORE = re.compile(r'"((?:[^"\\]|\\.){0,200})"\s*:')
_TOKEN = re.compile(r'"[^"\\]*(?:\\.[^"\\]*)*"|[\[\]{}]')  # a string (skipped) or a bracket
_LONG_INT = re.compile(rf"(?<![\w.])-?\d{{{MAX_INT_DIGITS + 1},}}")


def open_regular(path: str | os.PathLike, where: str, max_bytes: int) -> io.BufferedReader:
    """``path`` opened for reading if it is a regular file of at most ``max_bytes``; a FIFO, a
    device or a folder is refused without waiting on it (``OrdervibError`` "<where>: ...").
    A missing file raises ``FileNotFoundError`` for the caller to word.

    >>> open_regular("/dev/null", "x", 10)
    Traceback (most recent call last):
    node.contract.errors.OrdervibError: x: not a regular file (a character device)
    """
    try:  # O_NONBLOCK: opening a FIFO without a writer returns at once (then it is refused)
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except FileNotFoundError:
        raise
    except OSError as exc:
        raise OrdervibError(f"{where}: cannot be read ({exc.strerror})") from None
    f = os.fdopen(fd, "rb")
    st = os.fstat(fd)
    if not stat.S_ISREG(st.st_mode):
        f.close()
        raise OrdervibError(f"{where}: not a regular file ({file_kind(st.st_mode)})")
    if st.st_size > max_bytes:
        f.close()
        raise OrdervibError(f"{where}: {st.st_size} bytes, more than the {max_bytes} such a file may hold")
    return f


def read_bounded(path: str | os.PathLike, where: str, max_bytes: int) -> bytes:
    """The bytes of the regular file ``path`` (``open_regular``), at most ``max_bytes``."""
    with open_regular(path, where, max_bytes) as f:
        size = os.fstat(f.fileno()).st_size  # (read(n) allocates n bytes first: not the bound)
        try:
            data = f.read(size + 1)
        except OSError as exc:
            raise OrdervibError(f"{where}: cannot be read ({exc.strerror})") from None
    if len(data) > size:
        raise OrdervibError(f"{where}: grew while it was read")
    return data


def file_kind(mode: int) -> str:
    """What a non-regular file is, for messages: "a FIFO", "a folder", ..."""
    for test, name in ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def read_document(path: str | os.PathLike, where: str, max_bytes: int = MAX_DOCUMENT_BYTES) -> str:
    """The UTF-8 text of a regular file of at most ``max_bytes`` (``read_bounded``)."""
    data = read_bounded(path, where, max_bytes)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise OrdervibError(f"{where}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None


def parse_json(text: str, where: str) -> Any:
    """The JSON value in ``text``, refused in one line (naming the place and the key before it)
    when it nests deeper than ``MAX_DEPTH`` or holds an integer of more than ``MAX_INT_DIGITS``.

    >>> parse_json('{"n": [1, 2.5, null]}', "a.json")
    {'n': [1, 2.5, None]}
    >>> parse_json('{"n_runs": ' + "9" * 5000 + '}', "a.json")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    node.contract.errors.OrdervibError: a.json: line 1 column 12 (key 'n_runs'): an integer of 5000 digits...
    >>> parse_json('{"x": ' + "[" * 100 + "]" * 100 + '}', "a.json")
    Traceback (most recent call last):
    node.contract.errors.OrdervibError: a.json: line 1 column 38 (key 'x'): nested deeper than 32
    """
    deep = _too_deep(text)
    if deep is not None:
        raise OrdervibError(f"{where}: {_place(text, deep)}: nested deeper than {MAX_DEPTH}")
    try:
        return json.loads(text, parse_int=_bounded_int)
    except json.JSONDecodeError as exc:
        raise OrdervibError(f"{where}: not valid JSON ({exc})") from None
    except _LongInteger:
        m = _LONG_INT.search(text)
        at, n = (m.start(), len(m.group().lstrip("-"))) if m else (0, MAX_INT_DIGITS + 1)
        raise OrdervibError(f"{where}: {_place(text, at)}: an integer of {n} digits "
                            f"(at most {MAX_INT_DIGITS})") from None
    except (RecursionError, ValueError) as exc:  # what the checks above should have caught
        raise OrdervibError(f"{where}: not valid JSON ({type(exc).__name__}: {exc})") from None


class _LongInteger(ValueError):
    pass


def _bounded_int(s: str) -> int:
    if len(s.lstrip("-")) > MAX_INT_DIGITS:
        raise _LongInteger(s[:40])
    return int(s)


def _too_deep(text: str) -> int | None:
    """The offset of the first bracket nested deeper than ``MAX_DEPTH``; None if none is."""
    if text.count("[") + text.count("{") <= MAX_DEPTH:
        return None
    depth = 0
    for m in _TOKEN.finditer(text):
        c = m.group()
        if c == "[" or c == "{":
            depth += 1
            if depth > MAX_DEPTH:
                return m.start()
        elif c == "]" or c == "}":
            depth -= 1
    return None


def _place(text: str, at: int) -> str:
    """'line L column C (key 'k')' of offset ``at``: the key is the last one before it."""
    line = text.count("\n", 0, at) + 1
    column = at - (text.rfind("\n", 0, at) + 1) + 1
    keys = _KEY_BEFORE.findall(text, max(0, at - 2000), at)
    return f"line {line} column {column}" + (f" (key {keys[-1]!r})" if keys else "")


def parse_document(text: str, fmt: str, version: int, where: str, kind: str,
                   version_key: str = "version") -> dict[str, Any]:
    """The JSON object in ``text`` whose ``format`` is ``fmt`` and whose ``version_key`` is
    ``version``; else an ``OrdervibError`` "<where>: ..." (``kind`` names the file's kind).

    >>> parse_document('{"format": "f", "version": 1, "x": 2}', "f", 1, "a.json", "test")["x"]
    2
    >>> parse_document('{"format": "g"}', "f", 1, "a.json", "test")
    Traceback (most recent call last):
    node.contract.errors.OrdervibError: a.json: not an ordervib test file
    """
    doc = parse_json(text, where)
    if not isinstance(doc, dict) or doc.get("format") != fmt:
        raise OrdervibError(f"{where}: not an ordervib {kind} file")
    if doc.get(version_key) != version:
        raise OrdervibError(f"{where}: version {doc.get(version_key)!r} is not supported "
                            f"(this ordervib reads {version})")
    return doc


def read_npz(source: bytes | str | os.PathLike, where: str, expected: Callable[[str], bool],
             max_elements: int, max_bytes: int,
             shape_check: Callable[[str, tuple[int, ...]], None] | None = None) -> dict[str, np.ndarray]:
    """The float64 arrays of an npz archive (``np.savez``'s bytes or file), name -> array.

    Before anything is decompressed: every member is a ``<name>.npy`` whose name ``expected``
    accepts, and the sizes the archive declares (``ZipInfo.file_size``) add up to at most
    ``max_bytes``. Before a member's data is read: its ``.npy`` header says float64, at most
    ``max_elements`` elements, ``shape_check(name, shape)`` (if given) raises no ValueError,
    and header plus data are exactly its declared size. Any fault: one ``OrdervibError``
    "<where>: ..." naming the member.
    """
    # a file: regular, and at most the arrays' bound and the archive's own records (those of
    # np.savez are 100 to 200 bytes a member)
    f = io.BytesIO(source) if isinstance(source, bytes) else \
        open_regular(source, where, max_bytes + NPZ_OVERHEAD)
    try:
        return _read_npz(f, where, expected, max_elements, max_bytes, shape_check)
    finally:
        f.close()


def _read_npz(f: io.BufferedIOBase, where: str, expected: Callable[[str], bool],
              max_elements: int, max_bytes: int,
              shape_check: Callable[[str, tuple[int, ...]], None] | None) -> dict[str, np.ndarray]:
    try:
        archive = zipfile.ZipFile(f)
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, ValueError) as exc:
        raise OrdervibError(f"{where}: not an npz archive (truncated or damaged: {exc})") from None
    except OSError as exc:
        raise OrdervibError(f"{where}: cannot be read ({exc.strerror or exc})") from None
    with archive:
        infos = archive.infolist()
        if len(infos) > MAX_NPZ_MEMBERS:
            raise OrdervibError(f"{where}: {len(infos)} members (at most {MAX_NPZ_MEMBERS})")
        names, total = [], 0
        for info in infos:
            name = info.filename.removesuffix(".npy")
            if not info.filename.endswith(".npy") or not expected(name):
                raise OrdervibError(f"{where}: member {info.filename!r} is not one expected here")
            if name in names:
                raise OrdervibError(f"{where}: member {info.filename!r} appears twice")
            names.append(name)
            total += info.file_size
            if total > max_bytes:
                raise OrdervibError(f"{where}: member {info.filename!r}: its arrays declare "
                                    f"{total} bytes or more uncompressed (at most {max_bytes})")
        out = {}
        for name, info in zip(names, infos):
            try:
                out[name] = _read_member(archive, info, max_elements, shape_check)
            except (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError,
                    NotImplementedError) as exc:
                raise OrdervibError(f"{where}: member {info.filename!r}: {exc}") from None
    return out


def _read_member(archive: zipfile.ZipFile, info: zipfile.ZipInfo, max_elements: int,
                 shape_check: Callable[[str, tuple[int, ...]], None] | None) -> np.ndarray:
    with archive.open(info) as f:
        version = np.lib.format.read_magic(f)
        if version == (1, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_1_0(f)
        elif version == (2, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_2_0(f)
        else:
            raise ValueError(f".npy format version {version} is not read here")
        if dtype.kind != "f" or dtype.itemsize != 8 or dtype.fields is not None or dtype.shape:
            raise ValueError(f"dtype {dtype.str} where float64 is expected")
        if not all(isinstance(n, int) and n >= 0 for n in shape):
            raise ValueError(f"shape {shape} is not one of an array")
        n = math.prod(shape)
        if n > max_elements:
            raise ValueError(f"shape {shape} holds {n} elements (at most {max_elements})")
        if shape_check is not None:
            shape_check(info.filename.removesuffix(".npy"), shape)
        size = n * dtype.itemsize
        if f.tell() + size != info.file_size:
            raise ValueError(f"its header declares {size} bytes of data, the archive "
                             f"{info.file_size - f.tell()}")
        flat = np.empty(n, dtype=dtype)
        into, done = flat.view(np.uint8), 0
        while done < size:  # in chunks: no second copy of a large array
            chunk = f.read(min(READ_CHUNK, size - done))
            if not chunk:
                raise ValueError(f"{done} bytes of data where {size} are declared (truncated)")
            into[done:done + len(chunk)] = np.frombuffer(chunk, np.uint8)
            done += len(chunk)
    if dtype != np.float64:  # the other byte order
        flat = flat.astype(np.float64)
    return flat.reshape(shape, order="F" if fortran else "C")
