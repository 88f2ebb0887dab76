"""The house rules an AST can check (tests/support/house.py), on minirt/ and oracles/: no private name
used across modules, no function over 80 lines without a comment saying why it is one piece. Each
scan is shown to fail on a small package written for the purpose."""

from __future__ import annotations

from pathlib import Path

from support.house import MAX_LINES, long_functions, modules, private_uses

ROOT = Path(__file__).resolve().parents[2]
ROOTS = [(ROOT / "minirt", "minirt", "minirt"), (ROOT / "oracles", "minirt.oracles", "oracles")]

# Private names still used across minirt.diagnose's modules, to go as its parts are split by what each
# owns: each entry goes when its seam becomes a public name with a docstring (or the two files one). The
# test fails on an entry no longer found, so the list only shrinks.
PENDING: set[tuple[str, str]] = set()

# Not ours to make public: trimesh's RayMeshIntersector builds its Embree scene lazily, on first use of
# its private cached ``_scene``; reading it times the BVH's build apart from the casting (no public call
# builds it without casting rays).
# (The scan sees it because minirt.sweep.run has a method of that name.)
THIRD_PARTY = {("oracles/embree.py", "_scene")}

# Functions over MAX_LINES not split yet and not saying why they are one piece: none left. The test fails
# on an entry no longer found, so the list only shrinks.
PENDING_LONG: set[tuple[str, str]] = set()

MODULES = modules(ROOTS)


def test_no_private_name_is_used_across_modules():
    found = private_uses(MODULES)
    new = sorted(found - PENDING - THIRD_PARTY)
    assert not new, f"make each seam a public name with a docstring, or merge the two files: {new}"
    gone = sorted((PENDING | THIRD_PARTY) - found)
    assert not gone, f"no longer used across modules: take them off PENDING / THIRD_PARTY: {gone}"


def test_no_function_is_long_without_saying_why():
    found = {(f, name): n for f, name, n in long_functions(MODULES)}
    new = {k: n for k, n in found.items() if k not in PENDING_LONG}
    assert not new, f"over {MAX_LINES} lines: split them, or say '# one piece: why' above the def: {new}"
    gone = sorted(PENDING_LONG - set(found))
    assert not gone, f"no longer long: take them off PENDING_LONG: {gone}"


def _package(tmp_path: Path, files: dict[str, str]) -> list:
    root = tmp_path / "pkg"
    for name, text in files.items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text(text)
    return modules([(root, "pkg", "pkg")])


def test_the_private_scan_can_fail(tmp_path):
    mods = _package(
        tmp_path,
        {
            "__init__.py": "",
            "a.py": (
                "_secret = 1\n\n\nclass Tracer:\n    def _load(self):\n        return self._mine()\n\n"
                "    def _mine(self):\n        return 2\n\n\ndef _helper():\n    local_ = 3\n    _own = 4\n"
                "    return local_ + _own\n"
            ),
            "b.py": (
                "from pkg.a import _secret\nfrom . import a\nfrom .a import Tracer\n\n\n"
                "def f(tr: Tracer):\n    return tr._load(), a._helper(), _secret\n"
            ),
            "c.py": "import pkg.a\n\n\ndef g(x):\n    return pkg.a._secret, x._own, x._replace(), x._load\n",
            "d.py": "from pkg.a import Tracer\n\n\ndef h():\n    return Tracer()\n",
        },
    )
    found = private_uses(mods)
    assert found == {
        ("pkg/b.py", "_secret"),  # imported
        ("pkg/b.py", "_load"),  # a method of another module's class
        ("pkg/b.py", "_helper"),  # read off an imported module
        ("pkg/c.py", "_secret"),  # read off a module imported by its dotted name
        ("pkg/c.py", "_load"),
    }, found  # not: a's own uses, x._own (a local variable elsewhere), x._replace (defined nowhere here)


def test_the_long_function_scan_can_fail(tmp_path):
    body = "".join(f"    x{i} = {i}\n" for i in range(MAX_LINES))
    mods = _package(
        tmp_path,
        {
            "long.py": f"def too_long():\n{body}\n\ndef short():\n    return 1\n",
            "said.py": f"# one piece: a kernel's straight-line code, split only by its comments\ndef kept():\n{body}",
            "inside.py": f'def kept():\n    """Doc."""\n    # one piece: why\n{body}',
            "exact.py": "def fits():\n" + "".join(f"    x{i} = {i}\n" for i in range(MAX_LINES - 1)),
        },
    )
    assert long_functions(mods) == {("pkg/long.py", "too_long", MAX_LINES + 1)}
