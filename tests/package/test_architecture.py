"""The shape of the code, kept: rooms of a readable size, each saying exactly what the import-linter
contracts let it import (pyproject.toml; README's diagram drawn from the same contracts), and no
backend's name compared outside its own module and the registry (the contracts themselves are checked
by import-linter, tools/lint-imports.sh, in make test)."""

from __future__ import annotations

import ast
import importlib.util
import re
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


def _layers():
    """tools/layers.py, the contracts' reader (tools/ is not a package: loaded from its file)."""
    spec = importlib.util.spec_from_file_location("layers", ROOT / "tools" / "layers.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


LAYERS = _layers()
CONTRACT_LAYERS, FORBIDDEN = LAYERS.contracts(ROOT / "pyproject.toml")
ROOMS = [r for layer in CONTRACT_LAYERS for r in layer]


def _room_init(room: str) -> Path:
    """A room's __init__.py (minirt.oracles lives in oracles/, pyproject.toml's package-dir)."""
    short = room.removeprefix("minirt.")
    return ROOT / "oracles" / "__init__.py" if short == "oracles" else ROOT / "minirt" / short / "__init__.py"


def _doc(path: Path) -> str:
    return ast.get_docstring(ast.parse(path.read_text())) or ""


def test_every_room_is_in_the_layers():
    """Each subpackage of minirt (and the oracles) is a room the contracts place."""
    packages = {f"minirt.{p.parent.name}" for p in (ROOT / "minirt").glob("*/__init__.py")} | {"minirt.oracles"}
    assert packages <= set(ROOMS), sorted(packages - set(ROOMS))


@pytest.mark.parametrize("room", [r for r in ROOMS if _room_init(r).exists()])
def test_each_room_may_import_exactly_what_the_contracts_allow(room):
    """The room's "May import:" line names what pyproject.toml's contracts allow it, no more, no less, and
    the rest of its paragraph names no other room."""
    doc = _doc(_room_init(room))
    said = LAYERS.may_import(doc, CONTRACT_LAYERS)
    where = _room_init(room).relative_to(ROOT)
    assert said is not None, f"{where}: say what lives here and what it may import (a 'May import:' line)"
    allowed = LAYERS.allowed(room, CONTRACT_LAYERS, FORBIDDEN)
    assert said == allowed, f"{where}: the docstring says more {sorted(said - allowed)}, less {sorted(allowed - said)}"
    paragraph = " ".join(doc[doc.index("May import:") :].split("\n\n")[0].split())
    rest = paragraph[LAYERS.MAY_IMPORT.match(paragraph).end() :]
    assert not re.findall(r"minirt\.\w+", rest), f"{where}: a room named after the list: {rest!r}"


def test_the_docstring_check_can_fail():
    layers = [["minirt.a"], ["minirt.b", "minirt.c"], ["minirt.d"]]
    forbidden = {"minirt.a": {"minirt.c"}}
    assert LAYERS.allowed("minirt.a", layers, forbidden) == {"minirt.b", "minirt.d"}
    assert LAYERS.may_import("Lives here.\n\nMay import: minirt.b and below.", layers) == {
        "minirt.b",
        "minirt.c",
        "minirt.d",
    }
    assert LAYERS.may_import("May import: minirt.b, minirt.d.", layers) == {"minirt.b", "minirt.d"}
    assert LAYERS.may_import("May import: minirt.b and\n  minirt.d -- never the rest.", layers) == {
        "minirt.b",
        "minirt.d",
    }
    assert LAYERS.may_import("Nothing said.", layers) is None
    # a room that says it may import what a forbidden contract excludes is caught
    assert LAYERS.may_import("May import: minirt.b and below.", layers) != LAYERS.allowed("minirt.a", layers, forbidden)


def test_readme_draws_the_layers_the_contracts_declare():
    readme = (ROOT / "README.md").read_text()
    assert LAYERS.readme_block(readme) == LAYERS.diagram(CONTRACT_LAYERS, FORBIDDEN), (
        "README.md's architecture diagram is not the contracts': python tools/layers.py --write"
    )


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
