"""Small scenes for tests, as scene-file text: one writer for the camera, the light, the materials, the balls
and the planes that test modules used to spell out line by line, each in its own copy.

``scene_text`` writes the tables the way those copies were written by hand -- a leading newline, the tables
in the file's order, one key a line, no blank line between them -- so the text is the same, byte for byte, as
the literal it replaced, and a test that edits it (``text.replace(old, new)``, a line number in an error
message) finds what it expects. ``ball`` and ``plane`` are one ``[[shapes]]`` table each, to pass to
``scene_text`` or to add to a scene's text. Numbers are written as minirt.campaign.families.dump_toml writes
them, with ``repr``: they read back bit for bit.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

from minirt.campaign.families import dump_toml

Colour = float | tuple[float, float, float]  # a float: that grey, (v, v, v)


def _colour(c: Colour) -> tuple[float, float, float]:
    return (c, c, c) if isinstance(c, int | float) else tuple(c)


def material(
    diffuse: Colour, ambient: Colour | None = None, specular: Colour | None = None, reflection: Colour | None = None
) -> dict[str, tuple[float, float, float]]:
    """One ``[materials.NAME]`` table: the colours given, in the scene file's order."""
    given = {"ambient": ambient, "diffuse": diffuse, "specular": specular, "reflection": reflection}
    return {k: _colour(c) for k, c in given.items() if c is not None}


MATTE = material(0.5)  # the material "m" of a scene that says nothing else
SHINY = material((0.6, 0.5, 0.4), ambient=0.1, specular=0.3, reflection=0.2)  # every term, reflections too


def _floats(v: Iterable[float]) -> list[float]:
    return [float(x) for x in v]


def ball(center: Iterable[float], radius: float, material: str = "m") -> str:
    """One ball's ``[[shapes]]`` table."""
    shape = {"type": "ball", "center": _floats(center), "radius": float(radius), "material": material}
    return dump_toml({"shapes": [shape]})


def plane(normal: Iterable[float], distance: float, material: str = "m") -> str:
    """One plane's ``[[shapes]]`` table."""
    shape = {"type": "plane", "normal": _floats(normal), "distance": float(distance), "material": material}
    return dump_toml({"shapes": [shape]})


def scene_text(
    *shapes: str,
    distance: float = 2.0,
    size: int | tuple[int, int] | None = None,
    light: Iterable[float] = (10.0, 10.0, -1.0),
    color: Iterable[float] | None = None,
    render: dict[str, Any] | None = None,
    materials: dict[str, dict[str, Any]] | None = None,
) -> str:
    """A scene file: the camera at ``distance`` (``size``: width = height, or (width, height); None: the
    scene's default), the light at ``light`` (of ``color``), the ``render`` table if given, ``materials``
    (default: one matte "m") and the ``shapes`` (``ball``, ``plane``) in order."""
    camera: dict[str, Any] = {"distance": float(distance)}
    if size is not None:
        camera["width"], camera["height"] = (size, size) if isinstance(size, int) else size
    lamp: dict[str, Any] = {"position": _floats(light)}
    if color is not None:
        lamp["color"] = _floats(color)
    doc: dict[str, Any] = {"camera": camera, "light": lamp}
    if render:
        doc["render"] = render
    doc["materials"] = {"m": MATTE} if materials is None else materials
    return "\n" + dump_toml(doc) + "".join(shapes)


def write_scene(folder: Path, name: str, text: str) -> Path:
    """``text`` as the scene file ``folder/name.toml`` (the scene's name, in messages and file names, is ``name``)."""
    path = Path(folder) / f"{name}.toml"
    path.write_text(text)
    return path
