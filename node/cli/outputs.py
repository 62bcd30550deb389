"""How every sub-command treats the files it writes: checked first, never an input, replaced only whole.

- ``check_output`` runs before any work: the path has the right suffix, its folder exists,
  it is not a folder (or, for a model, not a file nor a folder of other things), it is
  not one of the command's inputs (``os.path.samefile`` / ``realpath``), and an existing
  file is refused unless the command replaces whole files or ``--force`` was given.
- ``replacing(path)`` gives a temporary name in the same folder; the output appears under
  its name (``os.replace``, atomic) only when the block ends without error, else the
  temporary file is removed and an existing output is left as it was.
- ``replacing_dir(path)`` does the same for a directory (a model bundle).

>>> import tempfile, os
>>> d = tempfile.mkdtemp()
>>> out = os.path.join(d, "a.txt")
>>> with replacing(out) as tmp:
...     _ = open(tmp, "w").write("new")
>>> open(out).read()
'new'
>>> try:
...     with replacing(out) as tmp:
...         _ = open(tmp, "w").write("half")
...         raise OSError("disk full")
... except OSError:
...     pass
>>> open(out).read(), sorted(os.listdir(d))
('new', ['a.txt'])
"""

from __future__ import annotations

import glob
import os
import shutil
from collections.abc import Iterable, Iterator
from contextlib import contextmanager

from node.contract.errors import OrdervibError

MODEL_MARKER = "manifest.json"  # the file that makes a folder a model bundle (node.models.bundle)


def same_file(a: str, b: str) -> bool:
    """Whether two paths name the same file or folder (also through links)."""
    try:
        return os.path.samefile(a, b)
    except OSError:  # one does not exist (yet)
        return os.path.realpath(a) == os.path.realpath(b)


def check_output(path: str, option: str, *, inputs: Iterable[str] = (), suffix: str | None = None,
                 replace: bool = True, force: bool = False) -> None:
    """One-line OrdervibError unless ``path`` may be written (see the module).

    replace: the command writes whole files through ``replacing`` (an existing output may
    be replaced); False: it writes in place, so an existing file needs ``force``.
    """
    if suffix is not None and not path.endswith(suffix):
        raise OrdervibError(f"{option} must name a {suffix} file, got {path!r}")
    if os.path.isdir(path):
        raise OrdervibError(f"{option} is a directory: {path}")
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        raise OrdervibError(f"output directory does not exist: {parent}")
    for src in inputs:
        if same_file(src, path):
            raise OrdervibError(f"{option} {path} must differ from the input {src}: give another name")
    if not (replace or force) and os.path.lexists(path):
        raise OrdervibError(f"{option} {path} exists: give a new name, or --force to overwrite it")


def check_output_dir(path: str, option: str, *, inputs: Iterable[str] = ()) -> None:
    """A model folder to write: new, empty, or a model bundle (replaced whole); never a file."""
    if os.path.lexists(path) and not os.path.isdir(path):
        raise OrdervibError(f"{option} {path} is a file, not a model directory")
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        raise OrdervibError(f"output directory does not exist: {parent}")
    for src in inputs:
        if same_file(src, path) or same_file(os.path.dirname(os.path.abspath(src)), path):
            raise OrdervibError(f"{option} {path} holds an input of this command: give another name")
    if os.path.isdir(path) and os.listdir(path) and not os.path.isfile(os.path.join(path, MODEL_MARKER)):
        raise OrdervibError(f"{option} {path} is a directory that holds no model: "
                            "give a new or empty directory, or a model to replace")


def check_new_files(paths: Iterable[str], option: str, force: bool) -> None:
    """Refuse existing files among ``paths`` (glob patterns) unless ``force``."""
    if force:
        return
    for pattern in paths:
        found = sorted(glob.glob(pattern))
        if found:
            raise OrdervibError(f"{option}: {found[0]} exists: give a new name, or --force to overwrite")


def _temp_name(path: str) -> str:
    head, tail = os.path.split(os.path.abspath(path))
    return os.path.join(head, f".{tail}.{os.getpid()}.part")


def _remove(path: str) -> None:
    if os.path.isdir(path) and not os.path.islink(path):
        shutil.rmtree(path, ignore_errors=True)
    elif os.path.lexists(path):
        os.remove(path)


@contextmanager
def replacing(path: str, overwrite: bool = True) -> Iterator[str]:
    """A temporary file name beside ``path``, renamed to ``path`` if the block succeeds.

    overwrite=False: never replaces a file that appeared at ``path`` meanwhile (a hard link
    that fails if it exists, then the temporary name removed): one-line ``OrdervibError``.
    """
    tmp = _temp_name(path)
    try:
        yield tmp
        if overwrite:
            os.replace(tmp, path)
        else:
            try:
                os.link(tmp, path)
            except FileExistsError:
                raise OrdervibError(f"{path} exists: not overwritten") from None
    finally:
        _remove(tmp)


@contextmanager
def replacing_dir(path: str) -> Iterator[str]:
    """A temporary folder beside ``path``; on success it takes the place of ``path`` (an older
    folder there is moved aside, then deleted). On failure ``path`` is left as it was."""
    path = os.path.normpath(path)
    tmp = _temp_name(path)
    old = tmp + ".old"
    try:
        yield tmp
        if os.path.isdir(path):
            os.replace(path, old)
        os.replace(tmp, path)
    finally:
        if os.path.isdir(old) and not os.path.lexists(path):  # stopped between the two renames
            os.replace(old, path)
        _remove(tmp)
        _remove(old)
