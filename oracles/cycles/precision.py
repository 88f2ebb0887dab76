"""How far Cycles' geometry may be from the reference's, and why: the figures its renders record in
``meta["precision"]`` and the per-pixel bounds its ``geometry_tolerance`` turns them into.

Cycles traces in float32, on its own camera rays. Three things separate its buffers from the float64
reference's, each bounded here:

1. Its rays. Sample 0 of a pixel goes through the pixel's filter centre, put on the rules' ray by the
   camera's shift (minirt.oracles.cycles.scene.camera_job), then through a float32 raster-to-camera
   projective transform, a normalisation and the camera-to-world transform. DIR_ERR bounds the angle
   between its direction and the reference's: 32 u32, for a few roundings in each of those steps and the
   raster coordinate (x + 0.5 + b, rounded to float32: u32 W pixels, u32 / d radians). Measured on the
   bundled scenes at 32 x 32 to 48 x 32: at most 9 u32 (5.3e-7 rad), and that includes the rounding of the
   hit position it was measured from. Its origin (the camera, or the image plane through the near clip:
   camera + near / cos * D in float32) is off by ORIGIN_ULPS u32 (|camera| + |o|) at most.
   Together, at distance t along the ray, Cycles' ray passes within e_o + DIR_ERR t of the reference's.
2. Its intersectors. A ball is a point primitive, intersected on the CPU by Embree's sphere points
   (Cycles' bvh/embree.cpp: RTC_GEOMETRY_TYPE_SPHERE_POINT, back faces culled by a filter) in float32 --
   not the textbook quadratic b^2 - c (Mitsuba's), whose cancellation costs u32 |f|^2, but its stable
   form (Embree's sphere_intersector.h, and Cycles' own point_intersect.h alike): c0 = C - o, projC0 =
   c0.D, perp = c0 - projC0 D, l2 = |perp|^2, hit where l2 <= r^2, t = projC0 - sqrt(r^2 - l2). Each of
   c0, projC0 and perp errs by a few roundings of |f| (|f| the origin's distance from the centre, plus
   r): |d perp| <~ 8 u32 |f|, so l2 = h^2 errs by 16 u32 |f| h, about 4 eps r^2 at the silhouette with
   eps = u32 (4 |f| + |C| + r) / r (|C|: the centre's own rounding). That flips hit/miss for margins below
   ~2 eps and moves t by ~2 eps r / sqrt(2 m) near the silhouette (m the relative margin); off it, t errs
   by a few u32 |f| (t_rel). A plane is a quad of two triangles whose hit point is interpolated from
   float32 corners: an absolute error 8 u32 (|c| + |S|) per quad (meta["planes"]).
3. Its buffers: position and normal passes are float32 (u32 |P| each, inside the bounds above).

So each ball's band (the margin within which hit/miss may flip) is its own: the decision's relative
error eps above and the ray's displacement (e_o + DIR_ERR |f|) / r, |f| the farthest ray origin's
distance from the centre plus the radius, with BAND_K of safety; a plane's is u32 + DIR_ERR (a grazing
decision turns with the direction). Measured: `minirt fuzz -b cycles --size 24x24`, seeds 1 to 4 (364
scenes of every family, balls up to 1e8 away): no FAIL; with --defects all (seed 1), every injected
defect that changes a pixel the check judges is caught.
"""

from __future__ import annotations

import math

import numpy as np

from minirt.model.scene import Ball, Scene
from minirt.oracles.base import ball_silhouette_margins

U32 = 2.0**-24  # float32 unit round-off
DIR_ERR = 32 * U32  # the camera ray's direction against the reference's (radians; see the module docstring)
ORIGIN_ULPS = 8.0  # the camera ray's origin: camera + near / cos * D, a few float32 roundings of |o|
T_REL = 64 * U32  # float32 roots: the part of the t error that does not depend on the silhouette margin
BAND_K = 16.0  # 4 roundings in the discriminant (|f|^2, b^2, the subtraction, sqrt), a factor 4 of safety
NORMAL_FLOOR_DEG = 0.01  # a float32 normal's own angle error (~1e-6 rad), with room


def origin_error(camera_distance: float, origins: np.ndarray) -> float:
    """e_o: how far Cycles' ray origin may be from the reference's (see the module docstring)."""
    reach = float(np.max(np.linalg.norm(origins, axis=1))) if len(origins) else 0.0
    return ORIGIN_ULPS * U32 * (camera_distance + reach)


def shape_eps(scene: Scene, origins: np.ndarray, e_o: float) -> tuple[list[float], list[float]]:
    """Per shape, (eps_disc, eps_ray): the relative precision of the hit/miss decision from the float32
    intersector (a ball: u32 (4 |f| + |C| + r) / r, see the module docstring; planes u32) and from the
    ray's displacement against the reference's ((e_o + DIR_ERR |f|) / r; planes DIR_ERR: |n·d| turns with
    the direction)."""
    o = np.asarray(origins, dtype=np.float64)
    disc, ray = [], []
    for s in scene.shapes:
        if isinstance(s, Ball):
            f = float(np.max(np.linalg.norm(o - np.asarray(s.center), axis=1))) + s.radius
            disc.append(U32 * (4 * f + float(np.linalg.norm(s.center)) + s.radius) / s.radius)
            ray.append((e_o + DIR_ERR * f) / s.radius)
        else:
            disc.append(U32)
            ray.append(DIR_ERR)
    return disc, ray


def band_scales(scene: Scene, origins: np.ndarray, e_o: float) -> dict[str, list[float]]:
    """Each shape's own band, as minirt.reference.band.margins' per-shape scales.

    A ball's float32 r^2 - l2 (l2 = h^2) errs by up to 4 eps_disc r^2, so (as Mitsuba's discriminant, whose
    derivation this repeats) the decision is uncertain where |r^2 - h^2| < 2 K eps_disc r^2, exact in m:
    outside (h = r (1 + m)) for m < sqrt(1 + 2 K eps_disc) - 1, inside (h = r (1 - m)) for m < 1 - sqrt(1 -
    2 K eps_disc) -- every hit when 2 K eps_disc >= 1. The ray's displacement moves h by at most
    eps_ray r, linearly: K eps_ray is added to both. Whether an origin is inside a ball: the wider of the
    two. Depth ties: K (eps_disc + eps_ray) (a root's t moves linearly). Planes: K (eps_disc + eps_ray)."""
    disc, ray = shape_eps(scene, origins, e_o)
    out: dict[str, list[float]] = {"scale": [], "inside": [], "origin": [], "tie": []}
    for s, ed, er in zip(scene.shapes, disc, ray, strict=True):
        lin = BAND_K * er
        if isinstance(s, Ball):
            x = 2 * BAND_K * ed
            outside = math.sqrt(1 + x) - 1 + lin
            inside = (1 - math.sqrt(1 - x) if x < 1 else 2.0) + lin
            out["scale"].append(outside)
            out["inside"].append(inside)
            out["origin"].append(max(outside, inside))
            out["tie"].append(BAND_K * (ed + er))
        else:
            for key in out:
                out[key].append(BAND_K * (ed + er))
    return out


def silhouette_t_bound(scene: Scene, o: np.ndarray, d: np.ndarray, shape_id: np.ndarray) -> np.ndarray:
    """Per ray, the part of a float32 sphere root's t error that grows near the silhouette (0 off balls):
    the error of r^2 - l2, 4 eps r^2 with eps = u32 (4 |f| + |C| + r) / r (the module docstring), moves
    t = projC0 - sqrt(r^2 - l2) by it over 2 sqrt(r^2 - l2) >= 2 r sqrt(2 m) (m the relative margin
    |r - h| / r): |dt| <= 2 eps r / sqrt(2 m) = 2 u32 (4 |f| + |C| + r) / sqrt(2 m); twice that is
    returned, |f| the ray's own origin's distance from the centre. Rays inside the band are not judged."""
    out = np.zeros(len(o))
    for on, s, f, m in ball_silhouette_margins(scene, o, d, shape_id):
        reach = 4 * np.linalg.norm(f, axis=1) + float(np.linalg.norm(s.center)) + s.radius
        out[on] = 4 * U32 * reach / np.sqrt(2 * m)
    return out


def hit_cos(scene: Scene, o: np.ndarray, d: np.ndarray, shape_id: np.ndarray) -> np.ndarray:
    """Per ray, |cos| of the incidence on the shape it hit (float64, the exact ray): |n·d| on a plane,
    sqrt(r^2 - h^2) / r on a ball (h the ray's distance from the centre); 1 on a miss. The harness's own
    margins give this for the nearest candidate hit, which need not be the hit shape: under near_root_only a
    ball the ray starts inside is a candidate but never hit (fuzz random_3_19: a plane met at |n·d| =
    0.0013 behind such a ball, its t judged at the ball's cos 0.72 and found 4 times over tolerance)."""
    out = np.ones(len(o))
    for k, s in enumerate(scene.shapes):
        on = shape_id == k
        if not on.any():
            continue
        if isinstance(s, Ball):
            f = o[on] - np.asarray(s.center)
            b = np.einsum("ij,ij->i", f, d[on])
            h = np.linalg.norm(f - b[:, None] * d[on], axis=1)
            out[on] = np.sqrt(np.maximum((s.radius - h) * (s.radius + h), 0.0)) / s.radius
        else:
            out[on] = np.abs(d[on] @ np.asarray(s.normal))
    return out


def ball_normal_bound(
    radius: list[float], t: np.ndarray, shape_id: np.ndarray, e_o: float, hit_cos: np.ndarray, o_norm: np.ndarray
) -> np.ndarray:
    """Per pixel (radians), how far Cycles' normal on a ball may turn from the reference's: its hit point
    moves along the surface by the ray's displacement over the incidence's cosine, (e_o + DIR_ERR t) / cos,
    and by its own float32 rounding, 8 u32 (|o| + t); the normal (P - C) / r turns by that over r.
    ``radius``: per shape, the ball's radius, 0 for a plane, whose normal is the quad's face normal (exact
    up to its corners' rounding): 0 there."""
    out = np.zeros(t.shape)
    with np.errstate(divide="ignore", invalid="ignore"):
        move = (e_o + DIR_ERR * t) / np.maximum(hit_cos, 1e-12) + 8 * U32 * (o_norm + t)
    for k, r in enumerate(radius):
        if r > 0:
            on = shape_id == k
            out[on] = move[on] / r
    return out
