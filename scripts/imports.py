#!/usr/bin/env python3
"""The package's import graph: circles, and arrows that run up the layer order.

    python scripts/imports.py            # figures, every circle and upward arrow; exit 1 if any
    python scripts/imports.py --late     # also every import made inside a function

Every import of a ``bldc_propulsion`` module counts: at module level, inside a function (a late
import defers a dependency, it does not remove it), and under ``if TYPE_CHECKING:`` (a type is a
dependency too). The files are read with ``ast``; nothing is imported. A module belongs to the
layer of its top-level name (``core.features`` to ``core``), see ``LAYERS``; an import may go to
its own layer or below. An arrow that must go up is listed in docs/architecture.md under
"Arrows up the layers" as ``- `FROM -> TO`: reason`` (test/test_architecture.py reads it).
"""

from __future__ import annotations

import argparse
import ast
import re
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "bldc_propulsion"
#: Bottom to top: a module may import its own layer and the layers below it. Names are the first
#: component below the package (a module or a subpackage); ``""`` is the package's __init__.
LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    # shared leaves: errors, the contract, names of recordings, the output rule, the user's priors
    ("base", ("", "errors", "contract", "specs", "atomic", "priors", "quiet_start", "runs")),
    ("physics", ("physics",)),  # the bench physics: equations, CONFIG, model-file form, fits
    ("core", ("core",)),  # the nodes' decisions, ROS-free
    # recordings, model files, the simulator, and the stamped outputs replay writes through bagio
    ("data", ("bagio", "recordings", "model", "sim", "stamped_writer")),
    ("training", ("training", "flightlogs")),  # flight-log import writes bags as import_csv does
    ("discrepancy", ("discrepancy",)),
    # the commands, replay (the nodes' cores over a recording, with the nodes' parameter names)
    # and the rclpy adapters themselves
    ("commands", ("commands", "replay", "info", "nodes")),
    ("top", ("cli",)),
)
#: Where docs/architecture.md lists the arrows allowed to go up (one per line).
ALLOWED_HEADING = "Arrows up the layers"
_ALLOWED_LINE = re.compile(r"^- `([\w.]+) -> ([\w.]+)`: \S")


@dataclass(frozen=True)
class Import:
    """One import statement's dependency of ``source`` on ``target`` (module names below the
    package: ``core.features``)."""

    source: str
    target: str
    line: int
    how: str  #: "module" (at import time), "late" (inside a function), "type" (TYPE_CHECKING only)
    commented: bool  #: a comment on its line or the line above says why (for late imports)


def module_name(path: Path, root: Path = ROOT) -> str:
    """``core.features`` for bldc_propulsion/core/features.py, ``core`` for its __init__.py."""
    parts = list(path.relative_to(root / PACKAGE).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _modules(root: Path) -> dict[str, Path]:
    return {module_name(p, root): p for p in sorted((root / PACKAGE).rglob("*.py"))}


def _commented(lines: list[str], line: int) -> bool:
    """A comment on the import's line, or above the run of imports it belongs to."""
    if "#" in lines[line - 1]:
        return True
    k = line - 2
    while k >= 0 and lines[k].strip().startswith(("from ", "import ")):
        if "#" in lines[k]:
            return True
        k -= 1
    return k >= 0 and lines[k].strip().startswith("#")


def _type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _walk(node: ast.AST, how: str) -> Iterator[tuple[ast.AST, str]]:
    """Every import node below ``node`` with how it is made."""
    for child in ast.iter_child_nodes(node):
        if isinstance(child, (ast.Import, ast.ImportFrom)):
            yield child, how
        elif isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            yield from _walk(child, "late")
        elif isinstance(child, ast.If) and _type_checking(child) and how == "module":
            for stmt in child.body:
                yield from _walk(ast.Module(body=[stmt], type_ignores=[]), "type")
            for stmt in child.orelse:
                yield from _walk(ast.Module(body=[stmt], type_ignores=[]), how)
        else:
            yield from _walk(child, how)


def _resolve(source: str, is_package: bool, node: ast.ImportFrom) -> str | None:
    """The module ``from ... import`` names (package-relative), None outside the package."""
    if node.level == 0:
        mod = node.module or ""
        if mod != PACKAGE and not mod.startswith(PACKAGE + "."):
            return None
        return mod[len(PACKAGE) + 1:]
    base = source.split(".") if source else []
    if not is_package:
        base = base[:-1]
    up = node.level - 1
    if up > len(base):
        return None
    base = base[:len(base) - up] if up else base
    return ".".join([*base, *(node.module.split(".") if node.module else [])])


def imports(root: Path = ROOT) -> list[Import]:
    """Every intra-package import of the package under ``root``."""
    modules = _modules(root)
    out = []
    for source, path in modules.items():
        text = path.read_text(encoding="utf-8")
        lines = text.splitlines()
        is_package = path.name == "__init__.py"

        def commented(line: int, lines: list[str] = lines) -> bool:
            return _commented(lines, line)

        for node, how in _walk(ast.parse(text, str(path)), "module"):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [a.name[len(PACKAGE) + 1:] for a in node.names if a.name.startswith(PACKAGE + ".")]
            elif isinstance(node, ast.ImportFrom):
                mod = _resolve(source, is_package, node)
                if mod is None:
                    continue
                for alias in node.names:
                    sub = f"{mod}.{alias.name}" if mod else alias.name
                    targets.append(sub if sub in modules else mod)
            for target in dict.fromkeys(targets):
                if target != source:
                    out.append(Import(source, target, node.lineno, how, commented(node.lineno)))
    return out


def third_party_late(root: Path = ROOT) -> list[tuple[str, int, str, bool]]:
    """(module, line, imported name, commented) of every import of another distribution made
    inside a function: allowed for start-up time, with a comment that says so."""
    out = []
    for source, path in _modules(root).items():
        text = path.read_text(encoding="utf-8")
        lines = text.splitlines()
        for node, how in _walk(ast.parse(text, str(path)), "module"):
            if how != "late":
                continue
            if isinstance(node, ast.ImportFrom):
                if node.level or (node.module or "").split(".")[0] == PACKAGE:
                    continue
                name = node.module or ""
            else:
                names = [a.name for a in node.names if a.name.split(".")[0] != PACKAGE]
                if not names:
                    continue
                name = names[0]
            out.append((source, node.lineno, name, _commented(lines, node.lineno)))
    return out


def layer_of(module: str) -> int:
    """Index of the layer ``module`` belongs to (ValueError for a module no layer names)."""
    top = module.split(".")[0]
    for i, (_, names) in enumerate(LAYERS):
        if top in names:
            return i
    raise ValueError(f"{module}: in no layer of scripts/imports.py LAYERS")


def unplaced(root: Path = ROOT) -> list[str]:
    """Modules that no layer names."""
    out = []
    for m in _modules(root):
        try:
            layer_of(m)
        except ValueError:
            out.append(m)
    return out


def upward(edges: list[Import]) -> list[Import]:
    """Imports of a module in a higher layer than the importer's."""
    return [e for e in edges if layer_of(e.target) > layer_of(e.source)]


def circles(edges: list[Import]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    graph: dict[str, set[str]] = {}
    for e in edges:
        graph.setdefault(e.source, set()).add(e.target)
        graph.setdefault(e.target, set())
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10 * len(graph) + 100))
    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(found)


def allowed_arrows(doc: Path = ROOT / "docs" / "architecture.md") -> dict[tuple[str, str], str]:
    """The upward arrows docs/architecture.md allows, with their reasons: the list items
    ``- `FROM -> TO`: reason`` of the section headed ALLOWED_HEADING."""
    out: dict[tuple[str, str], str] = {}
    inside = False
    for line in doc.read_text(encoding="utf-8").splitlines():
        if line.startswith("#"):
            inside = line.lstrip("#").strip().startswith(ALLOWED_HEADING)
            continue
        m = _ALLOWED_LINE.match(line) if inside else None
        if m:
            out[(m.group(1), m.group(2))] = line.split(": ", 1)[1]
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--late", action="store_true", help="list every import made inside a function")
    args = ap.parse_args(argv)
    edges = imports()
    missing = unplaced()
    if missing:
        print(f"modules in no layer: {', '.join(missing)}")
        return 1
    allowed = allowed_arrows()
    up = upward(edges)
    unexplained = [e for e in up if (e.source, e.target) not in allowed]
    rings = circles(edges)
    late = [e for e in edges if e.how == "late"]
    third = third_party_late()
    pairs = {(e.source, e.target) for e in edges}
    print(f"{len(_modules(ROOT))} modules, {len(pairs)} arrows ({len(edges)} imports: "
          f"{sum(e.how == 'module' for e in edges)} at module level, {len(late)} late, "
          f"{sum(e.how == 'type' for e in edges)} for types only)")
    print(f"layers, bottom up: {' < '.join(name for name, _ in LAYERS)}")
    print(f"circles: {len(rings)}")
    for ring in rings:
        print(f"  {' <-> '.join(ring)}")
    print(f"arrows up the layers: {len(up)} ({len(up) - len(unexplained)} explained in docs/architecture.md)")
    for e in up:
        why = allowed.get((e.source, e.target))
        print(f"  {e.source} -> {e.target} ({e.how}, line {e.line})" + (f": {why}" if why else ": NOT EXPLAINED"))
    print(f"late imports: {len(late)} of this package's modules, {len(third)} of other distributions "
          f"({sum(not c for *_, c in third)} without a comment)")
    if args.late:
        for e in late:
            print(f"  {e.source}:{e.line} -> {e.target}" + ("" if e.commented else " (no comment)"))
        for source, line, name, c in third:
            print(f"  {source}:{line} -> {name}" + ("" if c else " (no comment)"))
    return 1 if rings or unexplained else 0


if __name__ == "__main__":
    sys.exit(main())
