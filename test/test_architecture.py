"""The package's structure: no import circles, no arrow up the layer order (scripts/imports.py,
docs/architecture.md "Layers and imports"), the bench physics in one home, one name per class.

The tool itself is checked on a small package made to break each rule, so that a graph that
lost its late or TYPE_CHECKING imports could not pass here unnoticed.
"""

from __future__ import annotations

import ast
import io
import tokenize
from pathlib import Path

import pytest

from _scripts import load_script

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "bldc_propulsion"


tool = load_script("scripts/imports.py", "imports_tool")


@pytest.fixture(scope="module")
def edges():
    return tool.imports()


def test_every_module_is_in_a_layer():
    assert tool.unplaced() == []


def test_no_import_circles(edges):
    assert tool.circles(edges) == []


def test_no_arrow_runs_up_the_layers_unless_the_architecture_says_why(edges):
    allowed = tool.allowed_arrows()
    up = {(e.source, e.target) for e in tool.upward(edges)}
    assert sorted(up - set(allowed)) == []
    assert sorted(set(allowed) - up) == [], "docs/architecture.md lists an arrow that no longer exists"


def test_physics_sits_below_core_and_training_below_discrepancy():
    assert tool.layer_of("physics.plant") < tool.layer_of("core.estimator")
    assert tool.layer_of("training.fit_physics") < tool.layer_of("discrepancy.physics")


def test_physics_imports_nothing_above_the_shared_modules(edges):
    physics = tool.layer_of("physics.plant")
    assert sorted({e.target for e in edges if e.source.startswith("physics") and tool.layer_of(e.target) >= physics
                   and not e.target.startswith("physics")}) == []


def _write(root: Path, files: dict[str, str]) -> Path:
    for rel, text in files.items():
        path = root / "bldc_propulsion" / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
    return root


def test_the_tool_sees_late_and_type_only_imports(tmp_path):
    """A circle closed by a late import, an arrow up made only for a type, and relative imports
    of a module and of a name: each is found, each with how it was made."""
    root = _write(tmp_path, {
        "__init__.py": "",
        "core/__init__.py": "",
        "core/a.py": "from ..physics import b\n",
        "core/c.py": ("from typing import TYPE_CHECKING\n"
                      "if TYPE_CHECKING:\n    from ..training.t import Thing\n"),
        "physics/__init__.py": "",
        "physics/b.py": "def f():\n    from ..core.a import x  # late\n    return x\n",
        "training/__init__.py": "",
        "training/t.py": "from bldc_propulsion.core import a\n",
    })
    found = tool.imports(root)
    how = {(e.source, e.target): e.how for e in found}
    assert how == {("core.a", "physics.b"): "module", ("core.c", "training.t"): "type",
                   ("physics.b", "core.a"): "late", ("training.t", "core.a"): "module"}
    assert tool.circles(found) == [["core.a", "physics.b"]]
    assert {(e.source, e.target) for e in tool.upward(found)} == {("core.c", "training.t"), ("physics.b", "core.a")}
    assert [e.commented for e in found if e.how == "late"] == [True]


def test_the_architecture_page_lists_arrows_with_their_reasons(tmp_path):
    doc = tmp_path / "architecture.md"
    doc.write_text("# x\n- `a -> b`: not in the section\n### Arrows up the layers\n"
                   "- `core.x -> model`: the reason\nprose\n## next\n- `c -> d`: after it\n", encoding="utf-8")
    assert tool.allowed_arrows(doc) == {("core.x", "model"): "the reason"}


# --- one home ------------------------------------------------------------------------------------
def test_the_old_homes_of_the_physics_are_gone():
    for old in ("plant.py", "core/plant_stream.py", "sim/params.py"):
        assert not (PACKAGE / old).exists(), old


def test_no_two_public_classes_share_a_name():
    homes: dict[str, list[str]] = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ClassDef) and not node.name.startswith("_"):
                homes.setdefault(node.name, []).append(str(path.relative_to(ROOT)))
    assert {name: where for name, where in homes.items() if len(where) > 1} == {}


def test_the_command_scaling_is_written_once():
    """The regressions' centred command and supply (0.075, 0.025, 11.5) as numbers in code only in
    physics/scales.py (words and docstrings may say them)."""
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if path == PACKAGE / "physics" / "scales.py":
            continue
        tokens = tokenize.generate_tokens(io.StringIO(path.read_text(encoding="utf-8")).readline)
        found += [f"{path.relative_to(ROOT)}:{tok.start[0]} {tok.string}" for tok in tokens
                  if tok.type == tokenize.NUMBER and ast.literal_eval(tok.string) in (0.075, 0.025, 11.5)]
    assert found == []
