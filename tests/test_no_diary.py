"""The repository speaks of the product, not of how it was made: no tracked file outside tests/
names a development session or an issue by number, or a path of a development machine."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DIARY = re.compile(r"sessions? [0-9]+|issues? [0-9]+|issue #", re.IGNORECASE)
# a path of a machine: /work/..., /tmp/..., /root/..., /home/..., /Users/... (not part of a URL
# or of a longer relative path such as out/tmp/)
MACHINE_PATH = re.compile(r"(?<![\w.~/-])/(?:work|tmp|root|home|Users)/")


def findings(text: str) -> list[str]:
    """``line: match`` for every diary number or machine path in ``text``.

    >>> findings("as session 24 measured\\ncd /work/x; see https://e.org/home/a\\nSession.put")
    ['1: session 24', '2: /work/']
    """
    out = []
    for number, line in enumerate(text.splitlines(), 1):
        out += [f"{number}: {m.group(0)}" for m in DIARY.finditer(line)]
        out += [f"{number}: {m.group(0)}" for m in MACHINE_PATH.finditer(line)]
    return out


def tracked_files() -> list[Path]:
    """Every file git tracks outside tests/, text files only (no NUL byte)."""
    try:
        listed = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout")
    files = []
    for name in listed.decode().split("\0"):
        if not name or name.startswith("tests/"):
            continue
        path = ROOT / name
        if path.is_file() and b"\0" not in path.read_bytes():
            files.append(path)
    return files


def test_the_patterns_catch_a_diary_and_a_machine_path() -> None:
    assert findings("issue 35's targets") == ["1: issue 35"]
    assert findings("Issues 30, 31") == ["1: Issues 30"]
    assert findings("python -m bench prom-engine --default /tmp/x") == ["1: /tmp/"]
    assert findings("out/tmp/x, ~/home/y, https://e.org/work/z, Session.put, a session of Zenoh") == []


def test_no_tracked_file_keeps_a_diary_or_a_machine_path() -> None:
    files = tracked_files()
    assert files, "git ls-files listed nothing"
    bad = []
    for path in files:
        text = path.read_text(encoding="utf-8", errors="replace")
        bad += [f"{path.relative_to(ROOT)}:{hit}" for hit in findings(text)]
    assert not bad, "session or issue numbers, or machine paths:\n" + "\n".join(bad)
