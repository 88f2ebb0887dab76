"""The interface every oracle implements: minirt.model.backend's Backend, which the reference tracer
implements too. An oracle is an established renderer; its module (or its package's __init__.py) says, at
the top, the conventions it had to bridge, and its class why each of its tolerances is what it is
(geometry_tolerance, beside the derivations). Oracles import only the core (minirt.model, minirt.io,
minirt.jobs, minirt.jit)."""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np

from minirt.model.backend import Backend
from minirt.model.scene import Ball, Scene


class Oracle(Backend):
    """An established renderer behind the Backend interface."""


def plane_frame(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A right-handed orthonormal frame (t1, t2) with t1 x t2 = n (Duff et al.'s branchless form): the
    axes of a plane's quad, for every oracle that draws planes as quads (Mitsuba, Cycles)."""
    sign = math.copysign(1.0, n[2])
    a = -1.0 / (sign + n[2])
    b = n[0] * n[1] * a
    t1 = np.array([1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0]])
    t2 = np.array([b, sign + n[1] * n[1] * a, -n[1]])
    return t1, t2


def materials_use(scene: Scene, term: str) -> bool:
    """Does some shape's material have a non-zero ``term`` ("ambient", "specular", "reflection", ...)? What
    an oracle whose renderer has no such term (a physical one) must say it leaves out."""
    return any(any(v != 0 for v in getattr(s.material, term)) for s in scene.shapes)


def median_light_distance(scene: Scene, o: np.ndarray, d: np.ndarray, t: np.ndarray) -> float | None:
    """The median distance from the light to the hit points o + t d of the rays with a finite t; None when
    no ray hits. The distance at which an export's light, scaled by pi d^2, gives the exercise's brightness
    (Mitsuba's and Cycles' viewing_distance)."""
    hit = np.isfinite(t)
    if not hit.any():
        return None
    p = o[hit] + t[hit, None] * d[hit]
    return float(np.median(np.linalg.norm(p - np.asarray(scene.light.position, dtype=np.float64), axis=1)))


def ball_silhouette_margins(
    scene: Scene, o: np.ndarray, d: np.ndarray, shape_id: np.ndarray
) -> Iterator[tuple[np.ndarray, Ball, np.ndarray, np.ndarray]]:
    """For each ball some ray hit: (the rays on it, the ball, f = o - C per ray, the relative margin
    m = |r - h| / r of each ray's distance h from the centre, at least 1e-30). A float32 sphere root's t
    error grows as 1/sqrt(m) near the silhouette; each oracle bounds it from these (its silhouette_t_bound)."""
    for k, s in enumerate(scene.shapes):
        on = shape_id == k
        if not isinstance(s, Ball) or not on.any():
            continue
        f = o[on] - np.asarray(s.center)
        b = np.einsum("ij,ij->i", f, d[on])
        hh = np.linalg.norm(f - b[:, None] * d[on], axis=1)
        yield on, s, f, np.maximum(np.abs(s.radius - hh) / s.radius, 1e-30)
