"""minirt's declared layers, read from pyproject.toml's import-linter contracts: what each room may import.

    python tools/layers.py           print README's architecture diagram, drawn from the contracts
    python tools/layers.py --write   write it into README.md, between its two marker lines
    python tools/layers.py --check   exit 1 if README.md's diagram is not the one the contracts draw

A room may import every room on a layer below its own (the "layers" contract), less the rooms a
"forbidden" contract names for it. tests/package/test_architecture.py compares each room's "May
import:" line with this, and README's diagram with ``diagram()``.
"""

from __future__ import annotations

import re
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BEGIN = "<!-- layers: drawn from pyproject.toml by tools/layers.py --write; make test checks it -->"
END = "<!-- end of layers -->"


def contracts(pyproject: Path = ROOT / "pyproject.toml") -> tuple[list[list[str]], dict[str, set[str]]]:
    """(the layers, top first, each a list of independent rooms; the rooms each room is forbidden)."""
    data = tomllib.loads(pyproject.read_text(encoding="utf-8"))["tool"]["importlinter"]["contracts"]
    layers = [[r.strip() for r in layer.split("|")] for c in data if c["type"] == "layers" for layer in c["layers"]]
    forbidden: dict[str, set[str]] = {}
    for c in data:
        if c["type"] == "forbidden":
            for src in c["source_modules"]:
                forbidden.setdefault(src, set()).update(c["forbidden_modules"])
    return layers, forbidden


def layer_of(layers: list[list[str]], room: str) -> int:
    return next(i for i, layer in enumerate(layers) if room in layer)


def allowed(room: str, layers: list[list[str]], forbidden: dict[str, set[str]]) -> set[str]:
    """What the contracts let ``room`` import: the rooms on every layer below its own, less its forbidden."""
    below = {r for layer in layers[layer_of(layers, room) + 1 :] for r in layer}
    return below - forbidden.get(room, set())


MAY_IMPORT = re.compile(
    r"May import:\s*(?P<names>minirt\.\w+(?:(?:\s*,\s*(?:and\s+)?|\s+and\s+)minirt\.\w+)*)(?P<below>\s+and\s+below)?"
)


def may_import(doc: str, layers: list[list[str]]) -> set[str] | None:
    """The rooms a docstring's "May import:" line names (None: it has none). The line lists rooms by their
    dotted names; "NAME and below" at its end adds NAME's layer (the rooms beside NAME too) and every layer
    under it."""
    m = MAY_IMPORT.search(" ".join(doc.split()))
    if not m:
        return None
    names = re.findall(r"minirt\.\w+", m.group("names"))
    out = set(names)
    if m.group("below"):
        out |= {r for layer in layers[layer_of(layers, names[-1]) :] for r in layer}
    return out


def diagram(layers: list[list[str]], forbidden: dict[str, set[str]]) -> str:
    """README's architecture diagram: the layers, top to bottom, and the forbidden imports beside them."""
    short = {r: r.removeprefix("minirt.") for layer in layers for r in layer}
    lines = ["```", *(" | ".join(short[r] for r in layer) for layer in layers), "```", ""]
    lines.append("Each room may import the rooms on every line below its own, never one above; rooms on one line")
    lines.append("(`|`) are independent of each other. Beyond the layers:")
    lines.append("")
    for src in sorted(forbidden, key=lambda r: (layer_of(layers, r), r)):
        names = sorted(forbidden[src], key=lambda r: (layer_of(layers, r), r))
        lines.append(f"- `{short[src]}` never imports {', '.join(f'`{short[n]}`' for n in names)}")
    return "\n".join(lines)


def readme_block(readme: str) -> str:
    """README's text between the two marker lines."""
    a, b = readme.index(BEGIN) + len(BEGIN), readme.index(END)
    return readme[a:b].strip("\n")


def main(argv: list[str]) -> int:
    text = diagram(*contracts())
    readme = ROOT / "README.md"
    if argv[1:] == ["--write"]:
        old = readme.read_text(encoding="utf-8")
        a, b = old.index(BEGIN) + len(BEGIN), old.index(END)
        readme.write_text(old[:a] + "\n" + text + "\n" + old[b:], encoding="utf-8")
    elif argv[1:] == ["--check"]:
        if readme_block(readme.read_text(encoding="utf-8")) != text:
            print("README.md: the architecture diagram is not the contracts' (python tools/layers.py --write)")
            return 1
    elif argv[1:]:
        print("usage: python tools/layers.py [--write | --check]", file=sys.stderr)
        return 2
    else:
        print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
