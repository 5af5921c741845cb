"""No product function is longer than 80 lines: a longer one is asking to be split. A
compiled kernel may be exempt, marked by a ``# long-function:`` comment saying why, on the
line above its decorators."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("graft", "learner", "actors", "minecraft", "service")
LIMIT = 80
MARK = "# long-function:"


def _long_functions(source: str) -> list[tuple[str, int]]:
    lines = source.splitlines()
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            length = node.end_lineno - node.lineno + 1  # type: ignore[operator]
            first = min([node.lineno, *(d.lineno for d in node.decorator_list)])
            exempt = first >= 2 and lines[first - 2].strip().startswith(MARK)
            if length > LIMIT and not exempt:
                found.append((node.name, length))
    return found


def test_no_product_function_is_longer_than_80_lines() -> None:
    long = [
        f"{path.relative_to(ROOT)}:{name} ({length} lines)"
        for package in PACKAGES
        for path in sorted((ROOT / package).rglob("*.py"))
        if "_proto" not in path.parts
        for name, length in _long_functions(path.read_text())
    ]
    assert not long, "split these: " + ", ".join(long)


@pytest.mark.parametrize(
    ("source", "expected"),
    [
        ("def f():\n" + "    x = 1\n" * 80, [("f", 81)]),
        ("def f():\n" + "    x = 1\n" * 79, []),
        ("# long-function: a kernel\n@jit\ndef f():\n" + "    x = 1\n" * 90, []),
        ("# a comment\n@jit\ndef f():\n" + "    x = 1\n" * 90, [("f", 91)]),
    ],
)
def test_the_check_counts_lines_and_honours_the_mark(source, expected) -> None:
    assert _long_functions(source) == expected
