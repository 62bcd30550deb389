"""The documentation holds together in a clone (issue 34 item 7): every relative link of README.md,
CHANGELOG.md and docs/**/*.md names a file of the repository, and the README stays short."""

from __future__ import annotations

import re
from pathlib import Path
from urllib.parse import unquote

import pytest

ROOT = Path(__file__).resolve().parents[1]
README_MAX_LINES = 250
# [text](target) or ![alt](target "title"); the text may hold `code` but no brackets
LINK = re.compile(r"\[[^\[\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
FENCE = re.compile(r"^\s*(```|~~~)")
EXTERNAL = ("http://", "https://", "mailto:")


def markdown_files() -> list[Path]:
    return [ROOT / "README.md", ROOT / "CHANGELOG.md", *sorted((ROOT / "docs").rglob("*.md"))]


def links(text: str) -> list[tuple[int, str]]:
    """(line, target) of every Markdown link outside fenced code blocks.

    >>> links("see [a](a.md), ![b](img/b.png \\"t\\") and [`c`](../c.md#x)\\n```\\n[no](x.md)\\n```\\n")
    [(1, 'a.md'), (1, 'img/b.png'), (1, '../c.md#x')]
    """
    out: list[tuple[int, str]] = []
    fenced = False
    for number, line in enumerate(text.splitlines(), 1):
        if FENCE.match(line):
            fenced = not fenced
            continue
        if not fenced:
            out += [(number, m.group(1)) for m in LINK.finditer(line)]
    return out


def local_target(source: Path, target: str) -> Path | None:
    """The file a relative link names, or None for a web address, a mail address or an anchor."""
    if target.startswith(EXTERNAL) or target.startswith("#"):
        return None
    return (source.parent / unquote(target.split("#", 1)[0])).resolve()


def test_the_files_are_there() -> None:
    files = markdown_files()
    assert all(f.is_file() for f in files[:2]), files[:2]
    assert len(files) > 2


def test_the_link_parser_sees_links_and_skips_code() -> None:
    text = "[x](y.md) [web](https://e.org) [top](#a)\n```bash\n[z](missing.md)\n```\n"
    source = ROOT / "README.md"
    targets = [local_target(source, t) for _, t in links(text)]
    assert targets == [ROOT / "y.md", None, None]


@pytest.mark.parametrize("path", markdown_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_names_a_file_of_the_repository(path: Path) -> None:
    bad = []
    for line, target in links(path.read_text(encoding="utf-8")):
        resolved = local_target(path, target)
        if resolved is None:
            continue
        if not resolved.is_relative_to(ROOT):
            bad.append(f"{line}: {target} (outside the repository)")
        elif not resolved.exists():
            bad.append(f"{line}: {target} (no such file)")
    assert not bad, f"{path.relative_to(ROOT)}:\n" + "\n".join(bad)


def test_the_readme_is_short() -> None:
    lines = (ROOT / "README.md").read_text(encoding="utf-8").splitlines()
    assert len(lines) <= README_MAX_LINES, f"README.md has {len(lines)} lines (at most {README_MAX_LINES})"
