"""The rectangles standing in for the exercise's infinite planes (pure NumPy; the package docstring's
"Planes" says why and how).

Mitsuba has no infinite plane, and its ``rectangle`` (local [-1,1]^2, normal +z, to_world =
[S_u t1, S_v t2, n, c]) is a two-triangle mesh whose hit points are interpolated from float32 corners:
its absolute error grows like 8 u32 (|c| + |S|) (PlaneRect.abs_error). So each rectangle is the
smallest covering every point a ray of this view can hit: :func:`plane_frames` sizes it from the
primary rays' hits, the balls' and the light's projections; the ray route grows it after tracing
(rays.py) and renders again. The sensor route cannot, so :func:`sensor_frames` sizes it for every
pixel square's corner rays and every first shadow segment up front. Boxes are padded by _PAD of
their size.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from minirt.model import camera
from minirt.model.rules import Rules
from minirt.model.scene import Ball, Plane, Scene
from minirt.oracles.base import plane_frame
from minirt.oracles.mitsuba.accuracy import DIR_ERR, U32

_PAD = 1e-3


class PlaneRect:
    """The rectangle standing in for one plane: frame, centre (in plane coordinates) and half-sizes."""

    def __init__(self, plane: Plane):
        self.n = np.asarray(plane.normal, dtype=np.float64)
        self.q = np.asarray(plane.point, dtype=np.float64)
        self.t1, self.t2 = plane_frame(self.n)
        self.lo = np.array([np.inf, np.inf])
        self.hi = np.array([-np.inf, -np.inf])

    def uv(self, p: np.ndarray) -> np.ndarray:
        r = np.atleast_2d(p) - self.q
        return np.stack([r @ self.t1, r @ self.t2], axis=1)

    def include(self, p: np.ndarray) -> bool:
        """Grow the box to contain points p (N, 3); True if it grew."""
        p = np.atleast_2d(p)
        p = p[np.all(np.isfinite(p), axis=1)]
        if len(p) == 0:
            return False
        uv = self.uv(p)
        lo, hi = np.minimum(self.lo, uv.min(axis=0)), np.maximum(self.hi, uv.max(axis=0))
        grew = bool(np.any(lo < self.lo) or np.any(hi > self.hi))
        self.lo, self.hi = lo, hi
        return grew

    def outside(self, p: np.ndarray) -> np.ndarray:
        """Which points p (N, 3) lie outside the (padded) rectangle."""
        uv = self.uv(p)
        c, s = self.centre_uv(), self.half()
        return np.any(np.abs(uv - c) > s, axis=1)

    def centre_uv(self) -> np.ndarray:
        return (self.lo + self.hi) / 2

    def half(self) -> np.ndarray:
        h = (self.hi - self.lo) / 2
        return h * (1 + _PAD) + _PAD * max(float(np.max(h)), 1.0)

    def to_world(self) -> np.ndarray:
        cu, cv = self.centre_uv()
        su, sv = self.half()
        c = self.q + cu * self.t1 + cv * self.t2
        m = np.eye(4)
        m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = su * self.t1, sv * self.t2, self.n, c
        return m

    def abs_error(self) -> float:
        """Bound on the hit point's absolute error: corners of magnitude |c| + |S| interpolated in float32."""
        m = self.to_world()
        return 8 * U32 * (float(np.linalg.norm(m[:3, 3])) + float(np.hypot(*self.half())))

    def normal_error(self) -> float:
        """Bound on the error of a point's signed distance from the rectangle, which decides t >= 0: Mitsuba
        takes the ray to the rectangle's frame (to_object, float32) and solves t = -o.z / d.z. The local z
        row of to_object is the unit normal with offset -n·c; rounding the centre c to float32 and the
        inverse's cofactors (whose relative error is a few u, the in-plane scales cancelling) moves that
        offset by a few u |c|: 8 u32 |c|. The half size does not enter (it scales x and y only), so a
        rectangle 3.5e6 wide with its centre 2.4e6 away errs by 1.1 across its plane, not 2.3 (fuzz
        shadow_within_position_error: with abs_error its start band held 806 of 1032 hit pixels, now 0)."""
        return 8 * U32 * float(np.linalg.norm(self.to_world()[:3, 3]))

    def describe(self) -> dict[str, Any]:
        m = self.to_world()
        return {
            "centre": m[:3, 3].tolist(),
            "half_size": self.half().tolist(),
            "abs_error": self.abs_error(),
            "normal_error": self.normal_error(),
        }


def plane_hits(plane: PlaneRect, o: np.ndarray, d: np.ndarray) -> np.ndarray:
    """t of each ray with the infinite plane (float64), inf when parallel or behind."""
    nd = d @ plane.n
    with np.errstate(divide="ignore", invalid="ignore"):
        t = ((plane.q - o) @ plane.n) / nd
    return np.where(np.isfinite(t) & (t > 0), t, np.inf)


def plane_frames(scene: Scene, o: np.ndarray, d: np.ndarray) -> dict[int, PlaneRect]:
    """Initial rectangles: primary-ray hits, balls and the light projected (see the module docstring)."""
    rects = {}
    light = np.asarray(scene.light.position, dtype=np.float64)
    for k, s in enumerate(scene.shapes):
        if not isinstance(s, Plane):
            continue
        r = PlaneRect(s)
        t = plane_hits(r, o, d)
        r.include(o + np.where(np.isfinite(t), t, np.nan)[:, None] * d)
        # A grazing ray's hit moves along it by t DIR_ERR / |n·d| with the float32 direction: include that
        # far (4x) too, or Mitsuba's hit lands past the rectangle's edge (fuzz grazing_2026_46: |n·d| 1.7e-6,
        # the hit 6 % farther, beyond a rectangle sized by it). Rays with |n·d| <= 4 DIR_ERR are in the band.
        with np.errstate(divide="ignore", invalid="ignore"):
            spread = 4 * DIR_ERR / np.abs(d @ r.n)
        far = np.where(np.isfinite(t) & (spread < 1), t * (1 + spread), np.nan)
        r.include(o + far[:, None] * d)
        pts = [light, r.q, np.asarray(scene.camera.position)]
        for b in scene.shapes:
            if isinstance(b, Ball):
                c = np.asarray(b.center)
                pts += [c + b.radius * r.t1, c - b.radius * r.t1, c + b.radius * r.t2, c - b.radius * r.t2]
        r.include(np.array(pts))
        rects[k] = r
    return rects


def sensor_frames(scene: Scene, rules: Rules) -> dict[int, PlaneRect]:
    """Rectangles for the sensor route, which cannot grow them after tracing (Mitsuba's own rays and its
    stock ``direct`` integrator): ``plane_frames`` of the rays through every pixel square's four corners
    (the sensor's samples lie inside those squares, and a square's hits on a plane lie inside its
    corners' hits), plus each plane's projection of every such ray's hit on the other planes. A shadow
    segment from a hit P to the light L crosses plane B at a point of B lying between the projections of
    P and L onto B; both are in B's box, which is convex, so B covers every first shadow segment. (A
    fuzzed scene, random_7_5: a shadow segment passed beyond a rectangle sized for the primary rays
    alone, and 6 of its pixels came out lit, 21 sigma on that plane's mean.)"""
    os_, ds = [], []
    for u, v in ((0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)):
        n = scene.camera.width * scene.camera.height
        o, d = camera.rays_through(scene, rules, np.full(n, u), np.full(n, v))
        os_.append(o)
        ds.append(d)
    o, d = np.concatenate(os_), np.concatenate(ds)
    rects = plane_frames(scene, o, d)
    hits = {k: o + np.where(np.isfinite(t := plane_hits(r, o, d)), t, np.nan)[:, None] * d for k, r in rects.items()}
    for k, r in rects.items():
        for j, p in hits.items():
            if j != k:
                r.include(p)
    return rects
