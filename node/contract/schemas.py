"""The published JSON Schemas: one file per topic kind, ``<kind>.schema.json``, from ``json_schema``.

The files under ``docs/schemas/`` are these texts, committed; a test compares them with what
the code generates, so the documents and the messages cannot drift apart. Regenerate them with

    python -m node.contract.schemas docs/schemas

The text is stable: keys sorted, two-space indent, UTF-8, a trailing newline.

>>> sorted(schema_texts())[:2]
['health.schema.json', 'monitor.schema.json']
>>> schema_texts()["oc.schema.json"].splitlines()[:2]
['{', '  "description": "``testbed/<bed>/monitor/oc``: one message at each OC or phase switch.",']
"""

from __future__ import annotations

import argparse
import json
import logging
import os
from collections.abc import Sequence
from pathlib import Path

from node.contract.keys import TopicKind
from node.contract.messages import json_schema

SUFFIX = ".schema.json"
log = logging.getLogger(__name__)


def schema_file_name(kind: TopicKind) -> str:
    """The file name of a topic kind's schema.

    >>> schema_file_name(TopicKind.NODE_HEALTH)
    'node-health.schema.json'
    """
    return kind.value + SUFFIX


def schema_text(kind: TopicKind) -> str:
    """A topic kind's JSON Schema as the published text (sorted keys, 2-space indent, newline)."""
    return json.dumps(json_schema(kind), indent=2, sort_keys=True, ensure_ascii=False) + "\n"


def schema_texts() -> dict[str, str]:
    """Every topic kind's schema text, by file name (``TopicKind`` order)."""
    return {schema_file_name(kind): schema_text(kind) for kind in TopicKind}


def write_schemas(folder: str | os.PathLike) -> list[Path]:
    """Write every topic kind's schema into ``folder`` (created if missing); the paths written.

    A file whose text is already the generated one is left untouched.
    """
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, text in schema_texts().items():
        path = out / name
        if not path.is_file() or path.read_text(encoding="utf-8") != text:
            path.write_text(text, encoding="utf-8")
            written.append(path)
    return written


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m node.contract.schemas [FOLDER]``: write the schemas (default docs/schemas)."""
    parser = argparse.ArgumentParser(prog="python -m node.contract.schemas",
                                     description="write the JSON Schema of every topic kind")
    parser.add_argument("folder", nargs="?", default="docs/schemas", help="default docs/schemas")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    written = write_schemas(args.folder)
    log.info("%d of %d schema file(s) written in %s", len(written), len(TopicKind), args.folder)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
