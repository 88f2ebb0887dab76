"""The shape of the code, kept: rooms of a readable size, each saying what it may import, and no
backend's name compared outside its own module and the registry (the layers themselves are checked by
import-linter, tools/lint-imports.sh, in make test)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from minirt.harness import backends

ROOT = Path(__file__).resolve().parents[2]
SOURCES = sorted([*(ROOT / "minirt").rglob("*.py"), *(ROOT / "oracles").rglob("*.py")])
MAX_LINES = 800  # a file longer than this mixes concerns (the architecture issue measured 960-1,650)
MAX_TOP_LEVEL_MODULES = 15  # minirt/ holds subpackages; its own modules are the API and the package's glue
REGISTRY_FILE = ROOT / "minirt" / "harness" / "backends.py"  # the one place that may know names


def test_no_file_is_a_pile():
    long = {str(p.relative_to(ROOT)): n for p in SOURCES if (n := len(p.read_text().splitlines())) > MAX_LINES}
    assert not long, long


def test_the_package_is_rooms_not_a_pile():
    top = sorted(p.name for p in (ROOT / "minirt").glob("*.py"))
    assert len(top) <= MAX_TOP_LEVEL_MODULES, top


@pytest.mark.parametrize("package", sorted(p.parent.name for p in (ROOT / "minirt").glob("*/__init__.py")))
def test_each_room_says_what_lives_there_and_what_it_may_import(package):
    doc = ast.get_docstring(ast.parse((ROOT / "minirt" / package / "__init__.py").read_text())) or ""
    assert "May import" in doc, f"minirt/{package}/__init__.py: say what lives here and what it may import"


def _compared_names(tree: ast.AST, names: set[str]) -> list[tuple[int, str]]:
    """(line, name) of every comparison (==, !=, in, not in) with a backend's name as a string literal."""
    found = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Compare):
            continue
        for side in (node.left, *node.comparators):
            consts = side.elts if isinstance(side, ast.Tuple | ast.List | ast.Set) else [side]
            for c in consts:
                if isinstance(c, ast.Constant) and c.value in names:
                    found.append((node.lineno, c.value))
    return found


def test_nothing_outside_a_backend_compares_its_name():
    names = set(backends.all_names())
    found = {
        f"{p.relative_to(ROOT)}:{line}": name
        for p in SOURCES
        if p != REGISTRY_FILE and "oracles" not in p.relative_to(ROOT).parts[:1]
        for line, name in _compared_names(ast.parse(p.read_text()), names)
    }
    assert not found, f"ask the backend (minirt.model.backend.Backend), not its name: {found}"


def test_the_name_check_can_fail():
    code = 'if name == "mitsuba":\n    pass\nok = backend in ("povray", "x")\n'
    assert _compared_names(ast.parse(code), {"mitsuba", "povray"}) == [(1, "mitsuba"), (3, "povray")]
