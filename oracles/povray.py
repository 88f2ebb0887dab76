"""POV-Ray 3.7 as an oracle: the exercise's scene exported to POV-Ray's scene language, rendered, read back.

Conventions bridged (each measured with Debian's povray 3.7.0.10):

- Frame: POV-Ray is left-handed, x right, y up, camera looking along +z -- the exercise's own frame, so
  coordinates are written as they are (nothing mirrored).
- Pixel corner: with antialiasing off POV-Ray shoots pixel (i, j) through its CENTRE,
  normalise(D + x0 R + y0 U) with x0 = (i+0.5)/W - 0.5, y0 = 0.5 - (j+0.5)/H. A skewed
  ``direction <-0.5/W, 0.5/H, d>`` with ``right <1,0,0>``, ``up <0,1,0>``, ``location <0,0,-d>`` shifts
  that by half a pixel onto the exercise's CORNER rays (rule pixel_sample "corner"); for "center" the
  plain ``direction <0,0,d>``. No look_at/angle (they make the parser rewrite the vectors).
- Ray start: POV-Ray's primary rays start at the camera, the exercise's on the image plane z = 0 (rule
  ray_origin "image-plane"). The two agree unless a shape reaches into the pyramid between the camera
  and the image plane. Only then (simulate only what the scene calls for) the camera is a
  ``mesh_camera`` (distribution 0: pixel k's ray starts at the centroid of triangle k and runs along its
  face normal): one triangle per pixel, centred on the exercise's ray origin on z = 0, perpendicular
  to its direction. POV-Ray gives image row j the triangles of row j - 1, so H + 1 rows are rendered
  and the first dropped (measured: with it the hit mask and ids equal the reference's). Mesh vertices
  and normals are single precision: origins err by ~2^-24 |P|, directions by ~2^-23, which adds
  2^-22 (1 + t) to positions (``precision``) and a relative margin to the band, per shape
  (``band_scales``: each ball's own distance; ``band_inside_scales`` adds the bounding boxes;
  ``band_threshold`` is the largest).
  Antialiasing cannot be combined with it (the mesh camera maps a pixel to one triangle). t is
  re-based on the image-plane origin: t = |P - cam| * z / (z + d) (the part of the camera ray before
  z = 0 removed; with the mesh camera the same line starts at z = 0, so the same formula).
- Normals: POV-Ray flips them to face the viewer (two_sided True) and skips a light entirely when
  n·l < 1e-10 (no diffuse, no phong; phong only when r·l > 0): clamp True. Balls are seen from inside
  (near_root_only False).
- Shadows: only objects with 1e-3 < t < distance_to_light - 1e-3 block; objects beyond the light never
  shadow (shadow_range "to-light"). Secondary rays use POV-Ray's own epsilons (1e-3 for shadow rays);
  the closest exercise rule is offset "error-bound".
- Depth: ``max_trace_level`` N = primary ray plus N-1 bounces, so N = max_depth + 1; ``adc_bailout 0``
  (the default 1/255 prunes faint reflections).
- Shading: POV-Ray multiplies ambient by the pigment, so a material (ambient AC, diffuse DC, specular
  SC, reflection RC) becomes ``pigment { rgb DC } finish { ambient rgb (AC+BG)/DC diffuse 1 phong SC
  phong_size E reflection { rgb RC } }`` (E the rule specular_exponent, 8 by default) -- or, exactly and
  without a division, ``pigment { rgb 1 }`` with ``diffuse DC`` when DC is grey. BG is folded into
  ambient for rule background "on-hit"; for "on-miss" it is a ``background``; for "none" neither.
  ``phong`` is a scalar: when a specular colour is not grey, or a non-grey diffuse colour has a zero
  channel under a non-zero ambient, the scene is rendered once per colour channel with grey values and
  the channels combined.
- Output: ``assumed_gamma 1.0`` and File_Gamma 1.0 (linear values). The 8-bit PNG (+FN8) rounds
  floor(c*255 + 0.5) exactly as the exercise does; the float colour is POV-Ray's EXR, which is HALF
  float only (relative precision 2^-11; its own rounding flips 8-bit levels at .5 ties, hence both).
- Buffers (one EXR animation, frame_number selects the pass, to pay POV-Ray's ~0.65 s start-up once):
  hit mask from the alpha channel (+UA, no background); shape id from a constant pigment per shape
  (``finish { ambient 1 diffuse 0 }``), k + 1 = 2048 hi + lo with each part / 2048 in a channel of its
  own (a half float holds j / 2048 exactly for j < 2048; the hi frame only from 2,047 shapes: one id
  channel read (k + 1) / 2048 clamped to 1, and a scene of 10,000 balls "failed" 12,736 of 16,384 ids);
  position and t from pigment functions, each quantity q mapped to
  v = (q - lo)/(hi - lo) with a per-shape range and split into a coarse channel floor(1024 v)/1024 and a
  fine channel frac(1024 v) (decode v = coarse + fine/1024); normals analytically per shape from the
  decoded position ((P - C)/r, or the plane's normal, unflipped like the reference's).
- Antialiasing (``options={"antialias": R}``, R in 1..9): ``+A0.0 +R{R}`` instead of ``-A``. Threshold 0
  supersamples every pixel on POV-Ray's own jittered sub-pixel grid (method 1, default jitter, which is
  deterministic), not the exercise's stratified pattern. Colour only: no geometry frames and no 8-bit PNG
  pass (one start-up per render), ``image8`` is None. The supersampled area is POV-Ray's pixel square,
  which the "corner" skew shifts by half a pixel; to compare with the reference's samples (which cover
  [x, x+1) x [y, y+1)) render both with rule pixel_sample "center". Without the option: one ray per pixel.
- The exercise's own samples (``options={"samples": n}``, n > 1): a mesh_camera with n meshes, mesh s
  holding sample s's rays (camera.sample_offsets, the reference's stratified pattern), one triangle
  per pixel; POV-Ray shoots ray s of each pixel from mesh s and averages the n colours (distribution 0,
  ``rays_per_pixel`` n). So its image is the reference's n-sample image, pixel by pixel, up to its
  single-precision colour and the mesh's single-precision rays. Colour only (no geometry frames); the
  8-bit PNG pass is kept. At most MAX_MESH_RAYS = n x W x H rays (scene text ~130 bytes each, parsed once
  per pass); excludes ``antialias``.
- Numeric limits: hits beyond 1e7 and nearer than 1e-4 to the ray's origin are dropped (the
  latter matters for the mesh camera's image-plane origins: meta precision ``min_distance`` and
  ``start_err``, start_decision(), give the band of minirt.reference.band.start_band); an exactly tangent
  ray misses a sphere; |n·d| < 1e-10 misses a plane; with 3 or more finite objects POV-Ray builds
  float bounding boxes; coincident surfaces: the first declared object wins.
- Untrusted input: POV-Ray's language can open, read and write files. The exporter writes only numbers
  (Python floats, checked finite) and fixed keywords: no scene, material or file name ever reaches a
  .pov file.
"""

from __future__ import annotations

import functools
import math
import os
import re
import shlex
import shutil
import subprocess
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from minirt.errors import MinirtError
from minirt.io.images import read_image, read_image_u8
from minirt.jobs import processes
from minirt.model import camera
from minirt.model.backend import GeometryTolerance, Margins, Series, Setting, Truth, farthest_hit
from minirt.model.effects import Effects, effects
from minirt.model.result import RenderResult
from minirt.model.rules import Rules
from minirt.model.scene import Ball, Material, Scene
from minirt.oracles.base import Oracle

NAME = "povray"
INSTALL_HINT = "povray not found on PATH; install: sudo apt-get install povray"
MAX_DISTANCE = 1e7  # POV-Ray drops hits beyond this (configbackend.h MAX_DISTANCE)
MIN_ISECT_DEPTH = 1e-4  # ... and hits nearer than this to the ray's origin (configcore.h MIN_ISECT_DEPTH)
BOUNDING_THRESHOLD = 3  # with this many finite objects or more POV-Ray builds its bounding tree (+MB default)
FAR_ROOT_MARGIN = 10 * MIN_ISECT_DEPTH  # encoding_ranges: a near root this close to the start may be dropped
SPLIT = 1024  # coarse/fine split of an encoded value
MAX_ANTIALIAS = 9  # POV-Ray accepts Antialias_Depth 1..9
ID_SCALE = 2048  # shape id k is (k + 1) = 2048 hi + lo, each part stored as part / 2048: exact in half float
# Error of one decoded value v in [0, 1) in units of 1/SPLIT: the fine channel lies in [0, 1), where a
# half float's spacing is at most 2^-11, so rounding errs by at most 2^-12; POV-Ray's single-precision
# colour arithmetic (colour map, average) adds a few float ulps, bounded generously by 2^-20.
FINE_ERROR = 2.0**-12 + 2.0**-20
HALF_REL = 2.0**-11  # half float: relative rounding error <= 2^-11 (round to nearest, 11-bit significand)
# Channel quantities and parts per geometry frame. The fourth frame only for scenes of ID_SCALE - 1
# shapes or more: below, the id's high part is 0 and the third frame's low part is the whole id.
GEOMETRY_FRAMES = (("x", "x", "y"), ("y", "z", "z"), ("t", "t", "id"), ("id", "", ""))
GEOMETRY_PARTS = (("coarse", "fine", "coarse"), ("fine", "coarse", "fine"), ("coarse", "fine", ""), ("hi", "", ""))


# ---------------------------------------------------------------------------------------------
# What to render


@dataclass(frozen=True)
class Frame:
    """One frame of the animation: a colour render (channel 0-2 for grey per-channel renders, -1 for
    all channels at once) or geometry group 0-3 (see GEOMETRY_FRAMES)."""

    kind: str  # "color" | "geometry"
    index: int

    @property
    def label(self) -> str:
        if self.kind == "color":
            return "color" if self.index < 0 else f"color.{'RGB'[self.index]}"
        return "geometry." + "+".join(
            f"{q}.{p}" if p else q
            for q, p in zip(GEOMETRY_FRAMES[self.index], GEOMETRY_PARTS[self.index], strict=True)
            if q
        )


def _grey(c: tuple[float, float, float]) -> bool:
    return c[0] == c[1] == c[2]


def _ambient_numerator(m: Material, scene: Scene, rules: Rules, fx: Effects) -> tuple[float, float, float]:
    bg = scene.background if (rules.background == "on-hit" and fx.background) else (0.0, 0.0, 0.0)
    ac = m.ambient if fx.ambient else (0.0, 0.0, 0.0)
    return (ac[0] + bg[0], ac[1] + bg[1], ac[2] + bg[2])


def needs_per_channel(scene: Scene, rules: Rules) -> bool:
    """True when one RGB render cannot express the materials: phong is a scalar (a non-grey specular
    colour), or ambient = pigment * ambient cannot carry a non-zero ambient where the diffuse pigment
    has a zero channel (and the pigment is not grey, i.e. diffuse cannot go into the scalar ``diffuse``)."""
    fx = effects(scene, rules)
    for s in scene.shapes:
        m = s.material
        if fx.specular and not _grey(m.specular):
            return True
        if fx.diffuse and not _grey(m.diffuse):
            a = _ambient_numerator(m, scene, rules, fx)
            if any(m.diffuse[i] == 0.0 and a[i] != 0.0 for i in range(3)):
                return True
    return False


def color_frames(scene: Scene, rules: Rules) -> list[Frame]:
    if needs_per_channel(scene, rules):
        return [Frame("color", c) for c in range(3)]
    return [Frame("color", -1)]


def geometry_frames(scene: Scene | None = None) -> list[Frame]:
    """The geometry frames: three, and a fourth for the id's high part when the scene has ID_SCALE - 1
    shapes or more (a half float holds an integer part / 2048 exactly only below 2048)."""
    many = scene is not None and len(scene.shapes) >= ID_SCALE - 1
    return [Frame("geometry", g) for g in range(len(GEOMETRY_FRAMES) if many else 3)]


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
# Encoding ranges for the geometry buffers


def _pinhole_directions(scene: Scene, rules: Rules) -> np.ndarray:
    from dataclasses import replace

    _, d = camera.primary_rays(scene, replace(rules, ray_origin="camera"))
    return d


def encoding_ranges(scene: Scene, rules: Rules) -> list[dict[str, tuple[float, float]] | None]:
    """Per shape, the (lo, hi) of x, y, z and t over every hit of POV-Ray's primary rays with that shape
    alone (a ball's near root, and its far root where the near one may not count; t < 1e7), padded by
    1e-4 of the span so rounded hits stay inside [lo, hi).

    A superset of what is visible (occlusion ignored), so every decoded value lies in its range. None
    for a shape no primary ray reaches."""
    d = _pinhole_directions(scene, rules)
    cam = np.array(scene.camera.position)
    dist = scene.camera.distance
    # where a ray starts, as a t from the camera: the image plane z = 0 for rule ray_origin "image-plane"
    # (rays with d_z <= 0 never reach it), the camera itself otherwise
    with np.errstate(divide="ignore"):
        t_start = np.where(d[:, 2] > 0, -cam[2] / d[:, 2], np.inf) if rules.ray_origin == "image-plane" else 0.0
    out = []
    for s in scene.shapes:
        ts = []
        if isinstance(s, Ball):
            f = cam - np.array(s.center)
            b = d @ f
            c = f @ f - s.radius**2
            disc = b * b - c
            ok = disc >= 0
            sq = np.sqrt(np.where(ok, disc, 0.0))
            near, far = -b - sq, -b + sq
            ts.append(np.where(ok & (near > 0), near, np.nan))
            # The far root is the visible hit only where the near one is not: before the ray's start, or
            # within POV-Ray's MIN_ISECT_DEPTH of it. FAR_ROOT_MARGIN is ten times that depth plus 1e-6 of
            # the distance, far above the rays' own error there (MESH_RAY_ERROR (R + t) at t ~ 1e-4, and
            # the pinhole's 2^-22 t). Elsewhere the far root cannot be what POV-Ray reports, and leaving it
            # out keeps a huge ball's range (a ground of radius 1e6: its far side 2e6 away) to what is seen.
            maybe = near - t_start < FAR_ROOT_MARGIN + 1e-6 * np.abs(near)
            ts.append(np.where(ok & (far > 0) & maybe, far, np.nan))
        else:
            n = np.array(s.normal)
            nd = d @ n
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (s.distance - n @ cam) / nd
            ts.append(np.where((nd != 0) & (t > 0), t, np.nan))
        t = np.concatenate(ts)
        dd = np.concatenate([d] * len(ts))
        keep = np.isfinite(t) & (t < MAX_DISTANCE)
        t, dd = t[keep], dd[keep]
        ranges: dict[str, tuple[float, float]] = {}
        if t.size == 0:
            out.append(None)  # no primary ray reaches it: nothing to encode
            continue
        p = cam + t[:, None] * dd
        if rules.ray_origin == "image-plane":  # the exercise's rays start on z = 0: nothing before it is hit
            front = p[:, 2] >= 0
            t, p = t[front], p[front]
            if t.size == 0:
                out.append(None)
                continue
        tq = t * p[:, 2] / (p[:, 2] + dist) if rules.ray_origin == "image-plane" else t
        # A constant coordinate (a plane's y) still gets a span of 1e-6 of the scene's scale, so POV-Ray's
        # rounding of far hits (~1e-16 of |P|) stays far inside the padding.
        scale = max(1.0, float(np.abs(p).max()), float(t.max()))
        # POV-Ray's own rays hit up to MESH_RAY_ERROR (R + t) from these (the pinhole's error is smaller):
        # the ranges hold that too, now that a ball's far side no longer widens them.
        ray = MESH_RAY_ERROR * (mesh_reach(scene, rules) + float(t.max()))
        for name, q in (("x", p[:, 0]), ("y", p[:, 1]), ("z", p[:, 2]), ("t", tq)):
            lo, hi = float(q.min()), float(q.max())
            span = max(hi - lo, 1e-6 * scale)
            ranges[name] = (lo - 1e-4 * span - ray, hi + 1e-4 * span + ray)
        out.append(ranges)
    return out


# Mesh camera rays (single-precision vertices and normals): the centroid errs by ~2^-24 (|P| + size)
# < 2^-23 and the face normal, from vertex differences over edges of length size*sqrt(3) ~ 0.87 and then
# stored as a float, by ~2^-22 rad; a point at distance t along the ray thus moves by <= 2^-22 (1 + t).
# Twice that, 2^-21 (1 + t), is used below.
MESH_RAY_ERROR = 2.0**-21
# That holds for origins within 1 of the world origin (the image plane). Rays that start at a camera d away
# (rule ray_origin "camera", the exercise's samples) get triangles d times larger, so the face normal stays
# within 2^-22 rad, while the centroid errs by 2^-24 (|P| + size): a point at distance t then moves by
# <= MESH_RAY_ERROR (R + t), R = mesh_reach() = max(1, |P|). (Fuzz f32_2026_155, camera 5675 away: fixed-size
# triangles turned every sample ray by 1e-3 rad and all 188 compared pixels differed.)


def mesh_reach(scene: Scene, rules: Rules) -> float:
    """R of MESH_RAY_ERROR (R + t): max(1, |P|) over the mesh camera's ray origins."""
    return 1.0 if rules.ray_origin == "image-plane" else max(1.0, float(np.linalg.norm(scene.camera.position)))


def precision(
    scene: Scene,
    ranges: list[dict[str, tuple[float, float]] | None],
    mesh_camera: bool = False,
    reach: float = 1.0,
) -> dict[str, Any]:
    """The buffer precision the encoding guarantees (derived, not including POV-Ray's own rounding),
    plus the mesh camera's ray error when one is used."""
    per = FINE_ERROR / SPLIT  # error of v, as a fraction of the range
    pos = 0.0
    t_abs = 0.0
    t_rel = 0.0
    nrm = 0.0
    for s, r in zip(scene.shapes, ranges, strict=True):
        if r is None:
            continue
        ray = MESH_RAY_ERROR * (reach + r["t"][1]) if mesh_camera else 0.0
        e = max((r[q][1] - r[q][0]) * per for q in "xyz") + ray
        pos = max(pos, e)
        et = (r["t"][1] - r["t"][0]) * per + ray
        t_abs = max(t_abs, et)
        t_rel = max(t_rel, et / r["t"][0]) if r["t"][0] > 0 else math.inf
        if isinstance(s, Ball):
            nrm = max(nrm, math.sqrt(3) * e / s.radius)
    return {
        "position_abs": pos,
        "t_abs": t_abs,
        "t_rel": t_rel,
        "normal_abs": nrm,
        "color_rel": HALF_REL / 2,
        "color8": "exact (POV-Ray's +FN8 rounds floor(c*255 + 0.5))",
        "derivation": (
            "q = lo + (1024 coarse + fine) (hi - lo) / 1024 per shape and quantity; the fine channel in [0, 1) "
            "is a half float (error <= 2^-12) plus single-precision colour arithmetic (<= 2^-20), so "
            "|dq| <= (2^-12 + 2^-20)/1024 (hi - lo) = 2.4e-7 of the range; position_abs/t_abs are the largest "
            "over shapes, t_rel divides by the smallest t in the range; normals (P - C)/r err by "
            "sqrt(3) position_abs / r (planes exact); the float colour is half: relative 2^-12"
            + ("; plus the mesh camera's single-precision rays, 2^-21 (R + t_max) per shape" if mesh_camera else "")
        ),
        "mesh_camera": mesh_camera,
        # POV-Ray's ray directions: decoded far hits (|P - cam| ~ 1e3) lie within ~4e-8 rad of the exercise's
        # rays (measured), float32 level although its camera vectors are double; 2^-22 = 2.4e-7 leaves a factor
        # of 6. The mesh camera's single-precision rays err by MESH_RAY_ERROR.
        "dir_err": max(2.0**-22, MESH_RAY_ERROR if mesh_camera else 0.0),
        "ray_reach": reach if mesh_camera else 1.0,  # R: a ray's position error is dir_err (R + t)
    }


def start_decision(scene: Scene, rules: Rules, mesh_camera: bool) -> dict[str, Any]:
    """POV-Ray's minimum distance along the harness's rays and its position error there
    (minirt.reference.band.start_band).

    - Mesh camera: rays start on the harness's own origins, so hits within MIN_ISECT_DEPTH of them are
      dropped; the single-precision triangles place a point at distance t off by <= MESH_RAY_ERROR (1 + t)
      (see MESH_RAY_ERROR), at t = MIN_ISECT_DEPTH: MESH_RAY_ERROR (1 + 1e-4).
    - Pinhole camera, rule ray_origin "image-plane": rays start at the camera, at least the camera distance
      before the image plane, and no shape lies between the two (else the mesh camera is used), so no
      candidate of the reference is within 1e-4 of POV-Ray's origin: minimum distance 0. Its
      double-precision rays cross the image plane within dir_err |o - camera| of the exercise's origin o
      (dir_err = 2^-22, see precision()): the reference's own t > 0 decision is undecidable for POV-Ray
      within that distance.
    - Pinhole camera, rule ray_origin "camera": POV-Ray's rays and the exercise's start at the same point,
      the camera (its location is given exactly), so hits within MIN_ISECT_DEPTH of it are dropped, as
      with the mesh camera; at t = MIN_ISECT_DEPTH the direction error places a point dir_err
      MIN_ISECT_DEPTH off. (A fuzzed plane through the camera, grazing_7_1: the reference hit it at
      t ~ 1e-10 on a row of pixels, POV-Ray did not.)
    """
    if mesh_camera:
        return {
            "min_distance": MIN_ISECT_DEPTH,
            "start_err": MESH_RAY_ERROR * (mesh_reach(scene, rules) + MIN_ISECT_DEPTH),
        }
    if rules.ray_origin == "camera":
        return {"min_distance": MIN_ISECT_DEPTH, "start_err": 2.0**-22 * MIN_ISECT_DEPTH}
    o = camera.primary_rays(scene, rules)[0]
    reach = float(np.max(np.linalg.norm(o - np.asarray(scene.camera.position), axis=1))) if len(o) else 0.0
    return {"min_distance": 0.0, "start_err": 2.0**-22 * reach}


def band_scales(scene: Scene, rules: Rules, samples: int = 1) -> list[float]:
    """K·eps per shape for minirt.reference.band (its ``scale``): rays whose relative margin about that shape is below
    it may legitimately flip in POV-Ray, either way (hit to miss or miss to hit).

    - its double-precision sphere test uses the textbook discriminant b^2 - (|f|^2 - r^2), whose error
      is about 2^-53 |f|^2, a relative margin 2^-53 |f|^2/r^2 (silhouettes and depth ties alike);
    - a plane is missed when |n·d| < 1e-10 (the grazing margin).
    - with a mesh camera, rays start and point off by MESH_RAY_ERROR (1 + t): at a ball, t < |C| + r, a
      relative margin MESH_RAY_ERROR (1 + |C| + r)/r; at a plane, |n·d| moves by MESH_RAY_ERROR.
    Each term belongs to one ball (its discriminant, its distance), so each shape gets its own (fuzz far
    family: one ball 1e6 radii away made the scene-wide eps 0.3, and every pixel of the well-held ground
    fell in the band). K = 8 covers the few roundings chained in each. The bounding boxes, which can only
    lose a hit, are band_inside_scales.
    """
    base = 1e-10
    mesh = uses_mesh_camera(scene, rules, samples)
    if mesh:
        base = max(base, MESH_RAY_ERROR)
    cam = scene.camera.position
    reach = mesh_reach(scene, rules)
    out = []
    for s in scene.shapes:
        eps = base
        if isinstance(s, Ball):
            c = math.hypot(*s.center)
            f = math.dist(cam, s.center) + s.radius
            eps = max(eps, 2.0**-53 * f * f / (s.radius * s.radius))
            if mesh:
                eps = max(eps, MESH_RAY_ERROR * (reach + c + s.radius) / s.radius)
        out.append(8 * eps)
    return out


def band_inside_scales(scene: Scene, rules: Rules, samples: int = 1) -> list[float]:
    """K·eps per shape for the silhouette margin of rays that meet the ball (minirt.reference.band ``inside_scale``):
    band_scales plus POV-Ray's bounding boxes, which are tested before the exact sphere and so can only
    make it miss a ball the ray meets, never hit one it misses.

    With 3 or more finite objects POV-Ray bounds them with a tree of single-precision boxes stored as a
    lower corner and lengths, upper = lower + length in float: a face of any box holding ball k -- a
    node's box spans other balls too, up to the union box of every ball, largest coordinate E -- can sit
    2^-24 (|lower| + length + |upper|) <= 2^-24 4E inside the ball's extent. A ray whose closest approach
    h to the centre is below r - delta passes through every such box, so it is lost only where
    (r - h)/r < 2^-24 4E/r (fuzz far_2026_112: a ball of radius 0.27 beside one 1e8 away lost the top of
    its disc, its upper y off by ulp(1.6e7)). With fewer, no tree: the ball's own box, 2^-24 (|C| + r)/r.
    K = 8 as in band_scales. Planes are unbounded (no box): their band_scales."""
    balls = [s for s in scene.shapes if isinstance(s, Ball)]
    union = max((max(abs(x) for x in b.center) + b.radius for b in balls), default=0.0)
    out = []
    for s, sym in zip(scene.shapes, band_scales(scene, rules, samples), strict=True):
        if isinstance(s, Ball):
            box = 4 * union if len(balls) >= BOUNDING_THRESHOLD else math.hypot(*s.center) + s.radius
            sym = max(sym, 8 * 2.0**-24 * box / s.radius)
        out.append(sym)
    return out


def root_errors(scene: Scene, rules: Rules) -> list[float]:
    """Per shape, the error of POV-Ray's own sphere root times the cosine at the hit (minirt.harness.tolerances divides
    by |n·d| per pixel): its double-precision textbook discriminant b^2 - (|f|^2 - r^2) errs by about
    3 2^-53 |f|^2 (|f| the distance from the ray's origin to the centre, at most the camera's distance plus
    origin_lift plus r), and sqrt(disc) = r cos, so t errs by 1.5 2^-53 |f|^2/(r cos) and the hit point by
    as much along the ray. K = 8 as for the bands (12 2^-53 |f|^2/r). The normal (P - C)/r then errs by
    that over r. A ball 2.4e4 from the camera, radius 0.46 (fuzz f32_2026_22): 1.4e-6/cos, beside the
    encoding's 1.7e-7 -- measured 8.6e-7 along the ray near a silhouette. Planes: their t is one division,
    exact to a few ulps (0)."""
    cam = scene.camera.position
    lift = origin_lift(scene, rules) if scene.shapes else 0.0
    out = []
    for s in scene.shapes:
        if isinstance(s, Ball):
            f = math.dist(cam, s.center) + lift + s.radius
            out.append(12 * 2.0**-53 * f * f / s.radius)
        else:
            out.append(0.0)
    return out


def band_threshold(scene: Scene, rules: Rules, samples: int = 1, inside: list[float] | None = None) -> float:
    """The largest of band_inside_scales (``inside``, if already computed): one threshold for the whole
    scene (its worst-held shape)."""
    base = 8 * (MESH_RAY_ERROR if uses_mesh_camera(scene, rules, samples) else 1e-10)
    return max(band_inside_scales(scene, rules, samples) if inside is None else inside, default=base)


def origin_lift(scene: Scene, rules: Rules) -> float:
    """max |o - camera| over the harness's ray origins: 0 for rays from the camera (rule ray_origin
    "camera"), else the image plane's farthest pixel, distance / min d_z. A pinhole POV-Ray ray starts at
    the camera, so its t exceeds the harness's by at most this much."""
    if rules.ray_origin != "image-plane":
        return 0.0
    dz = float(_pinhole_directions(scene, rules)[:, 2].min())
    return scene.camera.distance / dz if dz > 0 else math.inf


def band_origin_scales(scene: Scene, rules: Rules, samples: int = 1) -> list[float]:
    """K·eps per shape for the origin margin (minirt.reference.band ``origin_scale``): whether a ray starts inside
    ball k, |o - C| < r, which POV-Ray decides at the ray's origin -- |f|^2 < r^2 in double precision,
    an error of about 2^-53 |f|^2, a relative margin 2^-53 |f|^2/r^2; the mesh camera's origins err by
    MESH_RAY_ERROR R (R = mesh_reach), MESH_RAY_ERROR R / r. Neither the distance along the ray nor the
    bounding boxes enter (the ground of a far scene, radius 1.5e6 and 0.47 under the camera: 3e-7 of its
    radius, far outside both). Planes: 1e-10 (unused: the origin margin is about balls)."""
    mesh = uses_mesh_camera(scene, rules, samples)
    reach = mesh_reach(scene, rules)
    cam = scene.camera.position
    lift = origin_lift(scene, rules) if scene.shapes else 0.0
    out = []
    for s in scene.shapes:
        eps = 1e-10
        if isinstance(s, Ball):
            f = math.dist(cam, s.center) + lift
            eps = max(eps, 2.0**-53 * f * f / (s.radius * s.radius))
            if mesh:
                eps = max(eps, MESH_RAY_ERROR * reach / s.radius)
        out.append(8 * eps)
    return out


# ---------------------------------------------------------------------------------------------
# Exporter: pure functions from (scene, rules) to text


def uses_mesh_camera(scene: Scene, rules: Rules, samples: int = 1) -> bool:
    """The pinhole camera reproduces the exercise's rays unless a shape sits between it and z = 0, or
    the exercise's own samples are asked for (samples > 1: one camera mesh per sample)."""
    return samples > 1 or (rules.ray_origin == "image-plane" and bool(between_camera_and_image_plane(scene)))


MESH_NAME = "MinirtCameraMesh"  # the identifier the exporter declares, with the sample's index appended
MAX_MESH_RAYS = 2**21  # samples x pixels: ~130 bytes of scene text each, ~3.5 s of parsing per million
MESH_TRIANGLE_SIZE = 0.5  # circumradius: large triangles keep the single-precision face normal accurate


def too_many_mesh_rays(scene: Scene, samples: int) -> str | None:
    """Why a mesh camera of ``samples`` meshes is refused for this image, or None."""
    w, h = scene.camera.width, scene.camera.height
    if samples * w * h <= MAX_MESH_RAYS:
        return None
    return (
        f"{samples} samples x {w}x{h} pixels = {samples * w * h} mesh-camera rays, more than {MAX_MESH_RAYS}: "
        "use a smaller image or fewer samples"
    )


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


def _shape_head(s) -> str:
    if isinstance(s, Ball):
        return f"sphere {{ {_v(s.center)}, {_f(s.radius)}"
    return f"plane {{ {_v(s.normal)}, {_f(s.distance)}"  # stored normalised: x·n = distance


def _material(m: Material, scene: Scene, rules: Rules, fx: Effects, channel: int) -> str:
    a = _ambient_numerator(m, scene, rules, fx)
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
        if not fx.diffuse or _grey(dc):
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


def command(
    scene: Scene,
    n_frames: int,
    first: int,
    last: int,
    kind: str,
    stem: str = "out",
    threads: int | None = None,
    antialias: int | None = None,
    mesh_camera: bool = False,
) -> list[str]:
    """The povray command line: frames first..last of an n_frames animation; kind "exr" or "png8".

    ``antialias`` R (1..MAX_ANTIALIAS): ``+A0.0 +R{R}`` -- threshold 0, so every pixel is supersampled
    with POV-Ray's own jittered sub-pixel grid of depth R (method 1, default jitter); None: ``-A``."""
    w, h = scene.camera.width, scene.camera.height
    if mesh_camera:
        h += 1  # POV-Ray gives row j the mesh camera's triangles of row j - 1: the first row is dropped
    aa = ["-A"] if antialias is None else ["+A0.0", f"+R{int(antialias)}"]
    cmd = ["povray", "-D", *aa, "+Q9", f"+W{w}", f"+H{h}"]
    if kind == "exr":
        cmd += ["+FE", "+UA", f"+O{stem}.exr"]
    else:
        cmd += ["+FN8", "File_Gamma=1.0", f"+O{stem}.png"]
    if n_frames > 1:  # an animation: frame_number selects the pass; outputs are numbered stem1, stem2, ...
        cmd += ["+KFI1", f"+KFF{n_frames}", f"+SF{first}", f"+EF{last}"]
    if threads:
        cmd.append(f"+WT{int(threads)}")
    cmd.append("+Iscene.pov")
    return cmd


# ---------------------------------------------------------------------------------------------
# Scenes POV-Ray's pinhole camera cannot reproduce


def _ball_pyramid_distance(scene: Scene, ball: Ball) -> float:
    """Distance from the ball's centre to the pyramid spanned by the camera and the image square z = 0."""
    d = scene.camera.distance
    cx, cy, cz = ball.center

    def dist(z: float) -> float:
        s = 0.5 * (z + d) / d
        return math.hypot(max(abs(cx) - s, 0.0), max(abs(cy) - s, 0.0), z - cz)

    lo, hi = -d, 0.0
    for _ in range(200):  # dist is convex in z (distance to a convex set, minimised over slices)
        m1, m2 = lo + (hi - lo) / 3, hi - (hi - lo) / 3
        if dist(m1) <= dist(m2):
            hi = m2
        else:
            lo = m1
    return min(dist(lo), dist(-d), dist(0.0))


def between_camera_and_image_plane(scene: Scene) -> list[int]:
    """Shapes whose surface reaches into the pyramid between the camera and the image square z = 0.

    There POV-Ray's camera rays and the exercise's image-plane rays can see different things."""
    d = scene.camera.distance
    verts = [(0.0, 0.0, -d)] + [(x, y, 0.0) for x in (-0.5, 0.5) for y in (-0.5, 0.5)]
    out = []
    for k, s in enumerate(scene.shapes):
        if isinstance(s, Ball):
            near = _ball_pyramid_distance(scene, s) <= s.radius * (1 + 1e-9)
            far = max(math.dist(v, s.center) for v in verts)
            if near and far >= s.radius * (1 - 1e-9):  # pyramid wholly inside the ball: same far root
                out.append(k)
        else:
            side = [sum(s.normal[i] * v[i] for i in range(3)) - s.distance for v in verts]
            if min(side) <= 0 <= max(side):
                out.append(k)
    return out


# ---------------------------------------------------------------------------------------------
# Running POV-Ray


class PovrayError(Exception):
    """POV-Ray failed; the message is one line."""


_PARSE_ERR = re.compile(r"^File '[^']*' line (\d+):\s*(.*)$")
_TIME = re.compile(r"^\s*(Parse|Bounding|Trace|Photon|Radiosity) Time:.*\(([\d.]+) seconds\)")


def parse_error(stderr: str) -> str:
    """One line from POV-Ray's output saying what went wrong (its parse error with the line number)."""
    lines = stderr.splitlines()
    for i, ln in enumerate(lines):
        m = _PARSE_ERR.match(ln.strip())
        if m and "error" in ln.lower():
            msg = m.group(2)
            for cont in lines[i + 1 :]:  # POV-Ray wraps messages at 80 columns
                c = cont.strip()
                if not c or c.startswith(("Fatal", "Render failed", "File '")):
                    break
                msg += " " + c
            return f"POV-Ray: scene.pov line {m.group(1)}: {msg}"
    for ln in reversed(lines):
        c = ln.strip()
        if re.search(r"error|failed|cannot|unable", c, re.I) and "user configuration file" not in c:
            return f"POV-Ray: {c}"
    tail = [ln.strip() for ln in lines if ln.strip()]
    return f"POV-Ray: {tail[-1]}" if tail else "POV-Ray failed without a message"


def _timings(stderr: str) -> dict[str, float]:
    out: dict[str, float] = {}
    for ln in stderr.splitlines():
        m = _TIME.match(ln)
        if m:
            key = m.group(1).lower()
            out[key] = out.get(key, 0.0) + float(m.group(2))
    return out


def default_timeout(scene: Scene, frames: int, samples: int = 1) -> float:
    """Seconds one POV-Ray pass may take before it counts as hung: 30 s of start-up and parsing, plus
    10 us per pixel, frame and sample. Measured: three_balls at 1024x1024, 4 frames, 1 sample, traces
    4.2 M pixel-frames in 3.2 s (about 0.75 us each, 2 cores), so this allows a machine or a scene 13x
    slower; a 16384x16384 render gets about 3 hours. The render option "timeout" overrides it."""
    return 30.0 + 1e-5 * scene.camera.width * scene.camera.height * frames * max(1, samples)


def _run(cmd: list[str], cwd: Path, timeout: float) -> tuple[str, dict[str, float]]:
    exe = shutil.which(cmd[0])
    if exe is None:
        raise FileNotFoundError(INSTALL_HINT)
    t0 = time.perf_counter()
    try:
        p = processes.run([exe, *cmd[1:]], cwd=cwd, timeout=timeout)  # dies with minirt (see processes)
    except subprocess.TimeoutExpired:
        raise PovrayError(f"POV-Ray timed out after {timeout:g} s") from None
    wall = time.perf_counter() - t0
    if p.returncode < 0:
        raise PovrayError(f"POV-Ray crashed (signal {-p.returncode}): {parse_error(p.stderr + p.stdout)}")
    if p.returncode != 0:
        raise PovrayError(parse_error(p.stderr + p.stdout))
    tm = _timings(p.stderr + p.stdout)
    inside = tm.get("parse", 0.0) + tm.get("bounding", 0.0) + tm.get("trace", 0.0)
    return p.stderr, {"wall": wall, **tm, "setup": max(wall - inside, 0.0)}


@functools.lru_cache(maxsize=8)
def _version(exe: str, mtime_ns: int, size: int) -> str | RuntimeError:
    """``povray --version`` of one executable, once per process (each call is a ~0.6 s start-up, and a
    check asks for every scene and pass); keyed by the file's path, time and size, so another povray
    on PATH is asked again. A failure is cached too (returned, not raised): a --version that hangs costs
    its time-out once per run, not once per scene."""
    try:  # a --version that hangs is a broken install: 10 s is 15x POV-Ray's own start-up
        p = processes.run([exe, "--version"], timeout=10)
    except subprocess.TimeoutExpired:
        return RuntimeError(f"'{exe} --version' did not answer in 10 s")
    except OSError as e:
        return RuntimeError(f"cannot run '{exe} --version': {e.strerror or e}")
    m = re.search(r"POV-Ray\s+(\d+(?:\.\d+)+)", p.stdout + p.stderr)
    if not m:
        said = " ".join((p.stdout + p.stderr).split())[:80]
        return RuntimeError(f"'{exe} --version' does not say it is POV-Ray (it said: {said!r})")
    return f"POV-Ray {m.group(1)}"


def _frame_files(cwd: Path, stem: str, ext: str) -> dict[int, Path]:
    out = {}
    for p in cwd.glob(f"{stem}*.{ext}"):
        num = p.name[len(stem) : -len(ext) - 1] or "1"  # a single frame is not numbered
        if num.isdigit():
            out[int(num)] = p
    return out


# ---------------------------------------------------------------------------------------------
# The oracle


class PovrayOracle(Oracle):
    name: ClassVar[str] = NAME
    shades: ClassVar[bool] = True
    display_name: ClassVar[str] = "POV-Ray"
    shading_model: ClassVar[str | None] = "exercise"
    concurrent: ClassVar[bool] = True  # its render is a process of its own: it overlaps the others' in a check
    # a check keeps its render and figures (1,400 bytes a pixel); a render keeps 60 and runs with 40 (its
    # working buffers are in its own process): measured with the others (minirt.jobs.memory)
    check_kept: ClassVar[int] = 1400
    render_kept: ClassVar[int] = 60
    render_running: ClassVar[int] = 40
    export_as: ClassVar[str | None] = "povray"
    export_what: ClassVar[str] = ".pov + command"
    supported: ClassVar[dict[str, tuple[Any, ...]]] = {
        # folded into ambient, or a background statement; "none": neither
        "background": ("on-hit", "on-miss", "none"),
        "near_root_only": (False,),  # it sees the inside of balls
        "shadow_range": ("to-light",),  # only objects before the light block
        "two_sided": (True,),  # normals flipped to face the viewer
        "clamp": (True,),  # light skipped when n·l < 1e-10, phong only when r·l > 0
        "offset": ("error-bound",),  # its own epsilons (1e-3 for shadow rays): the closest rule
        "offset_along": ("normal",),  # (its epsilons are distances along the ray; "ray" needs a number)
        "ray_origin": ("image-plane", "camera"),  # image-plane: skip when something is in between
        "pixel_sample": ("corner", "center"),  # skewed or plain direction vector
        # The skewed direction vector is written for the unshifted grid only (the mesh camera would follow).
        "pixel_shift": ((0.0, 0.0),),
        # specular_exponent: any, as phong_size (POV-Ray's phong is (r·l)^phong_size, only where r·l > 0).
    }

    def available(self) -> tuple[bool, str]:
        if shutil.which("povray") is None:
            return False, INSTALL_HINT
        try:
            return True, self.version()
        except Exception as e:  # a broken install: say so, do not raise
            return False, f"povray found but not runnable: {e}"

    def version(self) -> str:
        exe = shutil.which("povray")
        if exe is None:
            raise FileNotFoundError(INSTALL_HINT)
        st = os.stat(exe)
        v = _version(exe, st.st_mtime_ns, st.st_size)
        if isinstance(v, Exception):
            raise v
        return v

    # ---- render -------------------------------------------------------------------------
    def options(self, precision: str = "f64", samples: int | None = None, timeout: float | None = None) -> dict:
        """--timeout SECONDS: POV-Ray's process is killed after that long (an ERROR verdict)."""
        opts: dict[str, Any] = {"precision": precision}
        if timeout is not None:
            opts["timeout"] = timeout
        return opts

    def geometry_tolerance(self, result: RenderResult, ref: RenderResult, measured: Margins) -> GeometryTolerance:
        """This oracle's recorded precision as per-pixel tolerances, each with its derivation."""
        h, w = ref.height, ref.width
        p = result.meta.get("precision") or {}
        m = measured.image(h, w)
        t_ref = np.where(ref.hit, ref.t, 0.0)
        ties = None
        eps = p["band_threshold"]
        # its minimum distance along the harness's rays and its position error there (oracles.povray.start_decision)
        t_min, start_err = p.get("min_distance", 0.0), p.get("start_err", 0.0)
        starts = measured.start_band(h, w, t_min=t_min, plane_err=start_err, ball_err=start_err)
        if measured.scaled is not None and p.get(
            "band_scale"
        ):  # each shape's own threshold (oracles.povray.band_scales)
            band, ties = measured.per_shape_band(p, h, w)
            band = band | starts
        else:
            band = (m["margin"] < eps) | starts
        # POV-Ray drops hits beyond MAX_DISTANCE 1e7 from its ray's origin (a pinhole ray's origin is the
        # camera, up to max_distance_lift before the harness's): where the nearest candidate lies that far,
        # POV-Ray misses what the reference hits -- a decision it cannot make, like its minimum distance
        # (fuzz far_2026_6: rays starting just inside a ground of radius 4.5e7 meet its far side 1.04e7 away).
        if "max_distance" in p:
            band |= np.isfinite(m["near"]) & (m["near"] >= farthest_hit(p))
        # plus the conditioning of the hit: a ray whose origin and direction err by dir_err (R + t) -- the mesh
        # camera's single-precision rays, R its origins' reach -- meets a surface dir_err (R + t)/cos away, cos = |n·d|
        # at the hit, ball or plane (fuzz start_2026_83: a ball met at an angle, dt 1.65e-6 > t_abs 1.54e-6)
        # and POV-Ray's own sphere root, 12 2^-53 |f|^2/(r cos) along the ray (oracles.povray.root_errors; fuzz
        # f32_2026_22: a ball 2.4e4 away, its hit 8.6e-7 off along the ray near its silhouette), which turns
        # the normal (P - C)/r by as much over r
        root = np.zeros((h, w))
        root_n = np.zeros((h, w))
        if p.get("root_err"):
            # ids the scene does not have (a defective reference's, fuzz --defects ids-swapped on a one-ball
            # scene) get no root term: those pixels are id mismatches, never compared in t or normal
            n_shapes = len(p["root_err"])
            ids = np.where(ref.hit & (ref.shape_id < n_shapes), ref.shape_id, -1)
            k = np.maximum(ids, 0)
            per_t = np.asarray(p["root_err"], dtype=np.float64)[k]
            per_n = np.asarray(p.get("root_normal_err", np.zeros(len(p["root_err"]))), dtype=np.float64)[k]
            with np.errstate(divide="ignore", invalid="ignore"):
                root = np.where(ids >= 0, per_t / m["hit_cos"], 0.0)
                root_n = np.where(ids >= 0, per_n / m["hit_cos"], 0.0)
        with np.errstate(divide="ignore"):
            t_abs = p["t_abs"] + p.get("dir_err", 0.0) * (p.get("ray_reach", 1.0) + t_ref) / m["hit_cos"] + root
        deg = math.degrees(math.asin(min(1.0, 2 * p["normal_abs"]))) + 1e-9
        nd = np.degrees(np.arcsin(np.minimum(1.0, 2 * (p["normal_abs"] + root_n)))) + 1e-9
        why = {
            "band": f"margin < each shape's own threshold (at most {eps:.3g}): single-precision bounding boxes "
            "and textbook sphere roots in POV-Ray, its mesh camera's single-precision rays; "
            f"or a candidate hit with t cos within {start_err:.3g} of [0, {t_min:.3g}] (POV-Ray drops hits within "
            "its minimum distance 1e-4 of a mesh-camera ray's origin; its rays are off by start_err there)",
            "t": f"|dt| <= {p['t_abs']:.3g} + {p.get('dir_err', 0.0):.3g}*(R + t)/|n·d| (n at the hit, R = ray_reach) "
            "+ 12 2^-53 |f|^2/(r |n·d|) (POV-Ray's textbook sphere root, |f| from its ray's origin to the centre): "
            f"{p.get('derivation', '')}",
            "normal": f"{deg:.3g} deg: normals from decoded positions, |dn| <= {p['normal_abs']:.3g}, plus per pixel "
            "POV-Ray's root error over r: 12 2^-53 |f|^2/(r^2 |n·d|)",
        }
        summary = {
            "band_eps": eps,
            "t_abs": p["t_abs"],
            "normal_deg": deg,
            "min_distance": t_min,
            "start_band_pixels": int(starts.sum()),
        }
        return GeometryTolerance(band=band, t_abs=t_abs, normal_deg=nd, why=why, summary=summary, ties=ties)

    def render(self, scene: Scene, rules: Rules, options: dict[str, Any] | None = None, progress=None) -> RenderResult:
        opts = dict(options or {})
        w, h = scene.camera.width, scene.camera.height
        meta: dict[str, Any] = {"scene": scene.name, "rules": rules.as_dict(), "options": opts}

        def fail(status: str, reason: str) -> RenderResult:
            extra = {k: v for k, v in meta.items() if k != "backend"}
            return RenderResult.failed(NAME, w, h, status, reason, **extra)

        if shutil.which("povray") is None:
            return fail("skip", INSTALL_HINT)
        bad = self.cannot_follow(rules)
        if bad:
            return fail("skip", f"POV-Ray cannot follow rule(s): {', '.join(bad)}")
        samples = opts.get("samples", 1)
        if not (isinstance(samples, int) and not isinstance(samples, bool) and samples >= 1):
            return fail("error", f"samples must be an integer >= 1, got {samples!r}")
        if opts.get("antialias") is not None and samples > 1:
            return fail("error", "antialias and samples exclude each other (POV-Ray's own grid, or the exercise's)")
        too_many = too_many_mesh_rays(scene, samples)
        if too_many:
            return fail("skip", too_many)
        if opts.get("antialias") is not None and uses_mesh_camera(scene, rules):
            between = ", ".join(map(str, between_camera_and_image_plane(scene)))
            return fail("skip", f"object between camera and image plane (shape {between}) needs a mesh camera, "
                                "which cannot antialias")  # fmt: skip
        try:
            return self._render(scene, rules, opts, meta)
        except FileNotFoundError as e:
            return fail("skip", (str(e).splitlines() or [INSTALL_HINT])[0])
        except PovrayError as e:
            return fail("error", str(e))
        except Exception as e:  # never raise out of render()
            msg = (str(e).splitlines() or [""])[0]
            return fail("error", f"{type(e).__name__}: {msg}")

    def _render(self, scene: Scene, rules: Rules, opts: dict[str, Any], meta: dict[str, Any]) -> RenderResult:
        w, h = scene.camera.width, scene.camera.height
        samples = opts.get("samples", 1)
        threads = opts.get("threads")
        geometry = bool(opts.get("geometry", True))
        antialias = opts.get("antialias")
        if samples > 1:
            # The exercise's samples: colour only (an average of positions is no position), like antialias.
            geometry = False
        if antialias is not None:
            ok = isinstance(antialias, int) and not isinstance(antialias, bool) and 1 <= antialias <= MAX_ANTIALIAS
            if not ok:
                raise ValueError(f"antialias must be an integer in 1..{MAX_ANTIALIAS}, got {antialias!r}")
            # Antialiased renders are colour only: supersampling jitters the geometry passes' encodings
            # (an average of positions is no position), and the 8-bit PNG pass would pay the start-up twice.
            geometry = False
        t_start = time.perf_counter()
        fx = effects(scene, rules)
        cframes = color_frames(scene, rules)
        gframes = geometry_frames(scene) if geometry and scene.shapes else []
        frames = cframes + gframes
        timeout = float(opts.get("timeout") or default_timeout(scene, len(frames), samples))
        ranges = encoding_ranges(scene, rules) if gframes else None
        text = scene_to_pov(scene, rules, frames, ranges, samples)
        mesh = uses_mesh_camera(scene, rules, samples)
        meta.update(
            backend=NAME,
            version=self.version(),
            # one ray per pixel (-A): POV-Ray's antialiasing jitters its own grid, not the exercise's pattern
            settings={"width": w, "height": h, "max_depth": scene.max_depth, "timeout": timeout,
                      "samples_requested": scene.samples, "samples_rendered": samples if antialias is None else None,
                      "sampling": ("the exercise's stratified samples, one camera mesh each" if samples > 1 else
                                   "POV-Ray's jittered antialiasing grid" if antialias is not None else "one ray"),
                      "antialias": antialias,
                      "channel_mode": "per-channel" if len(cframes) == 3 else "rgb",
                      "frames": [f.label for f in frames], "max_trace_level": scene.max_depth + 1 if fx.reflection
                      else 1, "camera": "mesh_camera" if mesh else "perspective"},
            effects={"simulated": fx.simulated(), "skipped": fx.skipped(), **fx.as_dict()},
        )  # fmt: skip
        passes: list[dict[str, Any]] = []
        timings: dict[str, Any] = {"export": time.perf_counter() - t_start}
        with processes.temporary_folder("minirt-povray-") as cwd:
            (cwd / "scene.pov").write_text(text)
            n = len(frames)
            # One EXR animation: float colour frames and geometry frames, +UA for the hit mask.
            cmd_exr = command(scene, n, 1, n, "exr", threads=threads, antialias=antialias, mesh_camera=mesh)
            png_pass = antialias is None
            # The 8-bit PNG of the colour frames: POV-Ray's own rounding, exact. The two passes are
            # independent processes (their own output files, the same .pov read): run side by side, so
            # one's single-threaded parse and start-up overlap the other's trace (both cores busy).
            cmd_png = (
                command(scene, n, 1, len(cframes), "png8", threads=threads, mesh_camera=mesh) if png_pass else None
            )
            with ThreadPoolExecutor(max_workers=2) as pool:
                jobs = [pool.submit(_run, c, cwd, timeout) for c in (cmd_exr, cmd_png) if c is not None]
                done = [j.result() for j in jobs]  # the first failure raises, in pass order
            passes.append({"name": "exr", "frames": [f.label for f in frames], "command": shlex.join(cmd_exr),
                           "timings": done[0][1]})  # fmt: skip
            if cmd_png is not None:
                passes.append({"name": "png8", "frames": [f.label for f in cframes],
                               "command": shlex.join(cmd_png), "timings": done[1][1]})  # fmt: skip
            t0 = time.perf_counter()
            exr = _frame_files(cwd, "out", "exr")
            png = _frame_files(cwd, "out", "png") if png_pass else {}
            missing = [i for i in range(1, n + 1) if i not in exr] + [
                i for i in range(1, len(cframes) + 1) if png_pass and i not in png
            ]
            if missing:
                raise PovrayError(f"POV-Ray wrote no output for frame(s) {sorted(set(missing))}")
            first = 1 if mesh else 0  # the mesh camera's extra first row (see command)

            def read(path: Path, u8: bool = False) -> np.ndarray:
                try:
                    img = (read_image_u8(path) if u8 else read_image(path)[0])[first:]
                except MinirtError as e:  # the file POV-Ray left is cut short or is not an image
                    said = str(e).replace(str(path), path.name)
                    raise PovrayError(f"POV-Ray wrote a truncated or corrupt {path.name} ({said})") from None
                if img.shape[:2] != (h, w):
                    got = f"{img.shape[1]}x{img.shape[0] + first}"
                    raise PovrayError(f"POV-Ray wrote {path.name} at {got}, not the {w}x{h + first} asked for")
                return img

            color = np.zeros((h, w, 3))
            color8: np.ndarray | None = np.zeros((h, w, 3), dtype=np.uint8) if png_pass else None
            for i, f in enumerate(cframes, start=1):
                img = read(exr[i])
                img8 = read(png[i], u8=True) if png_pass else None
                if f.index < 0:
                    color = img[..., :3].astype(np.float64)
                    if img8 is not None:
                        color8 = img8[..., :3].copy()
                else:
                    color[..., f.index] = img[..., 0]
                    if img8 is not None and color8 is not None:
                        color8[..., f.index] = img8[..., 0]
            geom: dict[str, np.ndarray] = {}
            if gframes:
                imgs = [read(exr[len(cframes) + 1 + g]) for g in range(len(gframes))]
                geom = decode_geometry(scene, rules, imgs, ranges)
            timings["decode"] = time.perf_counter() - t0
        # The passes run side by side: setup, parse and trace are sums over them (each process's own
        # time), total is the wall time of the whole render.
        timings["passes"] = {p["name"]: p["timings"] for p in passes}
        timings["setup"] = sum(p["timings"]["setup"] for p in passes)
        timings["trace"] = sum(p["timings"].get("trace", 0.0) for p in passes)
        timings["parse"] = sum(p["timings"].get("parse", 0.0) for p in passes)
        timings["total"] = time.perf_counter() - t_start
        meta.update(passes=passes, commands=[p["command"] for p in passes], timings=timings)
        if gframes or geometry or samples > 1:  # geometry asked for (even with no shapes), or the exercise's samples
            meta["precision"] = precision(scene, ranges or [None] * len(scene.shapes), mesh, mesh_reach(scene, rules))
            inside = band_inside_scales(scene, rules, samples)
            root = root_errors(scene, rules)
            meta["precision"].update(
                band_threshold=band_threshold(scene, rules, samples, inside),
                band_scale=band_scales(scene, rules, samples),
                band_origin_scale=band_origin_scales(scene, rules, samples),
                band_inside_scale=inside,
                root_err=root,
                root_normal_err=[
                    e / s.radius if isinstance(s, Ball) else 0.0 for e, s in zip(root, scene.shapes, strict=True)
                ],
                max_distance=MAX_DISTANCE,
                max_distance_lift=0.0 if mesh else origin_lift(scene, rules),
                **start_decision(scene, rules, mesh),
            )
        if gframes:
            meta["encoding_ranges"] = ranges
            # pixels where the three frames' alpha and the id channel disagree on hit/miss (expected 0)
            meta["hit_consistency"] = geom.pop("hit_mismatch")
            meta["surface_residual"] = geom.pop("surface_residual")
        else:
            miss = np.zeros((h, w), dtype=bool)
            geom = {"hit": miss, "shape_id": np.full((h, w), -1, np.int32), "t": np.full((h, w), np.inf),
                    "position": np.zeros((h, w, 3)), "normal": np.zeros((h, w, 3))}  # fmt: skip
        # POV-Ray's own 8-bit image (exact rounding; rounding the half-float colour flips .5 ties); antialiased
        # renders have none (color8() then rounds the half-float colour)
        return RenderResult(backend=NAME, width=w, height=h, color=color, image8=color8, meta=meta, **geom)

    # ---- export ---------------------------------------------------------------------------
    def export(self, scene: Scene, rules: Rules, out_dir: Path, options: dict[str, Any] | None = None) -> list[Path]:
        return export(scene, rules, out_dir)

    # ---- the sweep (minirt.sweep): what accuracy costs in time ---------------------------------
    sweep_knobs: ClassVar[dict[str, Any]] = {
        "antialias": (0, 1, 2, 3, 4),  # 0: antialiasing off (-A); R > 0: +A0.0 +R{R}
        # the exercise's samples through POV-Ray's mesh camera (64 at 256² passes its ray limit)
        "samples": (1, 4, 16),
        "converged_spp": 1024,  # the reference's samples for the converged answer
    }
    SWEEP_STAGES = ("parse", "bounding", "photon", "radiosity", "trace")  # its own statistics (1 ms steps)
    SWEEP_RESOLUTION = 0.001

    def sweep(self, scene: Scene, rules: Rules, knobs: dict[str, Any]) -> list[Series]:
        """Two knobs, both measured against the reference at 1024 spp under POV-Ray's rules:

        - antialias: off, +A0.0 +R1 ... +R4. Method 1 with threshold 0 supersamples every pixel on an
          R x R jittered grid *plus* its centre ray, averaged with weight 1/(R^2 + 1) each
          (``tracetask.cpp`` SupersampleOnePixel), so its cost in rays per pixel is R^2 + 1 and it
          converges to a centre-weighted average, not the box the reference averages: expect a floor.
          Its pixel square is centred on the ray it shoots, so POV-Ray and its converged reference are
          rendered with rule ``pixel_sample = "center"`` (with "corner" the skewed camera shifts the
          supersampled square by half a pixel against the reference's samples).
        - samples: 1, 4, 16 (the exercise's stratified samples), pixel corner: POV-Ray renders the
          reference's own samples through its mesh camera, so it converges as the reference's spp does.

        The rows are colour only (no geometry frames, no 8-bit pass): one POV-Ray invocation per render.
        Time (``_sweep_seconds``): POV-Ray starts a process per render (~0.65 s whatever the size,
        measured from its own statistics): that start-up is its ``seconds_setup`` and is *not* in its
        ``seconds_median`` (the time inside POV-Ray: parse, bounding, trace); ``seconds_total`` has both.
        Its statistics count whole milliseconds: a median below 1 ms is recorded *at* 1 ms, an upper
        bound (``seconds_at_resolution``)."""
        from dataclasses import replace

        k = self.turned(knobs)
        n = k["converged_spp"]
        f64 = {"precision": "f64"}
        centre = replace(self.adapt(rules), pixel_sample="center")
        corner = self.adapt(rules)
        antialias = tuple(
            Setting(r, r * r + 1 if r else 1, {"geometry": False} if r == 0 else {"antialias": r},
                    "POV-Ray -A (antialiasing off)" if r == 0 else f"POV-Ray +A0.0 +R{r}",
                    "povray antialias off" if r == 0 else f"povray +A0.0 +R{r}")
            for r in k["antialias"]
        )  # fmt: skip
        # The exercise's own samples (pixel corner, the rules' own pixel square): its converged answer is
        # the reference under the same rules.
        samples = tuple(
            Setting(m, m, {"geometry": False, "samples": m},
                    f"POV-Ray with the exercise's {m} sample{'s' if m != 1 else ''} (mesh camera)",
                    f"povray {m} exercise samples")
            for m in k["samples"]
        )  # fmt: skip
        ref = "reference"  # the converged answers are the reference tracer's
        return [
            Series(self.name, "antialias", antialias, centre,
                   Truth(f"reference/{n}spp/povray-rules", ref, f64, samples=n, rules=centre,
                         describe={"precision": "f64", "spp": n}),
                   "color", metric="rmse", cost="rays per pixel (R^2 + 1)",
                   theory="~(R^2+1)^-0.75 (jittered grid, edges) down to a floor (centre-weighted filter)",
                   knobs={"povray_antialias": k["antialias"], "converged_reference_spp": n},
                   seconds=self._sweep_seconds),
            Series(self.name, "samples", samples, corner,
                   Truth(f"reference/{n}spp/povray-rules-corner", ref, f64, samples=n, rules=corner,
                         describe={"precision": "f64", "spp": n}),
                   "color", metric="rmse", cost="rays per pixel",
                   theory="as reference/spp: the same stratified samples, at POV-Ray's cost per ray",
                   knobs={"povray_samples": k["samples"], "converged_reference_spp": n},
                   seconds=self._sweep_seconds),
        ]  # fmt: skip

    @classmethod
    def _sweep_seconds(cls, res: RenderResult) -> tuple[float, float, float]:
        """(time inside POV-Ray, the process's start-up, its statistics' resolution) of one render."""
        tm = res.meta.get("timings", {})
        if "passes" not in tm:
            return float(tm.get("wall", math.nan)), 0.0, 0.0
        # the EXR pass is the image; the unantialiased render adds an 8-bit PNG pass (exact rounding only)
        passes = [tm["passes"]["exr"]] if "exr" in tm["passes"] else list(tm["passes"].values())
        work = sum(p.get(k, 0.0) for p in passes for k in cls.SWEEP_STAGES)
        return round(work, 6), sum(p["wall"] for p in passes) - work, cls.SWEEP_RESOLUTION


def decode_geometry(
    scene: Scene, rules: Rules, imgs: list[np.ndarray], ranges: list[dict[str, tuple[float, float]]]
) -> dict[str, Any]:
    """Buffers from the geometry frames (RGBA half floats; three, or four with the id's high part)."""
    h, w = imgs[0].shape[:2]
    ch: dict[tuple[str, str], np.ndarray] = {}
    for g, img in enumerate(imgs):
        for c, (q, part) in enumerate(zip(GEOMETRY_FRAMES[g], GEOMETRY_PARTS[g], strict=True)):
            ch[(q, part)] = img[..., c].astype(np.float64)
    alphas = [img[..., 3] > 0.5 for img in imgs]
    hit = alphas[0]
    hi = np.rint(ch[("id", "hi")] * ID_SCALE) if ("id", "hi") in ch else 0.0
    sid = (np.rint(ch[("id", "")] * ID_SCALE) + ID_SCALE * hi).astype(np.int32) - 1
    mismatch = int(sum(np.count_nonzero(a != hit) for a in alphas[1:]) + np.count_nonzero((sid >= 0) != hit))
    sid = np.where(hit, sid, -1)
    pos = np.zeros((h, w, 3))
    t = np.full((h, w), np.inf)
    nrm = np.zeros((h, w, 3))
    residual: dict[str, float] = {}  # self-check: distance of decoded points from their surface
    for k, s in enumerate(scene.shapes):
        m = sid == k
        if not m.any():
            continue
        vals = {}
        for q in ("x", "y", "z", "t"):
            lo, hi = ranges[k][q] if ranges[k] is not None else (0.0, 1.0)
            v1024 = np.rint(ch[(q, "coarse")][m] * SPLIT) + ch[(q, "fine")][m]
            vals[q] = lo + v1024 * ((hi - lo) / SPLIT)
        p = np.stack([vals["x"], vals["y"], vals["z"]], axis=-1)
        pos[m] = p
        t[m] = vals["t"]
        if isinstance(s, Ball):
            nrm[m] = (p - np.array(s.center)) / s.radius
            residual[str(k)] = float(np.abs(np.linalg.norm(p - np.array(s.center), axis=-1) - s.radius).max())
        else:
            nrm[m] = np.array(s.normal)
            residual[str(k)] = float(np.abs(p @ np.array(s.normal) - s.distance).max())
    return {"hit": hit, "shape_id": sid, "t": t, "position": pos, "normal": nrm, "hit_mismatch": mismatch,
            "surface_residual": residual}  # fmt: skip


def export(scene: Scene, rules: Rules, out_dir: str | Path) -> list[Path]:
    """Write ``scene.pov`` (the colour pass(es)), ``render.sh`` with the exact command and a README."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    frames = color_frames(scene, rules)
    pov = out / "scene.pov"
    pov.write_text(scene_to_pov(scene, rules, frames))
    mesh = uses_mesh_camera(scene, rules)
    cmd = shlex.join(command(scene, len(frames), 1, len(frames), "png8", mesh_camera=mesh))
    sh = out / "render.sh"
    header = "# Render scene.pov with POV-Ray 3.7 (linear 8-bit PNG, no antialiasing)"
    sh.write_text(f'#!/bin/sh\n{header}\ncd "$(dirname "$0")"\n{cmd}\n')
    sh.chmod(0o755)
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
    readme.write_text(f"Render with: {cmd}\nOutput: {output} (linear, File_Gamma 1.0).{note}\n")
    return [pov, sh, readme]
