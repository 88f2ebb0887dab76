"""Ball and Plane: where a ray meets them (problem 13.1's ``intersect``), in Dr.Jit arithmetic.

Every function works on a shape's values as the kernel reads them -- constants compiled in, opaque
values or gathers from the shape table (minirt.reference.values) -- so one function serves every way
the tracer finds its shapes: the tracer's unrolled tests, the shape table's loops and the BVH's leaves
(minirt.reference.accel) test a ball with the very same operations, and so give the same t, bit for bit.
``v`` is that representation (``values.Values``): its float types (``v.T``) and the rules as the kernel
sees them (``v.rule``, ``v.rules``: near_root_only).

Numerics (see "Numerics" in the README):
- Ball: f = o - C, b = f·d (d unit), discriminant r^2 - |g|^2 with g = f - b d (one fused
  multiply-add of the exact r^2), then q = -(b + sign(b) sqrt(disc)), roots c/q and q with
  c = (|f| - r)(|f| + r). This avoids both cancellations of the textbook form (small/far balls: the
  ray's length leaves g before anything is squared; near root of big balls: Vieta).
- Plane: point-normal form t = n·(Q - o) / (n·d) with Q = a n; a parallel ray (n·d = 0) misses.
- Only t > 0 counts (the exercise's "positive side"); a miss is t = inf.
"""

from __future__ import annotations

import math
from typing import Any

import drjit as dr
import numpy as np


def ball_ray(center, r, o, d) -> tuple[Any, Any, Any, Any]:
    """What every ball test starts from: r, f = o - C, b = f·d and |f - b d|^2, the ray's squared
    distance from the centre (d unit). center, r: Dr.Jit values (constants or gathered from the table)."""
    f = o - center
    b = dr.dot(f, d)
    g = f - b * d
    return r, f, b, dr.dot(g, g)


def ball_disc(r, gg) -> Any:
    """r^2 - |g|^2, the discriminant over 4 (gg = |g|^2, ``ball_ray``): one fused multiply-add, r^2
    exact inside it, minus a once-rounded squared length. What removes the textbook form's
    cancellation is g = f - (f·d) d (the ray's length is gone before anything is squared), not the
    factored (r - |g|)(r + |g|), which errs by the same ~2u |g|^2 and costs a square root per ball
    and ray."""
    return dr.fma(r, r, -gg)


def ball_c(r, f) -> Any:
    """c = |f|^2 - r^2 = (|f| - r)(|f| + r), the roots' product.

    The factored form on purpose: a secondary ray that starts on the ball (an offset of 0, or one
    below the hit point's rounding) has |f| within a few ulps of r, and the rounded square root
    often snaps to r itself, c = 0 exactly: the near root is exactly 0 (not t > 0) and the ray does
    not meet its own surface there. |f|^2 - r^2 in one fused multiply-add would give c the sign of the
    last bit of |f|^2 instead -- a coin toss between self-hit and not at every such point (acne), and
    one that another tracer's arithmetic tosses differently (tests/diagnose/test_diagnose.py's offset 0)."""
    lf = dr.sqrt(dr.squared_norm(f))  # dr.norm(f), spelt out: ball_occludes reads |f|^2 alone
    return (lf - r) * (lf + r)


def ball_t(v, center, radius, o, d, gate: bool = False) -> Any:
    """t of the ray (o, d) at the ball, inf on a miss. ``gate``: the roots in a Dr.Jit conditional on
    the ray meeting the ball (disc >= 0), which a packet of rays that all pass it skips; a miss is
    inf either way, so the same bits."""
    r, f, b, gg = ball_ray(center, radius, o, d)
    disc = ball_disc(r, gg)
    hit = disc >= 0
    if not gate:
        return _ball_roots(v, r, f, b, disc, hit)
    return dr.if_stmt(
        (r, f, b, disc, hit), hit, lambda *a: _ball_roots(v, *a), lambda *_: v.T.Float(math.inf), label="ball"
    )


def _ball_roots(v, r, f, b, disc, hit) -> Any:
    F = v.T.Float
    c = ball_c(r, f)
    sq = dr.sqrt(dr.maximum(disc, 0))
    q = -(b + dr.copysign(sq, b))  # Vieta: never subtracts nearly equal numbers
    q_ok = q != 0  # q = 0 only for a ray starting on the surface, tangent: both roots 0
    t0 = dr.select(q_ok, c / q, 0)
    t1 = dr.select(q_ok, q, 0)
    tn, tf = dr.minimum(t0, t1), dr.maximum(t0, t1)
    inf = F(math.inf)
    nro = v.rule("near_root_only")
    if nro is True:
        # "we are only interested in the smaller of the two intersection points, provided it is
        # not negative": from inside a ball the near root is behind the ray, so no hit at all.
        return dr.select(hit & (tn > 0), tn, inf)
    far = hit & (tf > 0)
    if nro is not False:
        far &= ~nro
    return dr.select(hit & (tn > 0), tn, dr.select(far, tf, inf))


def ball_occludes(v, center, radius, o, d, bounds: tuple[Any, Any] | None = None) -> Any:
    """ball_t(v, center, radius, o, d) < inf, from signs: the roots' product is c = |f|^2 - r^2 (d is
    unit) and their sum -2 b. Both roots > 0 iff c > 0 and b < 0; exactly one iff c < 0; c = 0
    gives roots 0 and -2 b. This decides as ball_t's t does: there q = -(b + sign(b) sqrt) has the
    sign of -b (or is 0 only where both roots are 0), so c / q and q carry these signs; the two
    differ only if c / q underflows to 0, i.e. a hit closer than 1e-308 relative, which the scene's
    1e-100 limits and the ray offsets exclude. ``bounds``: the radius's ``sqrt_bounds`` (as the kernel
    reads them), which spare the square root."""
    r, f, b, gg = ball_ray(center, radius, o, d)
    if bounds is None:
        c = ball_c(r, f)
        c_pos, c_neg, c_zero = c > 0, c < 0, c == 0
    else:
        # The sign of c = (|f| - r)(|f| + r) is that of |f| - r, |f| = sqrt(|f|^2) correctly rounded,
        # which is monotone: |f| > r iff |f|^2 > hi, |f| < r iff |f|^2 < lo (``sqrt_bounds``). The
        # same decisions without the square root. (The product cannot underflow to 0: |f| - r is 0 or
        # at least an ulp of r, and r > 1e-100.)
        ff = dr.squared_norm(f)
        lo, hi = bounds
        c_pos, c_neg = ff > hi, ff < lo
        c_zero = (ff >= lo) & (ff <= hi)
    hit = ball_disc(r, gg) >= 0
    both = c_pos & (b < 0)
    nro = v.rule("near_root_only")
    if nro is True:
        return hit & both
    other = c_neg | (c_zero & (b < 0))
    if nro is not False:
        other &= ~nro
    return hit & (both | other)


def sqrt_bounds(r: float, dtype) -> tuple[float, float]:
    """(lo, hi): the least x whose correctly rounded square root is >= r and the greatest whose root is
    <= r, r rounded to ``dtype`` (x of that type): sqrt(x) < r iff x < lo, > r iff x > hi, = r iff lo <= x
    <= hi. Found by stepping from r * r one representable number at a time (a few steps at most)."""
    with np.errstate(over="ignore"):  # r * r and the steps may reach inf for radii beyond the limits
        return _sqrt_bounds(dtype(r), dtype(np.inf))


def _sqrt_bounds(r, inf) -> tuple[float, float]:
    x = r * r
    hi = x
    while np.sqrt(hi) > r:
        hi = np.nextafter(hi, -inf)
    while np.sqrt(np.nextafter(hi, inf)) <= r:
        hi = np.nextafter(hi, inf)
    lo = x
    while np.sqrt(lo) < r:
        lo = np.nextafter(lo, inf)
    while lo > 0 and np.sqrt(np.nextafter(lo, -inf)) >= r:
        lo = np.nextafter(lo, -inf)
    return float(lo), float(hi)


def plane_t(v, n, q, o, d, gate: bool = False) -> Any:
    """t of the ray (o, d) at the plane through q with normal n, inf on a miss. ``gate``: the division
    in a Dr.Jit conditional on numerator and denominator having the same strict sign, which a packet
    of rays that all leave the plane (shadow rays from above a floor) skips. Only then can the
    quotient be > 0; NaN, zeros and opposite signs give inf either way, so the same bits."""
    denom = dr.dot(n, d)
    num = dr.dot(n, q - o)
    if not gate:
        return _plane_quotient(v, num, denom)
    towards = ((num > 0) & (denom > 0)) | ((num < 0) & (denom < 0))
    return dr.if_stmt(
        (num, denom), towards, lambda *a: _plane_quotient(v, *a), lambda *_: v.T.Float(math.inf), label="plane"
    )


def _plane_quotient(v, num, denom) -> Any:
    t = num / denom
    ok = (denom != 0) & (t > 0) & (t < math.inf)  # parallel rays miss; never NaN
    return dr.select(ok, t, v.T.Float(math.inf))
