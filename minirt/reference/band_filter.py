"""Which primary rays may lie in the silhouette band: one Dr.Jit kernel over a whole image, in front of
minirt.reference.band's exact margins, which are then computed only for the rays it lets through.

A rule diagnosis asks whether each pixel's ray is within ``eps`` of a decision that rounding flips
(``band.margins(...)["margin"] < eps``), under a camera's rules, for most pixels of the image: NumPy's
margins of an 800² image cost ~0.4-0.5 CPU-s a camera, almost all of it on rays far from any decision.
``near_band`` gives a superset of those rays from the same quantities computed in one kernel, and the
caller computes the exact margins of that superset only: its answer is the exact one, bit for bit.

Why a superset (the kernel's numbers are not NumPy's bits: a dot product may be summed or fused
otherwise). The kernel computes each quantity of ``band._every_ball`` with the same formulas in float64:
per ball h = |f - (f·d) d|, |f| and the roots (minirt.model.roots), per plane n·d and t. Each differs
from NumPy's by a few roundings of the magnitudes it is made of, at most ~2^-50 (|f| + r) for a ball
and ~2^-50 (|o| + |P|) for a plane. So:

- the silhouette and origin margins |h - r| / r, | |f| - r | / r err by ~2^-50 (|f| + r) / r, below
  2^-30 where (|f| + r) / r <= 2^20 -- checked before the kernel runs (``usable``: every ball, from the
  rays' largest |o|), else the caller goes exact;
- a grazing margin |n·d| errs by ~2^-50;
- a candidate hit counts where t > 0: its sign is uncertain only where |t| is within its error of 0, so
  rays with a candidate at |t| < 2^-20 (|f| + r) (a ball) or whose origin is within 2^-20 (|o| + |P|)
  of a plane (``ZERO``) are let through outright;
- the depth tie is the relative gap between the two nearest candidates times the smaller cosine. A
  ball's root errs by ~2^-52 (|f| + r + r^2 / sqrt(disc)) -- most near the silhouette -- and a plane's t
  by ~2^-52 |t| ((|o| + |P|) / |(P - o)·n| + 1 / |n·d|); times the candidate's own cosine (sqrt(disc) / r,
  |n·d|), which the tie is at most, and over the farther t (at least 2^-20 of the values it is made of,
  else let through), each adds ~2^-30 to the tie: the cosine cancels the growth near silhouettes and
  grazing angles. The kernel takes its own nearest and the least gap to every other candidate (times the
  smaller cosine): where its nearest is NumPy's, that least gap is at most NumPy's tie (the second
  nearest is among the others); where it is not, the two nearest are within rounding of each other, a
  gap of ~0, let through. A ball hit or missed otherwise (h within rounding of r) has a silhouette
  margin of ~0; a plane hit or missed otherwise (n·d within rounding of 0) a grazing margin of ~0.

Every margin below ``eps`` is thus below ``eps`` + 2^-29 in the kernel; rays are let through below
``SLACK`` ``eps`` (and where the kernel's value is not a number). Tested against the exact margins of
every pixel of the bundled scenes and random ones under each camera rule (tests/reference/test_band_filter.py).
The kernel unrolls the shapes (``MAX_SHAPES`` at most), each one's values read at run time (``dr.opaque``):
scenes with the same shapes' kinds share one compiled kernel.
"""

from __future__ import annotations

import math

import numpy as np

from minirt.model.roots import row_norm
from minirt.model.scene import Ball, Scene

MAX_SHAPES = 16  # unrolled in the kernel: ~40 operations a ball, ~20 a plane
SLACK = 2.0  # rays let through below SLACK eps (the kernel's margins within 2^-29 of NumPy's; eps >= 2^-24)
ZERO = 2.0**-20  # a candidate this near its ray's origin (relative to the values it is made of): let through
RATIO = 2.0**20  # (|f| + r) / r at most this for every ball, else no filter (``usable``)


def usable(scene: Scene, reach: float, eps: float) -> bool:
    """Whether ``near_band`` answers for rays whose origins are at most ``reach`` from the scene's
    origin: few enough shapes, every ball's (|f| + r) / r at most RATIO (|f| <= reach + |C|), and eps
    at least 2^-24 (the kernel's errors, 2^-29, are then below eps)."""
    if not 0 < len(scene.shapes) <= MAX_SHAPES or not eps >= 2.0**-24 or not math.isfinite(reach):
        return False
    for s in scene.shapes:
        if isinstance(s, Ball):
            lf = reach + math.sqrt(sum(c * c for c in s.center))
            if not s.radius > 0 or not (lf + s.radius) / s.radius <= RATIO:
                return False
    return True


def reach(scene: Scene, rules) -> float:
    """The largest |o| of the primary rays under these camera rules: an origin is the camera or a point
    of the image plane affine in the pixel's position, so the largest is at one of the four corner
    pixels (|o| is convex)."""
    from minirt.model import camera

    w, h = scene.camera.width, scene.camera.height
    o, _ = camera.primary_rays(scene, rules, np.array([0, w - 1, w * (h - 1), w * h - 1]))
    return float(row_norm(o).max())


def near_band(scene: Scene, o, d, eps: float) -> np.ndarray:
    """(N,) bool: rays (o, d: Dr.Jit float64 3-vectors, or (N, 3) NumPy arrays) whose exact margin
    (``band.margins``, unscaled) may be below ``eps`` -- every ray whose margin is, and a few more. Only
    where ``usable``."""
    import drjit as dr

    from minirt.jit.arrays import aligned

    F, V = dr.llvm.Float64, dr.llvm.Array3f64
    if isinstance(o, np.ndarray):
        o, d = (V(*(F(aligned(a[:, k], np.float64)) for k in range(3))) for a in (o, d))
    n = max(dr.width(o), dr.width(d))
    if n == 0:
        return np.zeros(0, dtype=bool)
    ov, dv = o, d
    with dr.scoped_set_flag(dr.JitFlag.FastMath, False):

        def dot(a, b):
            return (a[0] * b[0] + a[1] * b[1]) + a[2] * b[2]

        def norm(a):
            return dr.sqrt(dot(a, a))

        inf = dr.opaque(F, math.inf)
        low = dr.full(F, math.inf, n)  # the least of the silhouette, origin and grazing margins
        zero = dr.full(dr.llvm.Bool, False, n)
        cands = []  # (t, cos): t inf where the candidate does not count
        lo = norm(ov)
        for s in scene.shapes:
            if isinstance(s, Ball):
                c = V(*(dr.opaque(F, float(x)) for x in s.center))
                r = dr.opaque(F, float(s.radius))
                f = ov - c
                b = dot(f, dv)
                h = norm(f - b * dv)
                disc = (r - h) * (r + h)
                sq = dr.sqrt(dr.maximum(disc, 0.0))
                lf = norm(f)
                q = -(b + dr.copysign(sq, b))
                r0 = dr.select(q != 0, ((lf - r) * (lf + r)) / q, 0.0)
                low = dr.minimum(low, dr.minimum(dr.abs(h - r) / r, dr.abs(lf - r) / r))
                cos = sq / r
                for t in (dr.minimum(r0, q), dr.maximum(r0, q)):
                    zero |= (disc >= 0) & (dr.abs(t) < ZERO * (lf + r))
                    cands.append((dr.select((disc >= 0) & (t > 0), t, inf), cos))
            else:
                nn = V(*(dr.opaque(F, float(x)) for x in s.normal))
                p = V(*(dr.opaque(F, float(x)) for x in s.point))
                nd = dot(dv, nn)
                pd = dot(p - ov, nn)
                low = dr.minimum(low, dr.abs(nd))
                zero |= dr.abs(pd) < ZERO * (lo + norm(p))
                t = pd / nd
                cands.append((dr.select(dr.isfinite(t) & (t > 0), t, inf), dr.abs(nd)))
        first_t, first_cos, first_k = dr.full(F, math.inf, n), dr.full(F, 1.0, n), dr.full(dr.llvm.UInt32, 0, n)
        for k, (t, cos) in enumerate(cands):
            nearer = t < first_t
            first_t = dr.select(nearer, t, first_t)
            first_cos = dr.select(nearer, cos, first_cos)
            first_k = dr.select(nearer, k, first_k)
        tie = dr.full(F, math.inf, n)
        for k, (t, cos) in enumerate(cands):
            both = (first_k != k) & dr.isfinite(t) & dr.isfinite(first_t)
            gap = (t - first_t) / t * dr.minimum(dr.minimum(first_cos, cos), 1.0)
            tie = dr.select(both, dr.minimum(tie, gap), tie)
        m = dr.minimum(low, tie)
        through = zero | (m < SLACK * eps) | dr.isnan(m)
        dr.eval(through)
        return np.asarray(through, dtype=bool).copy()
