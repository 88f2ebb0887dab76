"""The bundled scenes: found by name (``exercise``) as well as by path, from any working folder.

They ship as the package data ``minirt.scene_files`` (the repository's scenes/ folder, mapped in
pyproject.toml) and are read through importlib.resources, which finds them in a wheel's install and in
the editable install of a checkout alike. scenes/samples/ holds the sample student image that
`make demo` grades.
"""

from __future__ import annotations

from collections.abc import Mapping
from importlib.resources import files
from os import PathLike
from pathlib import Path
from typing import Any

from minirt.errors import SceneError
from minirt.model.rules import Rules, resolve
from minirt.model.scene import Scene, load_scene

# A folder on disk in both installs (minirt is never imported from a zip: Dr.Jit and Mitsuba are not).
BUNDLED = Path(str(files("minirt.scene_files")))
SAMPLES = BUNDLED / "samples"


def names() -> list[str]:
    """The bundled scenes' names (their file stems), sorted."""
    return sorted(p.stem for p in BUNDLED.glob("*.toml"))


def find_scene(arg: str | Path) -> Path:
    """A scene file's path: the path itself if it exists (a path wins over a name), else the bundled
    scene of that name. Something that looks like a path (a .toml suffix, a slash) is returned as it
    is, for load_scene to say it does not exist; an unknown name raises SceneError naming the bundled
    scenes."""
    p = Path(arg)
    if p.exists() or p.suffix == ".toml" or "/" in str(arg):
        return p
    q = BUNDLED / f"{arg}.toml"
    if q.is_file():
        return q
    raise SceneError(f"{arg}: no such scene file, nor a bundled scene (bundled: {', '.join(names())})")


def bundled_scene(name: str) -> Scene:
    return load_scene(find_scene(name))


def scene_and_rules(
    scene: Scene | str | PathLike[str],
    width: int | None = None,
    height: int | None = None,
    samples: int | None = None,
    profile: str | None = None,
    rules: Mapping[str, Any] | None = None,
) -> tuple[Scene, Rules]:
    """The one way a scene is made ready to render: read (a file, or a bundled scene's name, unless
    already a ``Scene``), the overrides applied (as `minirt render`'s --width, --height, --samples and
    --profile, within the scene file's limits) and the rules it renders under resolved (the profile, the
    scene's [model], then ``rules``, as --rule NAME=VALUE gives them). Raises SceneError or MinirtError,
    one line per problem."""
    s = scene if isinstance(scene, Scene) else load_scene(find_scene(scene))
    s = s.with_overrides(width=width, height=height, samples=samples, profile=profile)
    return s, resolve(s, profile, dict(rules or {}))
