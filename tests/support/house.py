"""AST scans of the house rules every module of minirt keeps (tests/package/test_house.py runs them on
minirt/ and oracles/, and on small packages a test writes, to show that each can fail).

- ``private_uses``: a name with a leading underscore used from another module -- imported
  (``from minirt.x import _y``), read off an imported module (``x._y``), or read off an object when the
  name is defined in another module and not in this one (``tracer._load(...)``). A seam two files share
  is a public name with a docstring, or the two belong in one file.
- ``long_functions``: functions longer than ``MAX_LINES`` lines without a comment, in the lines just above
  the ``def`` or first in its body, saying why they are one piece (``# one piece: ...``).
"""

from __future__ import annotations

import ast
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

MAX_LINES = 80
ONE_PIECE = "# one piece:"  # the comment that says why a long function is not split


@dataclass(frozen=True)
class Module:
    name: str  # dotted, e.g. minirt.reference.tracer
    path: Path
    rel: str  # as the findings name it, e.g. minirt/reference/tracer.py
    is_package: bool
    tree: ast.Module


def modules(roots: Iterable[tuple[Path, str, str]]) -> list[Module]:
    """Every .py file under each (folder, its package's dotted name, its folder as findings name it)."""
    out = []
    for folder, package, shown in roots:
        for p in sorted(folder.rglob("*.py")):
            parts = list(p.relative_to(folder).with_suffix("").parts)
            is_package = parts[-1] == "__init__"
            if is_package:
                parts = parts[:-1]
            name = ".".join([package, *parts])
            rel = "/".join([shown, *p.relative_to(folder).parts])
            out.append(Module(name, p, rel, is_package, ast.parse(p.read_text(encoding="utf-8"), str(p))))
    return out


def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _absolute(mod: Module, node: ast.ImportFrom) -> str:
    """The module an ``from ... import`` reads, made absolute."""
    if not node.level:
        return node.module or ""
    base = mod.name.split(".")
    if not mod.is_package:
        base = base[:-1]
    base = base[: len(base) - node.level + 1]
    return ".".join(base + ([node.module] if node.module else []))


def _defined(tree: ast.Module) -> set[str]:
    """The private names a module defines for others to see: its top-level functions, classes and
    names, its classes' members, and attributes it sets on objects (``self._x = ...``); not the local
    variables of its functions."""
    out: set[str] = set()

    def targets(body: list[ast.stmt]) -> None:
        for node in body:
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                out.add(node.name)
                if isinstance(node, ast.ClassDef):
                    targets(node.body)
            elif isinstance(node, (ast.Assign, ast.AnnAssign, ast.AugAssign)):
                for t in node.targets if isinstance(node, ast.Assign) else [node.target]:
                    out.update(n.id for n in ast.walk(t) if isinstance(n, ast.Name))
            elif isinstance(node, (ast.Import, ast.ImportFrom)):
                out.update(a.asname for a in node.names if a.asname)
            elif isinstance(node, (ast.If, ast.Try)):
                targets(node.body)

    targets(tree.body)
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
            out.add(node.attr)
    return {n for n in out if _private(n)}


def private_uses(mods: list[Module]) -> set[tuple[str, str]]:
    """(file, name) for every private name a module uses from another module of ``mods``."""
    names = {m.name for m in mods}
    ours = {m.name: _defined(m.tree) for m in mods}
    anywhere = set().union(*ours.values()) if ours else set()
    found: set[tuple[str, str]] = set()
    for m in mods:
        module_aliases: set[str] = set()  # local names bound to one of ``mods``' modules
        for node in ast.walk(m.tree):
            if isinstance(node, ast.ImportFrom):
                src = _absolute(m, node)
                if src not in names and not any(n.startswith(src + ".") for n in names):
                    continue
                for a in node.names:
                    if _private(a.name) and src != m.name:
                        found.add((m.rel, a.name))
                    elif f"{src}.{a.name}" in names:
                        module_aliases.add(a.asname or a.name)
            elif isinstance(node, ast.Import):
                for a in node.names:
                    if a.name in names or any(n.startswith(a.name + ".") for n in names):
                        parts = a.name.split(".")
                        found |= {(m.rel, p) for p in parts if _private(p)}
                        module_aliases.add(a.asname or parts[0])
        own = ours[m.name]
        for node in ast.walk(m.tree):
            if not (isinstance(node, ast.Attribute) and _private(node.attr)):
                continue
            v = node.value
            if isinstance(v, ast.Name) and v.id in ("self", "cls"):
                continue  # the class's own (or its base's) member
            root = v
            while isinstance(root, ast.Attribute):
                root = root.value
            if isinstance(root, ast.Name) and root.id in module_aliases:
                found.add((m.rel, node.attr))  # minirt.x._y, x._y
            elif node.attr in anywhere and node.attr not in own:
                found.add((m.rel, node.attr))  # obj._y, _y defined in another module only
    return found


def _functions(tree: ast.Module) -> Iterator[ast.FunctionDef | ast.AsyncFunctionDef]:
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            yield node


def long_functions(mods: list[Module], max_lines: int = MAX_LINES) -> set[tuple[str, str, int]]:
    """(file, function's qualified-ish name, its lines) for every function longer than ``max_lines``
    (from its ``def`` or first decorator to its last line) without a ``# one piece:`` comment in the
    three lines above its ``def`` or in its body's first three lines."""
    found = set()
    for m in mods:
        lines = m.path.read_text(encoding="utf-8").splitlines()
        for f in _functions(m.tree):
            first = min([f.lineno, *(d.lineno for d in f.decorator_list)])
            length = (f.end_lineno or f.lineno) - first + 1
            if length <= max_lines:
                continue
            body_start = f.body[0].lineno
            if isinstance(f.body[0], ast.Expr) and isinstance(f.body[0].value, ast.Constant):
                body_start = (f.body[0].end_lineno or body_start) + 1  # after the docstring
            near = lines[max(0, first - 4) : first - 1] + lines[body_start - 1 : body_start + 2]
            if not any(ONE_PIECE in line for line in near):
                found.add((m.rel, f.name, length))
    return found
