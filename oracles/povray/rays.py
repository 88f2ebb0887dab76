"""POV-Ray's rays against the exercise's: which camera reproduces them, how far off its rays are, and
which hits POV-Ray drops along them.

- A pinhole camera (the exporter's ``perspective`` camera) shoots from the camera; the exercise's rays
  start on the image plane z = 0. The two see the same unless a shape reaches into the pyramid between
  camera and image square (:func:`between_camera_and_image_plane`); then, and for the exercise's own
  samples, a ``mesh_camera`` is used (:func:`uses_mesh_camera`), whose single-precision triangles put
  its rays MESH_RAY_ERROR (R + t) off (:func:`mesh_reach` is R). At most MAX_MESH_RAYS of them.
- POV-Ray drops hits beyond MAX_DISTANCE and nearer than MIN_ISECT_DEPTH to its ray's origin.
"""

from __future__ import annotations

import math

import numpy as np

from minirt.model import camera
from minirt.model.rules import Rules
from minirt.model.scene import Ball, Scene

MAX_DISTANCE = 1e7  # POV-Ray drops hits beyond this (configbackend.h MAX_DISTANCE)
MIN_ISECT_DEPTH = 1e-4  # ... and hits nearer than this to the ray's origin (configcore.h MIN_ISECT_DEPTH)
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
MAX_MESH_RAYS = 2**21  # samples x pixels: ~130 bytes of scene text each, ~3.5 s of parsing per million


def pinhole_directions(scene: Scene, rules: Rules) -> np.ndarray:
    """The primary rays' directions (N, 3) as from a pinhole at the camera (ray_origin "camera"): what
    POV-Ray's camera shoots, whatever the rules' ray origin."""
    from dataclasses import replace

    _, d = camera.primary_rays(scene, replace(rules, ray_origin="camera"))
    return d


def mesh_reach(scene: Scene, rules: Rules) -> float:
    """R of MESH_RAY_ERROR (R + t): max(1, |P|) over the mesh camera's ray origins."""
    return 1.0 if rules.ray_origin == "image-plane" else max(1.0, float(np.linalg.norm(scene.camera.position)))


def uses_mesh_camera(scene: Scene, rules: Rules, samples: int = 1) -> bool:
    """The pinhole camera reproduces the exercise's rays unless a shape sits between it and z = 0, or
    the exercise's own samples are asked for (samples > 1: one camera mesh per sample)."""
    return samples > 1 or (rules.ray_origin == "image-plane" and bool(between_camera_and_image_plane(scene)))


def too_many_mesh_rays(scene: Scene, samples: int) -> str | None:
    """Why a mesh camera of ``samples`` meshes is refused for this image, or None."""
    w, h = scene.camera.width, scene.camera.height
    if samples * w * h <= MAX_MESH_RAYS:
        return None
    return (
        f"{samples} samples x {w}x{h} pixels = {samples * w * h} mesh-camera rays, more than {MAX_MESH_RAYS}: "
        "use a smaller image or fewer samples"
    )


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
