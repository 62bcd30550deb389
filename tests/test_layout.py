"""The layout rule import-linter cannot check (tests/ is not a package): tests never import bench.

The benchmarks' reusable pieces live in ``harness/``; ``bench/`` holds only the runners.
"""

from __future__ import annotations

import ast
from pathlib import Path

TESTS = Path(__file__).resolve().parent
FORBIDDEN = "bench"


def _is_forbidden(module: str | None) -> bool:
    return module is not None and (module == FORBIDDEN or module.startswith(FORBIDDEN + "."))


def imported_modules(tree: ast.AST) -> list[tuple[int, str]]:
    """(line, module) of every absolute import, and of ``importlib.import_module`` / ``__import__``
    calls with a literal name, in a parsed file.

    >>> imported_modules(ast.parse("import a.b, c\\nfrom d import e\\nfrom . import f"))
    [(1, 'a.b'), (1, 'c'), (2, 'd')]
    """
    out: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.append((node.lineno, node.module))
        elif (isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant)
              and isinstance(node.args[0].value, str)
              and ((isinstance(node.func, ast.Attribute) and node.func.attr == "import_module")
                   or (isinstance(node.func, ast.Name) and node.func.id in ("import_module", "__import__")))):
            out.append((node.lineno, node.args[0].value))
    return sorted(out)


def test_the_scan_sees_every_form_of_import() -> None:
    src = ("import bench\nimport os, bench.rotor as r\nfrom bench import live\nfrom bench.peers import x\n"
           "def f():\n    import bench.faults\n"
           "importlib.import_module('bench.beam')\n"
           "import benchmark\nfrom harness import rotor\nfrom . import bench\n")
    hits = [line for line, mod in imported_modules(ast.parse(src)) if _is_forbidden(mod)]
    assert hits == [1, 2, 3, 4, 6, 7]


def test_no_test_imports_bench() -> None:
    files = sorted(TESTS.rglob("*.py"))
    assert Path(__file__).resolve() in files
    offenders = [f"{path.relative_to(TESTS.parent)}:{line}: {mod}"
                 for path in files
                 for line, mod in imported_modules(ast.parse(path.read_text(), str(path)))
                 if _is_forbidden(mod)]
    assert not offenders, "tests import bench (use harness/ instead):\n" + "\n".join(offenders)
