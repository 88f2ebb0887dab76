"""The protocol between minirt and a program given as a command line: the scene it is handed and the
image it hands back.

The scene: ``{scene}`` is a TOML file in minirt's own scene format (README: the scene format) and
``{scene_json}`` the same document as JSON, both written by ``scene_document``: ``[camera]`` distance,
width, height; ``[light]`` position, color; ``[render]`` background, max_depth (samples 1: the exercise
traces one ray a pixel); one ``[materials.mK]`` table per distinct material; ``[[shapes]]`` balls
(center, radius) and planes (normal, distance, the normal as the scene wrote it). No ``[model]`` table:
the rules are the program's own, which is what is graded. The camera is at (0, 0, -distance) looking
along +z at the image plane z = 0, x, y in [-0.5, 0.5], pixel (x, y) with y = 0 the top row.

The image: ``{out}`` is a path without an extension; the program writes ``{out}.EXT`` with EXT one of
``IMAGE_EXTENSIONS`` (``.pfm`` and ``.exr`` float: the colour as computed, unclamped, no 8-bit step;
``.png``, ``.ppm``, ``.bmp``, ... 8-bit). Where it wrote several, a float one is read (it removes the
8-bit encoding's ambiguity). Read by OpenImageIO (minirt.io.images), the file untrusted as any student's.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from minirt.errors import MinirtError
from minirt.io.images import read_student_image
from minirt.model.scene import Ball, Material, Scene
from minirt.model.toml_out import dump_toml

FLOAT_EXTENSIONS = (".pfm", ".exr")
IMAGE_EXTENSIONS = (*FLOAT_EXTENSIONS, ".tif", ".tiff", ".png", ".ppm", ".pnm", ".bmp", ".tga")


def scene_document(scene: Scene) -> dict[str, Any]:
    """The scene as the program reads it (see the module's docstring): plain lists and numbers."""
    names: dict[Material, str] = {}
    for s in scene.shapes:
        names.setdefault(s.material, f"m{len(names)}")
    shapes = []
    for s in scene.shapes:
        if isinstance(s, Ball):
            shapes.append({"type": "ball", "center": list(s.center), "radius": s.radius, "material": names[s.material]})
        else:
            w = s.written  # the normal as the scene wrote it (rule raw_normals reads its length)
            normal = [c * w for c in s.normal] if w != 1.0 else list(s.normal)
            shapes.append(
                {"type": "plane", "normal": normal, "distance": s.distance * w, "material": names[s.material]}
            )
    materials = {
        n: {k: list(getattr(m, k)) for k in ("ambient", "diffuse", "specular", "reflection")} for m, n in names.items()
    }
    cam = scene.camera
    return {
        "scene": {"name": scene.name, "description": scene.description},
        "camera": {"distance": cam.distance, "width": cam.width, "height": cam.height},
        "light": {"position": list(scene.light.position), "color": list(scene.light.color)},
        "render": {"background": list(scene.background), "max_depth": scene.max_depth, "samples": 1},
        "materials": materials,
        "shapes": shapes,
    }


def to_toml(doc: dict[str, Any]) -> str:
    """``scene_document``'s dict as TOML (minirt.model.toml_out: ``materials`` a table of tables, ``shapes``
    an array of tables)."""
    return dump_toml(doc)


def write_scene(scene: Scene, folder: Path) -> dict[str, Path]:
    """Write scene.toml and scene.json into ``folder``; the placeholders' paths."""
    doc = scene_document(scene)
    toml_path, json_path = folder / "scene.toml", folder / "scene.json"
    toml_path.write_text(to_toml(doc), encoding="utf-8")
    json_path.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    return {"scene": toml_path, "scene_json": json_path}


def find_image(out: Path) -> Path:
    """The image the program wrote as ``out.EXT`` (a float one first); MinirtError when there is none."""
    found = [out.with_name(out.name + ext) for ext in IMAGE_EXTENSIONS if out.with_name(out.name + ext).exists()]
    if not found:
        if out.exists():
            raise MinirtError(
                f"the program wrote {out.name} without an extension (write {out.name}.png, .ppm, .pfm ...)"
            )
        raise MinirtError("the program wrote no image (expected {out}.png, .ppm, .bmp, .pfm or .exr)")
    return found[0]


def read_output(out: Path, width: int, height: int, nonfinite: bool = False) -> tuple[np.ndarray, bool, str]:
    """(pixels (H, W, 3), is_float, the file's name) of the program's image, its size checked: uint8 levels
    or float32 colours (unclamped). An empty, unreadable or wrong-sized file is a MinirtError; so is a float
    image with NaN or infinite values, unless ``nonfinite`` (they are kept, to be counted)."""
    path = find_image(out)
    if path.stat().st_size == 0:
        raise MinirtError(f"the program's image {path.name} is empty")
    try:
        pixels, is_float = read_student_image(path, nonfinite=nonfinite)
    except MinirtError as e:  # named by the run's temporary folder: the file's name says it, the same every run
        raise MinirtError(str(e).replace(str(path), f"the program's image {path.name}")) from None
    if pixels.shape[:2] != (height, width):
        rows, cols = pixels.shape[:2]
        raise MinirtError(f"the program's image {path.name} is {cols}x{rows}, the scene {width}x{height}")
    return pixels, is_float, path.name
