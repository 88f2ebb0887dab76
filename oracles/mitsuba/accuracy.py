"""What Mitsuba's numbers are worth: the float32 error of its sphere roots, rays and normals, as the
constants and per-shape bands recorded in ``meta["precision"]`` and turned into per-pixel tolerances
by MitsubaOracle.geometry_tolerance (the rectangles' own bounds are PlaneRect's, planes.py).
"""

from __future__ import annotations

import math

import numpy as np

from minirt.model.scene import Ball, Scene
from minirt.oracles.base import ball_silhouette_margins

U32 = 2.0**-24  # float32 unit round-off
# Mitsuba's spawn_ray offset: a secondary ray leaves si.p + n * RAY_EPSILON (1 + max|p|) (include/mitsuba/core
# math.h: RayEpsilon = Epsilon * 1500, Epsilon = 2^-24 in float32). Where a rectangle's own float32 error
# exceeds it, the stock integrator's shadow ray can re-hit the rectangle (the sensor route; the custom rays
# restart past the error slab instead).
RAY_EPSILON = 2.0**-24 * 1500

# ---------------------------------------------------------------------------------------------
# Precision (used by the tests and recorded in meta["precision"]).
#
# Mitsuba's sphere (float32 in *_ad_* variants) solves |o + t d - c|^2 = r^2 with f = o - c in
# float32. Away from the silhouette the roots carry a few roundings of magnitude |f|: relative t
# error ~ 8 u32 |f| / t. At the silhouette the discriminant D = r^2 - h^2 (h the ray's distance from
# the centre) cancels: its absolute error is ~ 4 u32 |f|^2, and t moves by dD / (2 sqrt(D)), so the
# relative error grows like u32 |f|^2 / (r t sqrt(2 m)) with m = |h - r| / r the band margin. The
# hit/miss decision flips where D's error reaches D = 2 r^2 m, i.e. at m ~ 2 u32 |f|^2 / r^2.
# Rectangles add an absolute error ~ 8 u32 (|c| + |S|) (see the package docstring: Planes).
T_REL = 64 * U32  # ~3.8e-6: the part of the t error that does not depend on the silhouette margin
# The rays are rounded to float32 for Mitsuba: each unit direction component errs by <= u32, |dd| <= sqrt(3) u32.
DIR_ERR = math.sqrt(3) * U32
NORMAL_DEG = 0.01  # sphere normals are normalize(p - c) of a float32 point: ~1e-6 rad; planes exact


def band_eps(scene: Scene, origins: np.ndarray) -> float:
    """Relative precision eps of the hit/miss decision for this view (the band is margin < K eps).

    eps = u32 max over balls of |f|^2 / r^2, |f| the farthest ray origin's distance from the centre
    plus the radius: the discriminant's relative error (see above). Planes: grazing (|n.d| small)
    and depth ties are decided on float32 values, relative error ~ u32 (|c| + S) / t, bounded by
    the same form with |c| + S in place of |f|, but those are covered by meta's plane bounds.
    """
    return max(shape_eps(scene, origins), default=U32)


def shape_eps(scene: Scene, origins: np.ndarray) -> list[float]:
    """Per shape, the eps of :func:`band_eps`: u32 |f|^2 / r^2 for a ball (at least u32), u32 for a plane."""
    o = np.asarray(origins, dtype=np.float64)
    out = []
    for s in scene.shapes:
        eps = U32
        if isinstance(s, Ball):
            f = float(np.max(np.linalg.norm(o - np.asarray(s.center), axis=1))) + s.radius
            eps = max(eps, U32 * f * f / (s.radius * s.radius))
        out.append(eps)
    return out


BAND_K = 16.0  # 4 roundings in D (|f|^2 term, b^2 term, subtraction, sqrt) with a factor 4 of safety


def band_scales(scene: Scene, origins: np.ndarray, eps: list[float] | None = None) -> dict[str, list[float]]:
    """Each shape's own band (``minirt.reference.band.margins``' per-shape scales): a ball 1e6 radii away is held
    far less exactly than a ball beside the camera, and one scene-wide eps (:func:`band_eps`) is the
    worst ball's, which puts every ray of such a scene in the band.

    Ball k: eps_k = u32 |f_k|^2 / r_k^2 as in :func:`band_eps`, and its float32 discriminant
    D = r^2 - h^2 errs by up to 4 u32 |f|^2 = 4 eps r^2. With the band's safety (BAND_K: the linear band
    m < K eps is 8 times the linear flip point m = 2 eps) the decision is taken as uncertain where
    |D| < 2 K eps r^2, and |D| is exact in the margin m = |h - r| / r, not linear in it:
    outside (h = r (1 + m)): |D| = r^2 (m^2 + 2m), uncertain for m < sqrt(1 + 2 K eps) - 1;
    inside (h = r (1 - m)): |D| = r^2 (2m - m^2), uncertain for m < 1 - sqrt(1 - 2 K eps), every hit
    when 2 K eps >= 1 (the discriminant's error exceeds r^2: not one hit on that ball can be judged).
    Both are K eps for small eps (the scene-wide band's value). A far ball (eps 1e6) bands the rays within
    ~6e3 radii of it -- the pixel it is on -- not every ray. Whether an origin is inside a ball is the sign
    of |f|^2 - r^2, the same quadratic in the origin's margin: the wider of the two forms. Depth ties keep
    the linear K eps_k (a root's t moves linearly with D's error). Planes: K u32, the floor of
    :func:`band_eps` (their float32 error is in the rectangle bounds, meta["planes"]). ``eps``: the
    shapes' :func:`shape_eps`, if already computed."""
    out: dict[str, list[float]] = {"scale": [], "inside": [], "origin": [], "tie": []}
    for s, e in zip(scene.shapes, shape_eps(scene, origins) if eps is None else eps, strict=True):
        if isinstance(s, Ball):
            x = 2 * BAND_K * e
            outside = math.sqrt(1 + x) - 1
            inside = 1 - math.sqrt(1 - x) if x < 1 else 2.0  # margins <= 1 inside: 2 bands every hit
            out["scale"].append(outside)
            out["inside"].append(inside)
            out["origin"].append(max(outside, inside))
            out["tie"].append(x / 2)
        else:
            for key in out:
                out[key].append(BAND_K * U32)
    return out


def silhouette_t_bound(scene: Scene, o: np.ndarray, d: np.ndarray, shape_id: np.ndarray) -> np.ndarray:
    """Per ray, the part of Mitsuba's t error that grows near a ball's silhouette (0 elsewhere).

    Its float32 discriminant D = r^2 - h^2 (h the ray's distance from the centre) errs by ~4 u32 |f|^2,
    and t = -b -+ sqrt(D) moves by dD / (2 sqrt(D)); with D = r^2 (1 - (h/r)^2) >= 2 r^2 m for the
    relative margin m = |r - h|/r, |dt| <= 2 u32 |f|^2 / (r sqrt(2 m)). Twice that is returned (the
    margin taken at the float32-rounded ray). Rays inside the band (m < K eps) are not judged at all.
    """
    out = np.zeros(len(o))
    for on, s, f, m in ball_silhouette_margins(scene, o, d, shape_id):
        out[on] = 4 * U32 * np.einsum("ij,ij->i", f, f) / (s.radius * np.sqrt(2 * m))
    return out
