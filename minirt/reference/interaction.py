"""Where a ray hits a shape: the hit point, the shape's normal there, the hit point's error bound, and
where the secondary rays (shadow, reflection) leave from.

The exercise's ``normal`` of Ball and Plane, and the offset it hints at ("add a small fraction of
normal"), with the rules that vary them: offset (a number, or "error-bound": pbrt-v4's bound on the hit
point's rounding and its OffsetRayOrigin), offset_along and near_root_only. ``tr`` holds the settings
of the tracer whose kernel is being built (minirt.reference.settings.TraceSettings): its types, rules
and the scene's values (``tr.values``, either representation: the same operations on the same values,
so the same bits).
"""

from __future__ import annotations

from typing import Any

import drjit as dr
import numpy as np

from minirt.model.scene import Ball
from minirt.reference.settings import TraceSettings


def hit_point_and_normal(tr: TraceSettings, shape_id, o, d, t) -> tuple[Any, Any]:
    """p = o + t d and the hit shape's own normal: (p - C) / r for a ball, n for a plane.

    The hit shape's constants are selected first and the formula applied once, not once per
    shape: a third of the divisions with three balls, and the same operations on the same values
    for every ray, so the same bits.

    Rules from real solutions' bugs: hit_point "origin" takes p = t d (the ray's start left out), and
    ball_normal "inward" turns a ball's normal into (C - p) / r -- after the error-bound offset's
    re-projection, which needs the outward one.
    """
    p = t * d
    origin = tr.values.rule("hit_point_origin")
    if origin is not True:
        p = o + p if origin is False else dr.select(origin, p, o + p)
    n, ball = tr.values.frame(shape_id)
    if ball is None:  # a scene without balls
        return p, n
    c, r, inv_r, is_ball = ball
    p, n = ball_normal(tr, p, d, c, r, inv_r, is_ball, n)
    inward = tr.values.rule("ball_normal_inward")
    if inward is not False:
        n = dr.select(is_ball if inward is True else is_ball & inward, -n, n)
    return p, n


def ball_normal(tr: TraceSettings, p, d, c, r, inv_r, is_ball, n) -> tuple[Any, Any]:
    """Where is_ball: the normal (p - C) / r of the ball (C, r) hit at p, and under error-bound p put
    back on it; elsewhere p and n as given."""
    reproject = tr.values.switch("offset_error_bound")  # a batch's: each ray its candidate's (a mask)
    # pbrt-style under error-bound: put the point back on the sphere, normal from it. Otherwise
    # (p - C) times the radius's reciprocal: one division instead of three (the normal moves by at
    # most an ulp more; it is not of unit length to within rounding either way), and that one made
    # on the host (inv_r, the same bits).
    if reproject is True:
        nb = dr.normalize(p - c)
    elif reproject is False:
        nb = (p - c) * inv_r
    else:
        nb = dr.select(reproject, dr.normalize(p - c), (p - c) * inv_r)
    # A ball smaller than an ulp of its centre: the hit point can round onto the centre,
    # and p - C = 0 has no direction. Then the normal faces the ray.
    degenerate = ~(dr.squared_norm(nb) > 0) | ~dr.isfinite(dr.squared_norm(nb))
    nb = dr.select(degenerate, -d, nb)
    n = dr.select(is_ball, nb, n)
    if reproject is not False:
        p = dr.select(is_ball if reproject is True else is_ball & reproject, c + r * nb, p)
    return p, n


def error_bound(tr: TraceSettings, shape_id, p, o) -> Any:
    """Absolute error bound of a hit point p of the ray from o, per shape (measured to give 0 self-hits;
    tests/reference/test_hard_cases.py).

    Ball: gamma(6) (r + |p|) -- re-projection costs about 5 roundings of magnitude r + |p|, one more
    for the normalisation; the ray's origin no longer matters. Plane: gamma(4) (|a| + |p| + |o|) -- the
    point-normal form's dot products, and p = o + t d, whose distance from the plane errs by the
    rounding of n·o too: a point near the origin seen from far (fuzz start_2026_175: |p| 0.19, |o| 3.09)
    lies a few u |o| off its plane, far more than u |p|, and a bound without |o| left it there. (Each
    representation of the scene's values evaluates this per hit shape: ``values.Values.error_bound``.)
    """
    lp, lo = dr.norm(p), dr.norm(o)
    return tr.values.error_bound(shape_id, lp, lo)


def offset_origin(tr: TraceSettings, p, n, err, direction, outward=None) -> Any:
    """Start of a secondary ray leaving p in `direction` (n: the shading normal). ``outward`` (error-bound
    only): where true, offset to n's side whatever the direction (see ``outward``)."""
    T, rules = tr.T, tr.rules
    bound = tr.values.switch("offset_error_bound")  # a batch's: each ray its candidate's (a mask)
    if bound is not True and tr.runtime:  # read at run time (a batch's rays each their candidate's)
        along = dr.select(tr.values.rule("offset_along_ray"), direction, n)
        by_number = p + tr.values.number("offset") * along
        if bound is False:
            return by_number
        return dr.select(bound, _by_bound(T, p, n, err, direction, outward), by_number)
    if bound is False:
        off = rules.offset
        if rules.offset_along == "ray":
            return p + T.Float(off) * direction  # rule offset_along "ray": along the new ray
        return p + T.Float(off) * n  # the exercise's hint: "add a small fraction of normal"
    return _by_bound(T, p, n, err, direction, outward)


def _by_bound(T, p, n, err, direction, outward) -> Any:
    """``offset_origin`` under "error-bound"."""
    # (offset_along applies to numeric offsets only; validation rejects "ray" with "error-bound".)
    # Offset along n by the error bound, on the side the new ray leaves to, then one more ulp
    # away from p in each component (pbrt-v4's OffsetRayOrigin).
    side = dr.select(dr.dot(n, direction) < 0, T.Float(-1.0), T.Float(1.0))
    if outward is not None:
        side = dr.select(outward, T.Float(1.0), side)
    delta = side * err * n
    q = p + delta
    return T.Array3(*(_ulp_away(T, q[i], delta[i]) for i in range(3)))


def outward(tr: TraceSettings, shape_id) -> Any:
    """Where secondary rays must start outside the hit ball, whichever way they leave: under
    near_root_only with the error-bound offset. A shadow ray from a point facing away from the light
    runs into its own ball; started on the inside (the side the ray leaves to), near_root_only would
    not see that ball at all and the point would be lit -- every back-face self-shadow lost. Started
    outside by the error bound, its near root is in front (t ~ err / cos > 0), as under a numeric
    offset along the normal, and as without near_root_only (the far root from inside). Under
    near_root_only a ball is only hit from outside, so its shading normal is the outward one.
    None when the rule does not apply (the offset's side is then that of the new ray)."""
    nro = tr.values.rule("near_root_only")
    balls = any(isinstance(s, Ball) for s in tr.scene.shapes)
    bound = tr.values.switch("offset_error_bound")  # a batch's: each ray its candidate's (a mask)
    if bound is False or nro is False or not balls:
        return None
    is_ball = tr.values.is_ball(shape_id)
    out = is_ball if nro is True else is_ball & nro
    return out if bound is True else out & bound


def _ulp_away(T, x, delta) -> Any:
    """x one representable number further in the direction of ``delta`` (away from the point the offset
    left; a zero x becomes the least subnormal of delta's sign)."""
    bits = dr.reinterpret_array(T.Bits, x)
    grow = ((delta > 0) & (x > 0)) | ((delta < 0) & (x < 0))
    shrink = ((delta > 0) & (x < 0)) | ((delta < 0) & (x > 0))
    bits = dr.select(grow, bits + 1, dr.select(shrink, bits - 1, bits))
    y = dr.reinterpret_array(T.Float, bits)
    tiny = float(np.finfo(T.np_dtype).smallest_subnormal)
    return dr.select((x == 0) & (delta != 0), dr.copysign(T.Float(tiny), delta), y)
