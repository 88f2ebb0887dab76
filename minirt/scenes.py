"""The bundled scenes: found by name (``exercise``) as well as by path, from any working folder."""

from __future__ import annotations

from pathlib import Path

from minirt.errors import SceneError
from minirt.scene import Scene, load_scene

# The scenes that ship with minirt (the repository's scenes/ folder, beside the package).
BUNDLED = Path(__file__).resolve().parent.parent / "scenes"


def names() -> list[str]:
    return sorted(p.stem for p in BUNDLED.glob("*.toml"))


def find_scene(arg: str | Path) -> Path:
    """A scene file's path: the path itself if it exists, else the bundled scene of that name."""
    p = Path(arg)
    if p.exists() or p.suffix == ".toml" or "/" in str(arg):
        return p
    q = BUNDLED / f"{arg}.toml"
    if q.is_file():
        return q
    raise SceneError(f"{arg}: no such scene file, nor a bundled scene (bundled: {', '.join(names())})")


def bundled_scene(name: str) -> Scene:
    return load_scene(find_scene(name))
