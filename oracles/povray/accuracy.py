"""What POV-Ray's numbers are worth: the precision of the decoded buffers and POV-Ray's own arithmetic,
recorded with every render in ``meta["precision"]`` and turned into per-pixel tolerances by
PovrayOracle.geometry_tolerance.

- The encoding: a decoded quantity errs by (FINE_ERROR / SPLIT) of its range (:func:`precision`).
- The rays: the mesh camera's single-precision rays err by MESH_RAY_ERROR (R + t); the pinhole's by
  2^-22 (R + t) (measured; ``dir_err``).
- The decisions POV-Ray takes in its own precision, per shape, as K eps for minirt.reference.band:
  its double-precision textbook sphere discriminant (:func:`band_scales`, :func:`root_errors`), its
  single-precision bounding boxes (:func:`band_inside_scales`, from BOUNDING_THRESHOLD finite objects
  on), whether a ray starts inside a ball (:func:`band_origin_scales`), and its minimum distance
  (:func:`start_decision`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from minirt.model import camera
from minirt.model.rules import Rules
from minirt.model.scene import Ball, Scene
from minirt.oracles.povray.buffers import FINE_ERROR, HALF_REL, SPLIT
from minirt.oracles.povray.rays import (
    MESH_RAY_ERROR,
    MIN_ISECT_DEPTH,
    mesh_reach,
    pinhole_directions,
    uses_mesh_camera,
)

BOUNDING_THRESHOLD = 3  # with this many finite objects or more POV-Ray builds its bounding tree (+MB default)


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
    dz = float(pinhole_directions(scene, rules)[:, 2].min())
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
