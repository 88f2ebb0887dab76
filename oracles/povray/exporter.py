"""The exporter: pure functions from (scene, rules) to POV-Ray 3.7 scene text, and ``minirt export``'s
files (scene.pov, render.sh, README.txt).

The conventions bridged are the package docstring's (frame, pixel corner, ray start, shading, output):
here they become a ``perspective`` camera with a skewed direction (or a ``mesh_camera``), spheres and
planes with ``pigment``/``finish`` translated from the exercise's materials, one ``#case`` per frame of
the animation. Untrusted input: only numbers (Python floats, checked finite, :func:`_f`) and fixed
keywords are written -- no scene, material or file name, and no comment -- so a grep can prove it.
"""

from __future__ import annotations

import math
import shlex
from pathlib import Path

import numpy as np

from minirt.io.atomic import write_all
from minirt.model import camera
from minirt.model.effects import Effects, effects
from minirt.model.rules import Rules
from minirt.model.scene import Ball, Material, Scene
from minirt.oracles.povray.buffers import (
    GEOMETRY_FRAMES,
    GEOMETRY_PARTS,
    ID_SCALE,
    SPLIT,
    Frame,
    ambient_numerator,
    color_frames,
    encoding_ranges,
    is_grey,
)
from minirt.oracles.povray.rays import too_many_mesh_rays, uses_mesh_camera
from minirt.oracles.povray.runner import command

MESH_NAME = "MinirtCameraMesh"  # the identifier the exporter declares, with the sample's index appended
MESH_TRIANGLE_SIZE = 0.5  # circumradius: large triangles keep the single-precision face normal accurate


# ---------------------------------------------------------------------------------------------
# Numbers: the only thing besides fixed keywords that reaches a .pov file


def _f(x: float) -> str:
    x = float(x)
    if not math.isfinite(x):
        raise ValueError(f"non-finite number {x} cannot be exported")
    if x == 0.0:
        return "0"
    s = repr(x)
    return s[:-2] if s.endswith(".0") else s


def _v(v) -> str:
    return "<" + ", ".join(_f(c) for c in v) + ">"


# ---------------------------------------------------------------------------------------------
# The camera: pinhole, or one mesh per sample


def _mesh_camera(scene: Scene, rules: Rules, samples: int = 1) -> str:
    """A mesh_camera reproducing the exercise's rays: in mesh s, triangle k is centred on ray k's origin
    and its face normal (POV-Ray: cross(P3 - P1, P2 - P1), normalised) runs along ray k's direction.
    One mesh: the primary rays. ``samples`` meshes: sample s's rays (camera.sample_offsets, the
    reference's stratified pattern); POV-Ray shoots ray s of each pixel from mesh s and averages."""
    w, h = scene.camera.width, scene.camera.height
    too_many = too_many_mesh_rays(scene, samples)
    if too_many:
        raise ValueError(too_many)
    if samples == 1:
        return _camera_mesh(MESH_NAME + "0", *camera.primary_rays(scene, rules)) + _mesh_camera_statement(1)
    decls = [
        _camera_mesh(f"{MESH_NAME}{k}", *camera.rays_through(scene, rules, *camera.sample_offsets(samples, k, w * h)))
        for k in range(samples)
    ]
    return "".join(decls) + _mesh_camera_statement(samples)


def _mesh_camera_statement(samples: int) -> str:
    meshes = " ".join(f"mesh {{ {MESH_NAME}{k} }}" for k in range(samples))
    return f"camera {{ mesh_camera {{ {samples} 0 {meshes} }} }}"


def _camera_mesh(name: str, o: np.ndarray, d: np.ndarray) -> str:
    a = np.where(np.abs(d[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    e1 = np.cross(d, a)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(d, e1)
    s = MESH_TRIANGLE_SIZE * max(1.0, float(np.abs(o).max(initial=0.0)) * math.sqrt(3))  # see mesh_reach
    p1 = o + s * e1
    p2 = o + s * (-0.5 * e1 + math.sqrt(3) / 2 * e2)
    p3 = o + s * (-0.5 * e1 - math.sqrt(3) / 2 * e2)
    wrong = np.einsum("ij,ij->i", np.cross(p3 - p1, p2 - p1), d) < 0
    p2, p3 = np.where(wrong[:, None], p3, p2), np.where(wrong[:, None], p2, p3)
    if not np.isfinite(np.concatenate([p1, p2, p3])).all():
        raise ValueError("non-finite mesh camera vertex")
    # 9 significant digits round-trip a single-precision float, which is what POV-Ray stores. mesh2, not
    # mesh: mesh hashes every vertex and normal into 1000 buckets, and this view's normals all land in a
    # few of them, which made parsing quadratic (256²: 1.9 s, 512²: > 120 s); mesh2 takes them as given.
    # mesh_camera parses a literal mesh2 with mesh syntax (POV-Ray 3.7 parser), so it is declared first
    # under a fixed name and referenced.
    v = np.stack([p1, p2, p3], axis=1).reshape(-1)
    n = len(o)
    verts = ",\n".join(["<%.9g,%.9g,%.9g>"] * (3 * n)) % tuple(v.tolist())  # one C-level pass: 7x np.char.mod
    faces = ",\n".join(["<%d,%d,%d>"] * n) % tuple(range(3 * n))
    return (
        f"#declare {name} = mesh2 {{\nvertex_vectors {{ {3 * n},\n{verts}\n}}\nface_indices {{ {n},\n{faces}\n}}\n}}\n"
    )


def _camera(scene: Scene, rules: Rules, samples: int = 1) -> str:
    if uses_mesh_camera(scene, rules, samples):
        return _mesh_camera(scene, rules, samples)
    w, h, d = scene.camera.width, scene.camera.height, _f(scene.camera.distance)
    # corner: half a pixel up-left of POV-Ray's centre rays
    direction = f"<-0.5/{w}, 0.5/{h}, {d}>" if rules.pixel_sample == "corner" else f"<0, 0, {d}>"
    return f"camera {{ perspective location <0, 0, -{d}> right <1, 0, 0> up <0, 1, 0> direction {direction} }}"


# ---------------------------------------------------------------------------------------------
# Shapes, materials and frames


def _shape_head(s) -> str:
    if isinstance(s, Ball):
        return f"sphere {{ {_v(s.center)}, {_f(s.radius)}"
    return f"plane {{ {_v(s.normal)}, {_f(s.distance)}"  # stored normalised: x·n = distance


def _material(m: Material, scene: Scene, rules: Rules, fx: Effects, channel: int) -> str:
    a = ambient_numerator(m, scene, rules, fx)
    fin = []
    if channel >= 0:
        pigment = "rgb 1"
        fin.append(f"ambient {_f(a[channel])}")
        fin.append(f"diffuse {_f(m.diffuse[channel]) if fx.diffuse else '0'}")
        spec, refl = m.specular[channel], m.reflection[channel]
        if fx.specular and spec != 0:
            fin.append(f"phong {_f(spec)} phong_size {int(rules.specular_exponent)}")
        if fx.reflection and refl != 0:
            fin.append(f"reflection {{ rgb {_f(refl)} }}")
    else:
        dc = m.diffuse
        if not fx.diffuse or is_grey(dc):
            pigment = "rgb 1"
            fin.append(f"ambient rgb {_v(a)}")
            fin.append(f"diffuse {_f(dc[0]) if fx.diffuse else '0'}")
        else:
            pigment = f"rgb {_v(dc)}"
            amb = tuple(a[i] / dc[i] if dc[i] != 0 else 0.0 for i in range(3))  # ambient is x pigment
            fin.append(f"ambient rgb {_v(amb)}")
            fin.append("diffuse 1")
        if fx.specular and m.specular[0] != 0:
            fin.append(f"phong {_f(m.specular[0])} phong_size {int(rules.specular_exponent)}")
        if fx.reflection and any(c != 0 for c in m.reflection):
            fin.append(f"reflection {{ rgb {_v(m.reflection)} }}")
    return f"pigment {{ {pigment} }} finish {{ {' '.join(fin)} }}"


def _color_frame(scene: Scene, rules: Rules, channel: int) -> list[str]:
    fx = effects(scene, rules)
    out = []
    pick = (lambda c: _f(c[channel])) if channel >= 0 else _v
    if fx.diffuse or fx.specular:
        out.append(f"light_source {{ {_v(scene.light.position)} color rgb {pick(scene.light.color)} }}")
    if rules.background == "on-miss" and fx.background:
        out.append(f"background {{ rgb {pick(scene.background)} }}")
    for s in scene.shapes:
        out.append(f"{_shape_head(s)} {_material(s.material, scene, rules, fx, channel)} }}")
    return out


def _functions(
    scene: Scene, rules: Rules, k: int, rng: dict[str, tuple[float, float]] | None
) -> dict[tuple[str, str], str]:
    d = _f(scene.camera.distance)
    cam_dist = f"sqrt(x*x + y*y + (z + {d})*(z + {d}))"
    tfun = f"{cam_dist} * z / (z + {d})" if rules.ray_origin == "image-plane" else cam_dist
    exprs = {"x": "x", "y": "y", "z": "z", "t": tfun}
    out = {}
    for q, e in exprs.items():
        lo, hi = rng[q] if rng is not None else (0.0, 1.0)
        scaled = f"(({e}) - ({_f(lo)})) * {_f(SPLIT / (hi - lo))}"
        out[(q, "coarse")] = f"floor({scaled}) / {SPLIT}"
        out[(q, "fine")] = f"{scaled} - floor({scaled})"
    hi, lo = divmod(k + 1, ID_SCALE)
    out[("id", "")] = _f(lo / ID_SCALE)  # the low part; the whole id below ID_SCALE - 1 shapes
    out[("id", "hi")] = _f(hi / ID_SCALE)
    out[("", "")] = "0"  # an unused channel
    return out


def _geometry_frame(scene: Scene, rules: Rules, group: int, ranges) -> list[str]:
    out = []
    for k, s in enumerate(scene.shapes):
        fn = _functions(scene, rules, k, ranges[k])
        entries = []
        for ch, (q, part) in enumerate(zip(GEOMETRY_FRAMES[group], GEOMETRY_PARTS[group], strict=True)):
            unit = ["0", "0", "0"]
            unit[ch] = "3"  # average of three pigments divides by 3
            entries.append(
                f"    [1 function {{ {fn[(q, part)]} }} color_map {{ [0 rgb 0] [1 rgb <{', '.join(unit)}>] }}]"
            )
        out.append(f"{_shape_head(s)}")
        out.append("  pigment { average pigment_map {")
        out.extend(entries)
        out.append("  } } finish { ambient 1 diffuse 0 } }")
    return out


def scene_to_pov(
    scene: Scene,
    rules: Rules,
    frames: list[Frame] | None = None,
    ranges: list[dict[str, tuple[float, float]]] | None = None,
    samples: int = 1,
) -> str:
    """The scene as POV-Ray 3.7 text. ``frames``: the passes, one animation frame each (frame_number
    1, 2, ...); default the colour frame(s) only. ``samples`` > 1: the exercise's stratified samples
    through one camera mesh each. Only numbers and fixed keywords are written."""
    if frames is None:
        frames = color_frames(scene, rules)
    if ranges is None and any(f.kind == "geometry" for f in frames):
        ranges = encoding_ranges(scene, rules)
    fx = effects(scene, rules)
    depth = scene.max_depth + 1 if fx.reflection else 1
    # No comments at all: nothing but numbers and fixed keywords, so a grep can prove it.
    lines = [
        "#version 3.7;",
        f"global_settings {{ assumed_gamma 1.0 ambient_light 1 max_trace_level {depth} adc_bailout 0 }}",
        _camera(scene, rules, samples),
    ]
    bodies = []
    for f in frames:
        if f.kind == "color":
            body = _color_frame(scene, rules, f.index)
        else:
            body = _geometry_frame(scene, rules, f.index, ranges)
        bodies.append((f, body))
    if len(bodies) == 1:
        lines.extend(bodies[0][1])
    else:
        lines.append("#switch (frame_number)")
        for i, (_, body) in enumerate(bodies, start=1):
            lines.append(f"#case ({i})")
            lines.extend("  " + ln for ln in body)
            lines.append("#break")
        lines.append("#end")
    return "\n".join(lines) + "\n"


def export(scene: Scene, rules: Rules, out_dir: str | Path) -> list[Path]:
    """Write ``scene.pov`` (the colour pass(es)), ``render.sh`` with the exact command and a README."""
    out = Path(out_dir)
    frames = color_frames(scene, rules)
    pov = out / "scene.pov"
    mesh = uses_mesh_camera(scene, rules)
    cmd = shlex.join(command(scene, len(frames), 1, len(frames), "png8", mesh_camera=mesh))
    sh = out / "render.sh"
    header = "# Render scene.pov with POV-Ray 3.7 (linear 8-bit PNG, no antialiasing)"
    readme = out / "README.txt"
    note = ""
    if len(frames) == 3:
        note = (
            " The scene is rendered once per colour channel (frames 1-3 are grey renders of R, G and B):"
            " take channel 0 of out1.png, out2.png and out3.png."
        )
    if mesh:
        note += (
            " A shape lies between the camera and the image plane, so the camera is a mesh_camera whose rays"
            f" start on the image plane; POV-Ray renders {scene.camera.height + 1} rows: drop the first."
        )
    output = "out.png" if len(frames) == 1 else "out1.png, out2.png, out3.png"
    # The three together, atomically (a symlink planted under one of the names is replaced, never
    # written through); the script executable.
    files = {
        pov: scene_to_pov(scene, rules, frames),
        sh: f'#!/bin/sh\n{header}\ncd "$(dirname "$0")"\n{cmd}\n',
        readme: f"Render with: {cmd}\nOutput: {output} (linear, File_Gamma 1.0).{note}\n",
    }
    return write_all(files, modes={sh: 0o755})
