"""The package's code shape: no function (or method) under bldc_propulsion/ longer than
MAX_FUNCTION_LINES, so that each reads in one sitting.

Length is counted as ast gives it, ``end_lineno - lineno + 1`` from the ``def`` line (decorators
excluded) to the function's last line, docstring and nested functions included.
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "bldc_propulsion"
MAX_FUNCTION_LINES = 80


def function_lengths(source: str) -> list[tuple[str, int, int]]:
    """(qualified name, first line, length in lines) of every function and method in ``source``."""
    out: list[tuple[str, int, int]] = []

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef):
                assert child.end_lineno is not None
                out.append((prefix + child.name, child.lineno, child.end_lineno - child.lineno + 1))
                visit(child, f"{prefix}{child.name}.")
            elif isinstance(child, ast.ClassDef):
                visit(child, f"{prefix}{child.name}.")
            else:
                visit(child, prefix)

    visit(ast.parse(source), "")
    return out


def test_the_count_is_from_the_def_line_to_the_last_line_without_decorators():
    source = ("import functools\n"
              "\n"
              "@functools.cache\n"
              "def outer(x):\n"
              '    """Doc."""\n'
              "    def inner(y):\n"
              "        return y\n"
              "\n"
              "    return inner(x)\n"
              "\n"
              "class K:\n"
              "    @property\n"
              "    def p(self):\n"
              "        return 1\n")
    assert function_lengths(source) == [("outer", 4, 6), ("outer.inner", 6, 2), ("K.p", 13, 2)]


def test_no_function_in_the_package_is_longer_than_the_limit():
    files = sorted(PACKAGE.rglob("*.py"))
    assert len(files) > 50, f"found only {len(files)} modules under {PACKAGE}"
    offenders = [f"{path.relative_to(PACKAGE.parent)}:{line} {name}: {length} lines"
                 for path in files
                 for name, line, length in function_lengths(path.read_text(encoding="utf-8"))
                 if length > MAX_FUNCTION_LINES]
    assert not offenders, (f"{len(offenders)} function(s) over {MAX_FUNCTION_LINES} lines (split them into "
                           "well-named helpers):\n" + "\n".join(offenders))
