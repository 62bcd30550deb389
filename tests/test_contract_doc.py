"""The contract in the repository holds together with the code: the committed JSON Schemas
(docs/schemas/) are what ``node.contract`` generates, and docs/contract.md names every topic kind
and every field of every schema."""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from node.contract import Refused, TopicKind, json_schema
from node.contract.schemas import main, schema_file_name, schema_texts, write_schemas

ROOT = Path(__file__).resolve().parents[1]
SCHEMAS = ROOT / "docs" / "schemas"
CONTRACT = ROOT / "docs" / "contract.md"
REGENERATE = "python -m node.contract.schemas docs/schemas"


def fields(schema: dict[str, Any]) -> Iterator[str]:
    """Every property name of a schema, those of nested objects (list items, objects) too.

    >>> sorted(fields({"properties": {"a": {}, "b": {"items": {"properties": {"c": {}}}}}}))
    ['a', 'b', 'c']
    """
    for name, sub in schema.get("properties", {}).items():
        yield name
        yield from fields(sub)
    for key in ("items", "additionalProperties"):
        if isinstance(schema.get(key), dict):
            yield from fields(schema[key])


def test_every_topic_kind_has_a_committed_schema_file() -> None:
    committed = sorted(p.name for p in SCHEMAS.glob("*.schema.json"))
    assert committed == sorted(schema_texts()), f"docs/schemas/ is stale: run {REGENERATE}"


@pytest.mark.parametrize("kind", list(TopicKind), ids=str)
def test_the_committed_schema_is_what_the_code_generates(kind: TopicKind) -> None:
    name = schema_file_name(kind)
    path = SCHEMAS / name
    assert path.is_file(), f"docs/schemas/{name} is missing: run {REGENERATE}"
    assert path.read_text(encoding="utf-8") == schema_texts()[name], \
        f"docs/schemas/{name} differs from node.contract's messages: run {REGENERATE}"


def test_the_generator_writes_only_what_changed(tmp_path: Path) -> None:
    assert main([str(tmp_path / "s")]) == 0
    assert sorted(p.name for p in (tmp_path / "s").iterdir()) == sorted(schema_texts())
    assert write_schemas(tmp_path / "s") == []
    (tmp_path / "s" / "oc.schema.json").write_text("{}\n", encoding="utf-8")
    assert write_schemas(tmp_path / "s") == [tmp_path / "s" / "oc.schema.json"]


def test_the_contract_names_every_topic_kind() -> None:
    text = CONTRACT.read_text(encoding="utf-8")
    missing = [kind.value for kind in TopicKind if f"`{kind.value}`" not in text]
    assert not missing, f"docs/contract.md does not name the topic kind(s) {missing}"
    linked = [schema_file_name(kind) for kind in TopicKind
              if f"schemas/{schema_file_name(kind)}" not in text]
    assert not linked, f"docs/contract.md does not link the schema file(s) {linked}"


@pytest.mark.parametrize("kind", [k for k in TopicKind if json_schema(k).get("properties")], ids=str)
def test_the_contract_names_every_field_of_the_schema(kind: TopicKind) -> None:
    text = CONTRACT.read_text(encoding="utf-8")
    missing = sorted({f for f in fields(json_schema(kind)) if not re.search(rf"`{re.escape(f)}`", text)})
    assert not missing, f"docs/contract.md does not name the {kind.value} field(s) {missing}"


def test_the_contract_names_every_enumerated_value() -> None:
    """Flags, reasons, phases and refusal reasons: each value the schemas list is in the contract."""
    text = CONTRACT.read_text(encoding="utf-8")
    values: set[str] = set()

    def walk(node: Any) -> None:
        if isinstance(node, dict):
            values.update(v for v in node.get("enum", []) if isinstance(v, str))
            for sub in node.values():
                walk(sub)

    for kind in TopicKind:
        walk(json_schema(kind))
    values.update(r.value for r in Refused)  # the keys of a health message's refused
    missing = sorted(v for v in values if f"`{v}`" not in text)
    assert not missing, f"docs/contract.md does not name the value(s) {missing}"


def test_a_limit_table_is_read_and_kept_as_the_contract_says(tmp_path: Path) -> None:
    """docs/contract.md section 4: [[limit]] tables are read, checked and kept in the bundle's schedule."""
    from node.contract import load_schedule

    plain = 'switch = "nB"\ntolerance = 0.02\n[[oc]]\nname = "OC3"\nspeed = 4700.0\n'
    limit = '[[limit]]\ntarget = "yB"\nmax = 12.0\nfrom_speed = 7000.0\nto_speed = 9900.0\n'
    (tmp_path / "plain.toml").write_text(plain, encoding="utf-8")
    (tmp_path / "limit.toml").write_text(plain + limit, encoding="utf-8")
    with_limit = load_schedule(tmp_path / "limit.toml")
    assert with_limit != load_schedule(tmp_path / "plain.toml")
    assert with_limit.to_dict()["limit"] == [{"target": "yB", "max": 12.0, "from_speed": 7000.0,
                                              "to_speed": 9900.0}]
    assert "Not yet in ordervib 0.1.0:** the schedule parser" not in CONTRACT.read_text(encoding="utf-8")
