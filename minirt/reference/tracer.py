"""The reference tracer: the exercise's model (problem 13.1), vectorised with Dr.Jit's LLVM backend.

Structure follows the problem set: ``Ball`` and ``Plane`` each ``intersect`` a ray and give a
``normal``; ``Scene.Intersect`` (here :meth:`Tracer.closest`) keeps the closest hit; ``TraceRay``
(here :meth:`Tracer.trace`) adds ambient, the shadow-tested diffuse and specular terms, the
reflection and the background, in the pseudo-code's order.

The recursion runs in one kernel: the reflections in a Dr.Jit loop, the first level before it in
straight-line code (from ``LOOP_FIRST_LEVEL_BELOW`` rays) or as its first iteration (the shading code
compiled once), each packet of rays skipping what none of its rays needs (``Tracer._trace_fused``). Above
``WAVEFRONT_MIN_BALLS`` balls, and for recorded levels, it is traced as a wavefront instead: one kernel
per reflection level over all rays of that level, then only the rays that hit something reflective are
compacted (``dr.compress``) into the next level. Either way colours are combined back to front,
``c = local + kr * c_child``, which is exactly the recursive form's arithmetic, and the two give the
same bits. Dr.Jit's FastMath is switched off while tracing: the NaN/inf guards
below and the stable intersection forms rely on IEEE semantics.

Numerics (see "Numerics" in the README and the notes in the code):
- Ball: f = o - C, b = f·d (d unit), discriminant r^2 - |g|^2 with g = f - b d (one fused
  multiply-add of the exact r^2), then q = -(b + sign(b) sqrt(disc)), roots c/q and q with
  c = (|f| - r)(|f| + r). This avoids both cancellations of the textbook form (small/far balls: the
  ray's length leaves g before anything is squared; near root of big balls: Vieta).
- Plane: point-normal form t = n·(Q - o) / (n·d) with Q = a n; a parallel ray (n·d = 0) misses.
- Only t > 0 counts (the exercise's "positive side"); ties go to the lower shape id.
"""

from __future__ import annotations

import math
import time
from collections.abc import Collection
from dataclasses import dataclass, field
from typing import Any

import drjit as dr
import numpy as np

from minirt.jit import arrays as jitmem
from minirt.jit.arrays import aligned
from minirt.jit.engine import require_llvm
from minirt.model import camera
from minirt.model.effects import Effects, effects
from minirt.model.result import TERMS, RenderResult
from minirt.model.rules import SPECULAR_EXPONENT_MAX, Rules
from minirt.model.scene import Ball, Plane, Scene
from minirt.reference import accel
from minirt.reference.accel import ShapeTable, gamma


def _power(x, e: int) -> Any:
    """x^e by square-and-multiply (e >= 1): the squares of x from the lowest bit up, multiplied into the
    result where e has a bit set. For e = 8 exactly x2 = x x, x4 = x2 x2, x8 = x4 x4; for 16 one more square."""
    result, base = None, x
    while True:
        if e & 1:
            result = base if result is None else result * base
        e >>= 1
        if not e:
            return result
        base = base * base


def _power_runtime(x, e, bits: int) -> Any:
    """x^e for an exponent held in a Dr.Jit variable (opaque: one kernel serves every exponent), by the
    same square-and-multiply as ``_power``: the result starts at 1 (1·y is exact) and takes each square
    where e has a bit set, so for every e the same roundings, the same bits. The squares above e's top
    bit are computed and never used."""
    result, base = dr.full(type(x), 1.0, dr.width(x)), x
    for k in range(bits):
        result = dr.select(((e >> k) & 1) != 0, result * base, result)
        if k + 1 < bits:
            base = base * base
    return result


@dataclass
class _Types:
    Float: Any
    UInt: Any
    Int: Any
    Bool: Any
    Array3: Any
    Bits: Any
    np_dtype: Any
    u: float  # unit round-off

    @classmethod
    def of(cls, precision: str) -> _Types:
        from drjit import llvm

        if precision == "f64":
            return cls(
                llvm.Float64,
                llvm.UInt32,
                llvm.Int32,
                llvm.Bool,
                llvm.Array3f64,
                llvm.UInt64,
                np.float64,
                2.0**-53,
            )
        if precision == "f32":
            return cls(
                llvm.Float,
                llvm.UInt32,
                llvm.Int32,
                llvm.Bool,
                llvm.Array3f,
                llvm.UInt32,
                np.float32,
                2.0**-24,
            )
        raise ValueError(f"unknown precision {precision!r} (f64 or f32)")


@dataclass
class Level:
    """One reflection level of the wavefront: its rays, hits and local shading (all Dr.Jit arrays)."""

    parent: Any  # index into the previous level (None for primary rays)
    o: Any
    d: Any
    shape_id: Any
    t: Any
    p: Any
    n: Any  # the shape's own normal (unflipped)
    local: Any  # ambient + diffuse + specular (in that order)
    kr: Any  # reflection colour of the hit material
    bg: Any  # the background contribution at this level
    terms: dict[str, Any] = field(default_factory=dict)
    record: dict[str, Any] = field(default_factory=dict)
    code: Any = None  # shape id, shadow and light-side decisions of each ray, packed (see ray_tree)
    spawn: Any = None  # which rays spawned a reflected ray (None: none did)
    slot: Any = None  # for those, the index of that ray in the next level (exclusive prefix sum of spawn)


class Tracer:
    """Traces batches of rays through one scene under one set of rules.

    ``prune=False`` switches off every optimisation that skips work (effects and per-ray pruning):
    it exists so a test can show that pruning leaves every output bit-identical.
    """

    def __init__(
        self,
        scene: Scene,
        rules: Rules,
        precision: str = "f64",
        prune: bool = True,
        runtime: bool | None = None,
        accel: str = "auto",
    ):
        """``runtime``: the rules a search varies most are values the kernel reads, not constants
        compiled into it -- specular_exponent, the camera's pixel_sample, pixel_shift, ray_origin, and
        near_root_only, two_sided, clamp, a numeric offset and offset_along (the rules that change which
        work is done stay compiled in: offset "error-bound", shadow_range, background, and the effects)
        -- and primary rays come from an array of pixel indices (``primary_rays(pixels)``). Renders
        that differ only in those, and renders of a few pixels, share one kernel: a search over
        candidates compiles each kernel once. The same bits either way (tested), at the cost of a few
        selects per ray. None (the default): read at run time for images below
        ``LOOP_FIRST_LEVEL_BELOW`` pixels, where a kernel's compile outweighs its runs -- a scene rendered
        under another rule (``--rule``, a profile, a test's sweep) then reuses the compiled kernels --
        and compiled in from there, where the selects would cost every ray and a compile is amortised.

        ``accel``: how rays find their shapes. "unrolled" tests every shape in code generated for this
        scene (constants compiled in: fastest for a few shapes, one kernel per layout); "bvh" gathers
        from the shape table and walks a BVH over the balls (``minirt.reference.accel``: kernels independent of
        the layout, time ~log N); "loop" gathers from the table and tests every ball in a loop (the
        brute force, with kernels independent of the layout: what the tree is tested against); "auto"
        picks "bvh" from ``ACCEL_MIN_SHAPES`` shapes on. The same bits every way (tested)."""
        require_llvm()
        self.scene, self.rules, self.precision, self.prune = scene, rules, precision, prune
        if runtime is None:
            runtime = scene.camera.width * scene.camera.height < LOOP_FIRST_LEVEL_BELOW
        self.runtime = runtime
        self.T = _Types.of(precision)
        if accel == "auto":
            accel = "bvh" if len(scene.shapes) >= ACCEL_MIN_SHAPES else "unrolled"
        if accel not in ACCELS:
            raise ValueError(f"unknown accel {accel!r} (auto, {', '.join(ACCELS)})")
        self.accel = accel
        self.table = ShapeTable(scene, self.T, with_tree=accel == "bvh") if accel != "unrolled" else None
        self._consts: dict[Any, Any] = {}  # ``_k``'s opaque values
        self._index = {id(s): k for k, s in enumerate(scene.shapes)}
        if precision == "f32":
            _check_float32_range(scene)
        if prune:
            self.effects = effects(scene, rules)
        else:
            self.effects = Effects(True, True, True, True, scene.max_depth > 0, scene.max_depth, True)

    # ---- small helpers -------------------------------------------------------------------
    def _rule(self, cond: bool) -> Any:
        """A rule's yes/no as the kernel sees it: under ``runtime`` an opaque Dr.Jit Bool (read at run
        time, one kernel for both answers), else the Python bool itself (compiled in)."""
        return dr.opaque(self.T.Bool, bool(cond)) if self.runtime else bool(cond)

    def _vec(self, v) -> Any:
        return self.T.Array3(*(float(c) for c in v))

    def _k(self, key, value, F=None) -> Any:
        """A value of the scene (a shape's, a material's, the light's, the camera's) as the unrolled path's
        kernels see it, in float type F (default the precision's; a sequence: a 3-vector). Compiled in as
        a literal -- or under ``runtime`` an opaque value the kernel reads, made once per Tracer under
        ``key``: a scene that differs only in its values (a ball moved, a colour changed, a campaign's
        defect) then reuses the compiled kernels, at the cost of the literals' folding (three_balls
        1024^2: 8.5 -> 9.7 ms a trace), which is why large images compile them in. The same value in the
        same operations either way, so the same bits (tested, as the table path, whose values are
        gathered, is). A literal is never cached: one made inside a symbolic conditional may not be used
        outside it."""
        F = F or self.T.Float
        if isinstance(value, int | float):
            kind, value = F, float(value)
        else:
            kind, value = (self.T.Array3 if F is self.T.Float else dr.llvm.Array3f64), [float(c) for c in value]
        if not self.runtime:
            return kind(*value) if isinstance(value, list) else kind(value)
        v = self._consts.get(key)
        if v is None:
            v = self._consts[key] = dr.opaque(kind, value)
        return v

    def _scene_vec(self, name: str) -> Any:
        """A scene constant (light, light_color, background): read from the shape table when there is
        one, else as ``_k`` gives it; the same value, the same bits."""
        if self.table is not None:
            return self.table.vec(name)
        sc = self.scene
        return self._k(
            name, {"light": sc.light.position, "light_color": sc.light.color, "background": sc.background}[name]
        )

    def _by_id(self, shape_id, values: list, zero) -> Any:
        """Per-lane lookup of a per-shape constant: a select chain (shapes are few)."""
        out = zero
        for k, v in enumerate(values):
            out = dr.select(shape_id == k, v, out)
        return out

    def _material_term(self, shape_id, name: str) -> Any:
        if self.table is not None:
            return dr.gather(self.T.Array3, self.table.material[name], self.T.UInt(shape_id), shape_id >= 0)
        vals = [self._k((name, k), getattr(s.material, name)) for k, s in enumerate(self.scene.shapes)]
        return self._by_id(shape_id, vals, self._vec((0.0, 0.0, 0.0)))

    # ---- Ball, Plane: intersect -------------------------------------------------------------
    def _ball_ray(self, center, r, o, d) -> tuple[Any, Any, Any, Any]:
        """What every ball test starts from: r, f = o - C, b = f·d and |f - b d|^2, the ray's squared
        distance from the centre (d unit). center, r: Dr.Jit values (constants or gathered from the table)."""
        f = o - center
        b = dr.dot(f, d)
        g = f - b * d
        return r, f, b, dr.dot(g, g)

    @staticmethod
    def _ball_disc(r, gg) -> Any:
        """r^2 - |g|^2, the discriminant over 4 (gg = |g|^2, ``_ball_ray``): one fused multiply-add, r^2
        exact inside it, minus a once-rounded squared length. What removes the textbook form's
        cancellation is g = f - (f·d) d (the ray's length is gone before anything is squared), not the
        factored (r - |g|)(r + |g|), which errs by the same ~2u |g|^2 and costs a square root per ball
        and ray."""
        return dr.fma(r, r, -gg)

    @staticmethod
    def _ball_c(r, f) -> Any:
        """c = |f|^2 - r^2 = (|f| - r)(|f| + r), the roots' product.

        The factored form on purpose: a secondary ray that starts on the ball (an offset of 0, or one
        below the hit point's rounding) has |f| within a few ulps of r, and the rounded square root
        often snaps to r itself, c = 0 exactly: the near root is exactly 0 (not t > 0) and the ray does
        not meet its own surface there. |f|^2 - r^2 in one fused multiply-add would give c the sign of the
        last bit of |f|^2 instead -- a coin toss between self-hit and not at every such point (acne), and
        one that another tracer's arithmetic tosses differently (tests/diagnose/test_diagnose.py's offset 0)."""
        lf = dr.sqrt(dr.squared_norm(f))  # dr.norm(f), spelt out: _ball_occludes reads |f|^2 alone
        return (lf - r) * (lf + r)

    def _ball(self, ball: Ball) -> tuple[Any, Any]:
        """A ball's centre and radius (``_k``)."""
        k = self._index[id(ball)]
        return self._k(("center", k), ball.center), self._k(("radius", k), ball.radius)

    def _plane(self, plane: Plane) -> tuple[Any, Any]:
        """A plane's normal and point (``_k``)."""
        k = self._index[id(plane)]
        return self._k(("normal", k), plane.normal), self._k(("point", k), plane.point)

    def intersect_ball(self, ball: Ball, o, d) -> Any:
        return self._ball_t(*self._ball(ball), o, d)

    def _ball_t(self, center, radius, o, d, gate: bool = False) -> Any:
        """t of the ray (o, d) at the ball, inf on a miss. ``gate``: the roots in a Dr.Jit conditional on
        the ray meeting the ball (disc >= 0), which a packet of rays that all pass it skips; a miss is
        inf either way, so the same bits."""
        r, f, b, gg = self._ball_ray(center, radius, o, d)
        disc = self._ball_disc(r, gg)
        hit = disc >= 0
        if not gate:
            return self._ball_roots(r, f, b, disc, hit)
        return dr.if_stmt((r, f, b, disc, hit), hit, self._ball_roots, lambda *_: self.T.Float(math.inf), label="ball")

    def _ball_roots(self, r, f, b, disc, hit) -> Any:
        F = self.T.Float
        c = self._ball_c(r, f)
        sq = dr.sqrt(dr.maximum(disc, 0))
        q = -(b + dr.copysign(sq, b))  # Vieta: never subtracts nearly equal numbers
        q_ok = q != 0  # q = 0 only for a ray starting on the surface, tangent: both roots 0
        t0 = dr.select(q_ok, c / q, 0)
        t1 = dr.select(q_ok, q, 0)
        tn, tf = dr.minimum(t0, t1), dr.maximum(t0, t1)
        inf = F(math.inf)
        nro = self._rule(self.rules.near_root_only)
        if nro is True:
            # "we are only interested in the smaller of the two intersection points, provided it is
            # not negative": from inside a ball the near root is behind the ray, so no hit at all.
            return dr.select(hit & (tn > 0), tn, inf)
        far = hit & (tf > 0)
        if nro is not False:
            far &= ~nro
        return dr.select(hit & (tn > 0), tn, dr.select(far, tf, inf))

    def intersect_plane(self, plane: Plane, o, d) -> Any:
        return self._plane_t(*self._plane(plane), o, d)

    def _plane_t(self, n, q, o, d, gate: bool = False) -> Any:
        """t of the ray (o, d) at the plane through q with normal n, inf on a miss. ``gate``: the division
        in a Dr.Jit conditional on numerator and denominator having the same strict sign, which a packet
        of rays that all leave the plane (shadow rays from above a floor) skips. Only then can the
        quotient be > 0; NaN, zeros and opposite signs give inf either way, so the same bits."""
        denom = dr.dot(n, d)
        num = dr.dot(n, q - o)
        if not gate:
            return self._plane_quotient(num, denom)
        towards = ((num > 0) & (denom > 0)) | ((num < 0) & (denom < 0))
        return dr.if_stmt((num, denom), towards, self._plane_quotient, lambda *_: self.T.Float(math.inf), label="plane")

    def _plane_quotient(self, num, denom) -> Any:
        t = num / denom
        ok = (denom != 0) & (t > 0) & (t < math.inf)  # parallel rays miss; never NaN
        return dr.select(ok, t, self.T.Float(math.inf))

    def intersect(self, shape, o, d, gate: bool = False) -> Any:
        """t of the ray (o, d) at the shape, inf on a miss; ``gate``: see ``_ball_t``, ``_plane_t``."""
        if isinstance(shape, Ball):
            return self._ball_t(*self._ball(shape), o, d, gate)
        return self._plane_t(*self._plane(shape), o, d, gate)

    def closest(self, o, d) -> tuple[Any, Any]:
        """Appendix 1: the closest hit over all shapes; ties keep the lower shape id."""
        # Full width from the start: with no shapes at all these are the results, one per ray.
        t_best = dr.full(self.T.Float, math.inf, dr.width(d))
        id_best = dr.full(self.T.Int, -1, dr.width(d))
        if self.table is not None:
            tab = self.table
            if tab.n_planes:
                t_best, id_best = accel.planes_closest(self, tab, o, d, t_best, id_best)
            if tab.n_balls and tab.tree is not None:
                t_best, id_best = accel.traverse(self, tab, o, d, t_best, id_best)
            elif tab.n_balls:
                t_best, id_best = accel.balls_closest_loop(self, tab, o, d, t_best, id_best)
            return id_best, t_best
        for k, s in enumerate(self.scene.shapes):
            tk = self.intersect(s, o, d, gate=True)
            closer = tk < t_best
            t_best = dr.select(closer, tk, t_best)
            id_best = dr.select(closer, k, id_best)
        return id_best, t_best

    # ---- normal, hit point ------------------------------------------------------------------
    def hit_point_and_normal(self, shape_id, o, d, t) -> tuple[Any, Any]:
        """p = o + t d and the hit shape's own normal: (p - C) / r for a ball, n for a plane.

        The hit shape's constants are selected first and the formula applied once, not once per
        shape: a third of the divisions with three balls, and the same operations on the same values
        for every ray, so the same bits.
        """
        p = o + t * d
        zero = self._vec((0.0, 0.0, 0.0))
        if self.table is not None:
            return self._hit_point_and_normal_table(shape_id, d, p)
        balls = [(k, s) for k, s in enumerate(self.scene.shapes) if isinstance(s, Ball)]
        planes = [(k, s) for k, s in enumerate(self.scene.shapes) if isinstance(s, Plane)]
        n = zero
        for k, s in planes:
            n = dr.select(shape_id == k, self._k(("normal", k), s.normal), n)
        if balls:
            is_ball = self.T.Bool(False)
            c, r, inv_r = zero, self.T.Float(1.0), self.T.Float(1.0)
            for k, s in balls:
                on = shape_id == k
                is_ball |= on
                ck, rk = self._ball(s)
                c = dr.select(on, ck, c)
                r = dr.select(on, rk, r)
                inv_r = dr.select(on, self._k(("inv_radius", k), self._reciprocal(s.radius)), inv_r)
            p, n = self._ball_normal(p, d, c, r, inv_r, is_ball, n)
        return p, n

    def _reciprocal(self, x: float) -> float:
        """1 / x rounded as the kernel's 1.0 / x in its precision (one IEEE division, correctly rounded
        either side): a per-shape constant the kernel selects instead of dividing per ray."""
        dt = self.T.np_dtype
        return float(dt(1.0) / dt(x))

    def _ball_normal(self, p, d, c, r, inv_r, is_ball, n) -> tuple[Any, Any]:
        """Where is_ball: the normal (p - C) / r of the ball (C, r) hit at p, and under error-bound p put
        back on it; elsewhere p and n as given."""
        reproject = self.rules.offset == "error-bound"
        # pbrt-style under error-bound: put the point back on the sphere, normal from it. Otherwise
        # (p - C) times the radius's reciprocal: one division instead of three (the normal moves by at
        # most an ulp more; it is not of unit length to within rounding either way), and that one made
        # on the host (inv_r, the same bits).
        nb = dr.normalize(p - c) if reproject else (p - c) * inv_r
        # A ball smaller than an ulp of its centre: the hit point can round onto the centre,
        # and p - C = 0 has no direction. Then the normal faces the ray.
        degenerate = ~(dr.squared_norm(nb) > 0) | ~dr.isfinite(dr.squared_norm(nb))
        nb = dr.select(degenerate, -d, nb)
        n = dr.select(is_ball, nb, n)
        if reproject:
            p = dr.select(is_ball, c + r * nb, p)
        return p, n

    def _hit_point_and_normal_table(self, shape_id, d, p) -> tuple[Any, Any]:
        """hit_point_and_normal with the hit shape's constants gathered from the table: the same
        operations on the same values as the select chains, so the same bits."""
        T, tab = self.T, self.table
        hit = shape_id >= 0
        k = T.UInt(shape_id)
        is_ball = dr.gather(T.Bool, tab.is_ball, k, hit)
        n = dr.gather(T.Array3, tab.plane_normal, k, hit & ~is_ball)
        c = dr.gather(T.Array3, tab.center, k, is_ball)
        r = dr.select(is_ball, dr.gather(T.Float, tab.radius, k, is_ball), T.Float(1.0))
        inv_r = dr.select(is_ball, dr.gather(T.Float, tab.inv_radius, k, is_ball), T.Float(1.0))
        return self._ball_normal(p, d, c, r, inv_r, is_ball, n)

    def error_bound(self, shape_id, p, o) -> Any:
        """Absolute error bound of a hit point p of the ray from o, per shape (measured to give 0 self-hits;
        tests/reference/test_hard_cases.py).

        Ball: gamma(6) (r + |p|) -- re-projection costs about 5 roundings of magnitude r + |p|, one more
        for the normalisation; the ray's origin no longer matters. Plane: gamma(4) (|a| + |p| + |o|) -- the
        point-normal form's dot products, and p = o + t d, whose distance from the plane errs by the
        rounding of n·o too: a point near the origin seen from far (fuzz start_2026_175: |p| 0.19, |o| 3.09)
        lies a few u |o| off its plane, far more than u |p|, and a bound without |o| left it there.
        """
        u = self.T.u
        lp, lo = dr.norm(p), dr.norm(o)
        if self.table is not None:
            k, hit = self.T.UInt(shape_id), shape_id >= 0
            factor = dr.gather(self.T.Float, self.table.err_factor, k, hit)
            is_ball = dr.gather(self.T.Bool, self.table.is_ball, k, hit)
            extra = dr.select(is_ball, self.T.Float(0.0), lo)
            return factor * ((dr.gather(self.T.Float, self.table.err_length, k, hit) + lp) + extra)
        vals = []
        for k, s in enumerate(self.scene.shapes):
            if isinstance(s, Ball):  # + 0.0: the table path's sum, same bits
                vals.append(gamma(6, u) * ((self._k(("radius", k), s.radius) + lp) + 0.0))
            else:
                vals.append(gamma(4, u) * ((self._k(("abs_distance", k), abs(s.distance)) + lp) + lo))
        return self._by_id(shape_id, vals, self.T.Float(0))

    def offset_origin(self, p, n, err, direction, outward=None) -> Any:
        """Start of a secondary ray leaving p in `direction` (n: the shading normal). ``outward`` (error-bound
        only): where true, offset to n's side whatever the direction (see ``_outward``)."""
        off = self.rules.offset
        if off != "error-bound" and self.runtime:
            along = dr.select(dr.opaque(self.T.Bool, self.rules.offset_along == "ray"), direction, n)
            return p + dr.opaque(self.T.Float, float(off)) * along
        if off != "error-bound":
            if self.rules.offset_along == "ray":
                return p + self.T.Float(off) * direction  # rule offset_along "ray": along the new ray
            return p + self.T.Float(off) * n  # the exercise's hint: "add a small fraction of normal"
        # (offset_along applies to numeric offsets only; validation rejects "ray" with "error-bound".)
        # Offset along n by the error bound, on the side the new ray leaves to, then one more ulp
        # away from p in each component (pbrt-v4's OffsetRayOrigin).
        side = dr.select(dr.dot(n, direction) < 0, self.T.Float(-1.0), self.T.Float(1.0))
        if outward is not None:
            side = dr.select(outward, self.T.Float(1.0), side)
        delta = side * err * n
        q = p + delta
        return self.T.Array3(*(self._ulp_away(q[i], delta[i]) for i in range(3)))

    def _outward(self, shape_id) -> Any:
        """Where secondary rays must start outside the hit ball, whichever way they leave: under
        near_root_only with the error-bound offset. A shadow ray from a point facing away from the light
        runs into its own ball; started on the inside (the side the ray leaves to), near_root_only would
        not see that ball at all and the point would be lit -- every back-face self-shadow lost. Started
        outside by the error bound, its near root is in front (t ~ err / cos > 0), as under a numeric
        offset along the normal, and as without near_root_only (the far root from inside). Under
        near_root_only a ball is only hit from outside, so its shading normal is the outward one.
        None when the rule does not apply (the offset's side is then that of the new ray)."""
        nro = self._rule(self.rules.near_root_only)
        balls = [k for k, s in enumerate(self.scene.shapes) if isinstance(s, Ball)]
        if self.rules.offset != "error-bound" or nro is False or not balls:
            return None
        if self.table is not None:
            is_ball = dr.gather(self.T.Bool, self.table.is_ball, self.T.UInt(shape_id), shape_id >= 0)
        else:
            is_ball = self.T.Bool(False)
            for k in balls:
                is_ball |= shape_id == k
        return is_ball if nro is True else is_ball & nro

    def _ulp_away(self, x, delta) -> Any:
        T = self.T
        bits = dr.reinterpret_array(T.Bits, x)
        grow = ((delta > 0) & (x > 0)) | ((delta < 0) & (x < 0))
        shrink = ((delta > 0) & (x < 0)) | ((delta < 0) & (x > 0))
        bits = dr.select(grow, bits + 1, dr.select(shrink, bits - 1, bits))
        y = dr.reinterpret_array(T.Float, bits)
        tiny = float(np.finfo(T.np_dtype).smallest_subnormal)
        return dr.select((x == 0) & (delta != 0), dr.copysign(T.Float(tiny), delta), y)

    # ---- shading ----------------------------------------------------------------------------
    def shadow_blocked(self, o, s, light_dist, record: bool = False) -> tuple[Any, list[Any]]:
        """Is the shadow ray blocked? Rule shadow_range: 'any' (anything with t > 0) or 'to-light'.

        Under 'any' only the existence of a root with t > 0 matters; for a ball the signs of the
        quantities ``intersect_ball`` computes already decide it (``occludes_ball``), without the
        square root and the division that give t: a quarter less time for the whole trace kernel on
        three_balls. The balls' distances are then computed only when ``record`` asks.
        """
        if self.table is not None and not record:
            return self._shadow_blocked_table(o, s, light_dist), []
        blocked = self.T.Bool(False)
        ts = []
        for shape in self.scene.shapes:
            need_t = record or self.rules.shadow_range != "any" or not isinstance(shape, Ball)
            tk = self.intersect(shape, o, s, gate=True) if need_t else None
            if record:
                ts.append(tk)
            if self.rules.shadow_range != "any":
                blocked |= tk < light_dist
            elif isinstance(shape, Ball):
                blocked |= self.occludes_ball(shape, o, s)
            else:
                # Planes keep t: a near-parallel ray's quotient can overflow to inf (a miss), which
                # signs alone would not see; a division is cheap beside a ball's square roots.
                blocked |= tk < math.inf
        return blocked, ts

    def _shadow_blocked_table(self, o, s, light_dist) -> Any:
        """shadow_blocked through the shape table: planes in a loop, balls through the BVH (a ray stops
        at its first blocker). The same decisions per shape, so the same answer."""
        tab, to_light = self.table, self.rules.shadow_range != "any"
        blocked = dr.full(self.T.Bool, False, dr.width(s))
        if tab.n_planes:
            blocked = accel.planes_block(self, tab, o, s, light_dist, to_light)
        if tab.n_balls:
            if to_light:
                blocks = lambda c, r: self._ball_t(c, r, o, s) < light_dist  # noqa: E731
                bound = light_dist
            else:
                blocks = lambda c, r: self._ball_occludes(c, r, o, s)  # noqa: E731
                bound = dr.full(self.T.Float, math.inf, dr.width(s))
            if tab.tree is not None:
                by_balls, _ = accel.traverse(self, tab, o, s, bound, None, blocks=blocks)
            else:
                by_balls = accel.balls_each(
                    self, tab, o, lambda acc, c, r, _: acc | blocks(c, r), dr.full(self.T.Bool, False, dr.width(s)),
                    stop=lambda acc: acc,
                )  # fmt: skip
            blocked = blocked | by_balls
        return blocked

    def occludes_ball(self, ball: Ball, o, d) -> Any:
        k = self._index[id(ball)]
        lo, hi = sqrt_bounds(ball.radius, self.T.np_dtype)
        return self._ball_occludes(*self._ball(ball), o, d, (self._k(("sqrt_lo", k), lo), self._k(("sqrt_hi", k), hi)))

    def _ball_occludes(self, center, radius, o, d, bounds: tuple[float, float] | None = None) -> Any:
        """intersect_ball(ball, o, d) < inf, from signs: the roots' product is c = |f|^2 - r^2 (d is
        unit) and their sum -2 b. Both roots > 0 iff c > 0 and b < 0; exactly one iff c < 0; c = 0
        gives roots 0 and -2 b. This decides as intersect_ball's t does: there q = -(b + sign(b) sqrt)
        has the sign of -b (or is 0 only where both roots are 0), so c / q and q carry these signs; the
        two differ only if c / q underflows to 0, i.e. a hit closer than 1e-308 relative, which the
        scene's 1e-100 limits and the ray offsets exclude."""
        r, f, b, gg = self._ball_ray(center, radius, o, d)
        if bounds is None:
            c = self._ball_c(r, f)
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
        hit = self._ball_disc(r, gg) >= 0
        both = c_pos & (b < 0)
        nro = self._rule(self.rules.near_root_only)
        if nro is True:
            return hit & both
        other = c_neg | (c_zero & (b < 0))
        if nro is not False:
            other &= ~nro
        return hit & (both | other)

    def shadow_margin(self, o, s, light_dist, hit) -> Any:
        """Per shadow ray, the absolute distance from the nearest ball silhouette in front of it (before
        the light under shadow_range "to-light"): how far its origin may move before the decision can
        flip. Large (1e30) when no ball is in front; planes' decisions are the light's side, not this."""
        F = self.T.Float
        out = dr.full(F, 1e30, dr.width(s))

        def nearer(out, center, radius, _id=None):
            r, _, b, gg = self._ball_ray(center, radius, o, s)
            front = -b > -r
            if self.rules.shadow_range != "any":
                front &= -b < light_dist + r
            return dr.select(front, dr.minimum(out, dr.abs(dr.sqrt(gg) - r)), out)

        if self.table is not None:
            if self.table.n_balls:
                out = accel.balls_each(self, self.table, o, nearer, out)
        else:
            for ball in self.scene.shapes:
                if isinstance(ball, Ball):
                    out = nearer(out, *self._ball(ball))
        return dr.select(hit, out, F(1e30))

    def shade_level(
        self, o, d, parent, depth_left: int, record: bool, margins: Any = False, gate: bool = False
    ) -> tuple[Level, Any]:
        """Intersect one level's rays and shade them locally; return the level and the next rays' mask.

        ``gate`` (not with ``record``): the shading -- hit point, normal, shadow ray, terms,
        next ray -- runs in a Dr.Jit conditional on the hit, which a packet of rays that all miss skips
        (half the packets of three_balls' first level, the sky); the misses get the values the shading
        gives them (zeros, p = o + 0 d), so the same bits either way."""
        shape_id, t = self.closest(o, d)
        hit = shape_id >= 0
        t = dr.select(hit, t, math.inf)
        if not gate:
            return self._shade(o, d, parent, shape_id, hit, t, depth_left, record, margins)
        fx, zero = self.effects, self._vec((0.0, 0.0, 0.0))
        names = [k for k in ("ambient", "diffuse", "specular") if getattr(fx, k)]
        spawns = fx.reflection and depth_left > 0
        margins = margins if self._has_margins() else False

        def on_hit(o, d, shape_id, hit, t):
            lvl, spawn = self._shade(o, d, None, shape_id, hit, t, depth_left, False, margins)
            ro, rd = lvl.record["next"] if spawns else (zero, zero)
            terms = [lvl.terms[k] for k in names]
            margin = [lvl.record["shadow_margin"]] if margins is not False else []
            return lvl.p, lvl.n, lvl.local, lvl.kr, terms, ro, rd, spawn if spawns else hit, lvl.code, margin

        def on_miss(o, d, shape_id, hit, t):
            p = o + dr.select(hit, t, 0) * d  # hit_point_and_normal's p of a miss
            # a miss's decision code: id -1, unlit, s·n = 0 (its normal is 0); its margin: shadow_margin's.
            # One per ray, as the shading's are: where no ray can hit (no shapes) this branch is all there
            # is, and the ray-tree hash and the margins are read per pixel.
            n = dr.width(hit)
            code, margin = dr.full(self.T.Int, -4, n), [dr.full(self.T.Float, 1e30, n)] if margins is not False else []
            return p, zero, zero, zero, [zero for _ in names], zero, zero, self.T.Bool(False), code, margin

        p, n, local, kr, terms, ro, rd, spawn, code, margin = dr.if_stmt(
            (o, d, shape_id, hit, t), hit, on_hit, on_miss, label="shade"
        )
        lvl = Level(
            parent, o, d, shape_id, t, p, n, local, kr, self._background(hit), dict(zip(names, terms, strict=True))
        )
        lvl.code = code
        if margins is not False:
            lvl.record["shadow_margin"] = margin[0]
        if not spawns:
            return lvl, None
        lvl.record["next"] = (ro, rd)
        return lvl, spawn

    def _shade(self, o, d, parent, shape_id, hit, t, depth_left: int, record: bool, margins: Any) -> tuple[Level, Any]:
        """shade_level after the closest hit (shape_id, hit, t: inf on a miss). ``margins``: True, False, or
        a mask of the rays whose shadow margins are wanted (the others get 1e30, shadow_margin's none)."""
        fx = self.effects
        zero = self._vec((0.0, 0.0, 0.0))
        p, n = self.hit_point_and_normal(shape_id, o, d, dr.select(hit, t, 0))
        ns = n
        two_sided = self._rule(self.rules.two_sided)
        if two_sided is not False:
            flip = dr.dot(d, n) > 0  # shading normal faces the incoming ray
            ns = dr.select(flip if two_sided is True else flip & two_sided, -n, n)
        rec: dict[str, Any] = {}
        terms: dict[str, Any] = {}
        local = zero
        if fx.ambient:
            terms["ambient"] = dr.select(hit, self._material_term(shape_id, "ambient"), zero)
            local = local + terms["ambient"]
        r = d - 2 * dr.dot(d, ns) * ns  # reflected incoming direction
        err = self.error_bound(shape_id, p, o) if self.rules.offset == "error-bound" else None
        outward = self._outward(shape_id)
        clamp_all, clamp_specular = self._rule(self.rules.clamp is True), self._rule(self.rules.clamp == "specular")
        if fx.diffuse or fx.specular:
            lpos = self._scene_vec("light")
            lc = self._scene_vec("light_color")
            to_light = lpos - p
            light_dist = dr.norm(to_light)
            # The light exactly at the hit point has no direction: that point is unlit (not 0/0).
            at_light = ~(light_dist > 0)
            s = dr.select(at_light, zero, to_light * (1.0 / dr.select(at_light, 1, light_dist)))
            sn = dr.dot(s, ns)
            lit = hit & ~at_light
            if fx.shadows:
                so = self.offset_origin(p, ns, err, s, outward)
                blocked, shadow_ts = self.shadow_blocked(so, s, light_dist, record)
                lit = hit & ~blocked
                if margins is True:
                    rec["shadow_margin"] = self.shadow_margin(so, s, light_dist, hit)
                elif margins is not False:  # in a conditional: the loop's later levels skip the ball loop
                    rec["shadow_margin"] = dr.if_stmt(
                        (so, s, light_dist, hit, margins),
                        margins,
                        lambda so, s, light_dist, hit, _: self.shadow_margin(so, s, light_dist, hit),
                        lambda *_: self.T.Float(1e30),
                        label="margins",
                    )
                if record:
                    rec.update(shadow_origin=so, shadow_dir=s, light_dist=light_dist, shadow_ts=shadow_ts)
            if fx.diffuse:
                if isinstance(clamp_all, bool):
                    fac = dr.maximum(sn, 0) if clamp_all else sn  # "specular": s·n raw
                else:
                    fac = dr.select(clamp_all, dr.maximum(sn, 0), sn)
                terms["diffuse"] = dr.select(lit, lc * self._material_term(shape_id, "diffuse") * fac, zero)
                local = local + terms["diffuse"]
            if fx.specular:
                rs = dr.dot(r, s)
                e = self.rules.specular_exponent
                if self.runtime:
                    pw = _power_runtime(rs, dr.opaque(self.T.UInt, e), SPECULAR_EXPONENT_MAX.bit_length())
                else:
                    pw = _power(rs, e)  # (r·s)^e: for e = 8 rs2, rs4, rs4 * rs4
                on = lit
                if self.runtime:
                    on = lit & dr.select(clamp_all, (sn > 0) & (rs > 0), ~clamp_specular | (rs > 0))
                elif clamp_all:
                    on = lit & (sn > 0) & (rs > 0)
                elif clamp_specular:
                    on = lit & (rs > 0)
                terms["specular"] = dr.select(on, lc * self._material_term(shape_id, "specular") * pw, zero)
                local = local + terms["specular"]
        bg = self._background(hit)
        kr = self._material_term(shape_id, "reflection") if fx.reflection else zero
        spawn = None
        if fx.reflection and depth_left > 0:
            spawn = hit
            if self.prune:
                spawn = hit & dr.any(kr != 0)
        lvl = Level(parent, o, d, shape_id, t, p, n, local, kr, bg, terms, rec)
        # The discrete decisions this ray's colour jumps with: which shape, lit or not, and under clamp = true
        # the side of the surface the light is on (the specular lobe is cut at s·n = 0 with (r·s)^e > 0; the
        # diffuse term and the cut at r·s = 0 are continuous, so clamp = "specular" adds none). Packed as an
        # integer.
        code = self.T.Int(shape_id) * 4
        if fx.diffuse or fx.specular:
            code = code + dr.select(lit, 1, 0)
            if fx.specular and clamp_all is not False:
                code = code + dr.select((sn > 0) if clamp_all is True else (sn > 0) & clamp_all, 2, 0)
        lvl.code = code
        if record:
            rec.update(shading_normal=ns, reflected=r, error_bound=err)
        if spawn is not None:
            ro = self.offset_origin(p, ns, err, r, outward)
            lvl.record["next"] = (ro, r)
        return lvl, spawn

    def _has_margins(self) -> bool:
        """Whether shading records shadow margins when asked: only where shadow rays are cast (``_shade``)."""
        fx = self.effects
        return fx.shadows and (fx.diffuse or fx.specular)

    def _background(self, hit) -> Any:
        """The background term of a ray that hit (``hit``) or missed: rule background."""
        zero = self._vec((0.0, 0.0, 0.0))
        if not self.effects.background or self.rules.background == "none":
            return zero
        bgc = self._scene_vec("background")
        return dr.select(hit, bgc, zero) if self.rules.background == "on-hit" else dr.select(hit, zero, bgc)

    def trace(
        self,
        o,
        d,
        record: bool = False,
        tree: bool = False,
        out: dict[str, Any] | None = None,
        terms: Collection[str] | None = None,
        path: str = "auto",
    ) -> tuple[Any, list[Level]]:
        """TraceRay for a batch: returns the colour of each ray and its levels (the first level's rays,
        hits and terms first).

        ``path`` "fused": every level in one kernel (``_trace_fused``); "wavefront": each level a kernel
        of its own, the rays that go on compacted between them; "auto": the wavefront with ``record``
        (whose levels keep every ray's values) and from ``WAVEFRONT_MIN_BALLS`` balls (a tree's traversal
        then costs most, and runs faster over compacted, coherent packets), else fused. The same
        operations on the same values either way, so the same bits (tested).

        Memory traffic is what limits a wavefront, so each level writes only what is read later:
        every level its hit ids and local colour (the reflection colour and the background are
        re-derived from the ids in the combining pass); the first level, or every level when
        ``record``, also its terms, t, hit points and normals.

        ``out`` (a dict to fill): the first level's outputs are written by the kernels that compute
        them, straight into the interleaved float64 buffers NumPy views (``_scatter_out``), instead of
        being stored per component and copied by a read-out kernel afterwards. ``out`` then holds
        "color", "position", "normal", "term.<name>" (4 N, see ``_scatter_out``) and "t" (N, float64);
        the first level's colour, terms, hit points and normals are not kept per component (unless
        ``record``). ``terms``: the names of the terms written to ``out`` (default every term the
        effects compute); the others still add to the colour, but their 32 bytes a ray are never written.
        """
        if path not in ("auto", "fused", "wavefront"):
            raise ValueError(f"unknown path {path!r} (auto, fused, wavefront)")
        if path == "auto":
            path = self._path(record)
        if path == "fused":
            if record:
                raise ValueError("record needs the wavefront path")
            return self._trace_fused(o, d, out, terms, tree)
        with dr.scoped_set_flag(dr.JitFlag.FastMath, False):
            rays = max(dr.width(a[k]) for a in (o, d) for k in range(3))  # the first level's
            levels: list[Level] = []
            parent = None
            depth = self.effects.reflection_depth if self.effects.reflection else 0
            for level in range(depth + 1):
                lvl, spawn = self.shade_level(o, d, parent, depth - level, record, margins=tree and level == 0)
                levels.append(lvl)
                # One fused kernel per level: everything later steps read is evaluated together, so
                # nothing (intersection, shadow rays) is recomputed when it is read back.
                outputs = [lvl.shape_id, lvl.local]
                if tree:
                    outputs.append(lvl.code)
                    if "shadow_margin" in lvl.record:
                        outputs.append(lvl.record["shadow_margin"])
                if level == 0 and out is not None:
                    vectors = {"position": lvl.p, "normal": lvl.n} | {
                        "term." + k: v for k, v in lvl.terms.items() if terms is None or k in terms
                    }
                    self._scatter_out(out, vectors, rays, lvl.shape_id >= 0, masked=("position", "normal"))
                    out["t"] = dr.llvm.Float64(lvl.t)
                    outputs.append(out["t"])
                    if record:
                        outputs += [lvl.t, lvl.p, lvl.n, lvl.terms]
                elif level == 0 or record:
                    outputs += [lvl.t, lvl.p, lvl.n, lvl.terms]
                if spawn is None:
                    dr.eval(*outputs)
                    break
                ro, rd = lvl.record["next"]
                dr.eval(*outputs, spawn, ro, rd)
                idx = dr.compress(spawn)
                if dr.width(idx) == 0:
                    break
                lvl.spawn, lvl.slot = spawn, dr.prefix_sum(self.T.UInt(spawn))
                o, d, parent = dr.gather(self.T.Array3, ro, idx), dr.gather(self.T.Array3, rd, idx), idx
            # Back to front: c = ambient + diffuse + specular + kr * trace(reflected) + background.
            # A ray's reflected colour is gathered from the next level through its slot (0 where it
            # spawned none): fused into this level's kernel, where a scatter into zeros would cost a
            # memset and a kernel of its own per level.
            child = child_tree = None
            for k in range(len(levels) - 1, -1, -1):
                lvl = levels[k]
                c = lvl.local
                if tree:  # the decisions of the whole ray tree below this ray, hashed (collisions only hide)
                    below = self.T.UInt(0)
                    if child_tree is not None:
                        below = dr.gather(self.T.UInt, child_tree, lvl.slot, active=lvl.spawn)
                    lvl.record["tree"] = _tree_hash(self.T.UInt(lvl.code), below)
                    child_tree = lvl.record["tree"]  # evaluated with this level's colour, in one kernel
                if self.effects.reflection:
                    refl = self._vec((0.0, 0.0, 0.0))
                    if child is not None:
                        refl = dr.gather(self.T.Array3, child, lvl.slot, active=lvl.spawn)
                    lvl.terms["reflection"] = lvl.kr * refl
                    c = c + lvl.terms["reflection"]
                if self.effects.background:
                    lvl.terms["background"] = lvl.bg
                    c = c + lvl.bg
                extra = [lvl.record["tree"]] if tree else []
                if k == 0 and out is not None:
                    late = [k for k in ("reflection", "background") if k in lvl.terms and (terms is None or k in terms)]
                    vectors = {"color": c} | {"term." + name: lvl.terms[name] for name in late}
                    self._scatter_out(out, vectors, rays)
                    dr.eval(*extra, *([c, lvl.terms] if record else []))  # runs the scatters too
                elif k == 0 or record:
                    dr.eval(c, lvl.terms, *extra)
                else:
                    dr.eval(c, *extra)
                child = c
            return child, levels

    def _path(self, record: bool) -> str:
        """The path ``trace(path="auto")`` takes."""
        many = self.table is not None and self.table.n_balls >= WAVEFRONT_MIN_BALLS
        return "wavefront" if record or many else "fused"

    def _trace_fused(
        self, o, d, out: dict[str, Any] | None, terms: Collection[str] | None, tree: bool = False
    ) -> tuple[Any, list[Level]]:
        """``trace`` in one kernel: the first level in straight-line code, the deeper ones in a Dr.Jit loop
        (one iteration per reflection), then the colours combined back to front. Below
        ``LOOP_FIRST_LEVEL_BELOW`` rays the first level is the loop's first iteration instead
        (``_levels_looped``): the same operations, the shading code in the kernel once.

        A wavefront stores each level's rays, ids and colours and compacts the rays that go on; here a
        ray's levels stay in registers and a packet of rays leaves the loop when its last ray stops
        reflecting (three_balls 1024^2, f64: 21.6 -> 16.1 ms; f32 13.2 -> 8.5 ms). What the combination
        needs of each deeper level is carried through the loop: its local colour and its hit id, from
        which the reflection colour and the background are re-derived as the wavefront's combining pass
        does (an id of -2: the level was not reached, its colour 0 -- what the wavefront gathers for a
        ray that spawned none). Every level computes what ``shade_level`` computes, in the same order.

        The first level's outputs (``out``, ``terms``: as for ``trace``) are written by this kernel. Without
        ``out`` nothing is evaluated: the colour and the first level's arrays are Dr.Jit expressions, and
        what the caller evaluates together runs as one kernel (``dr.eval(c, levels[0].t)``); each array
        evaluated on its own would run a kernel of its own (the same bits, more time); a component that is
        one constant for every ray (a lone plane's normal) may be an array of width 1. Evaluating only
        the colour skips the 160 bytes a ray of first-level arrays: 18.2 -> 14.7 ms on three_balls 1024^2.

        ``tree``: as for ``trace``, the first level's record holds "tree" (each deeper level's decision code
        is carried through the loop like its id and hashed back to front as the wavefront does) and
        "shadow_margin" (a miss's is shadow_margin's 1e30, which the shading's conditional gives it)."""
        fx = self.effects
        depth = fx.reflection_depth if fx.reflection else 0
        with dr.scoped_set_flag(dr.JitFlag.FastMath, False):
            rays = max(dr.width(a[k]) for a in (o, d) for k in range(3))
            if depth > 0 and rays < LOOP_FIRST_LEVEL_BELOW:
                return self._trace_looped(o, d, rays, depth, out, terms, tree)
            lvl, spawn = self.shade_level(o, d, None, depth, False, margins=tree, gate=True)
            refl, below = None, self.T.UInt(0)
            if fx.reflection:
                refl = self._vec((0.0, 0.0, 0.0))
                if spawn is not None:
                    refl, below = self._reflected(spawn, *lvl.record.pop("next"), depth, tree)
            c = self._first_colour(lvl, refl)
            if tree:
                lvl.record["tree"] = _tree_hash(self.T.UInt(lvl.code), below)
            if out is None:  # lazy: the caller evaluates what it reads with the colour, in one kernel
                return c, [lvl]
            wanted = self._term_names(terms)
            bufs = self._out_buffers(["color", "position", "normal"] + ["term." + k for k in wanted], rays)
            vectors = {"position": lvl.p, "normal": lvl.n} | {"term." + k: lvl.terms[k] for k in wanted}
            self._queue_out(bufs, vectors, rays, lvl.shape_id >= 0, masked=("position", "normal"))
            return self._write_first(out, bufs, lvl, c, rays)

    def _trace_looped(self, o, d, rays: int, depth: int, out, terms, tree: bool) -> tuple[Any, list[Level]]:
        """``_trace_fused`` with the first level as the loop's first iteration (``_levels_looped``)."""
        if out is None:
            lvl, c = self._levels_looped(o, d, rays, depth, tree)
            return c, [lvl]
        wanted = self._term_names(terms)
        bufs = self._out_buffers(["color", "position", "normal"] + ["term." + k for k in wanted], rays)
        lvl, c = self._levels_looped(o, d, rays, depth, tree, bufs, wanted)
        late = {"term." + k: lvl.terms[k] for k in ("reflection", "background") if k in wanted}
        self._queue_out(bufs, late, rays)
        return self._write_first(out, bufs, lvl, c, rays)

    def _term_names(self, terms: Collection[str] | None) -> list[str]:
        """The terms a first level has (those the effects compute), among ``terms`` (None: all), in TERMS' order."""
        return [k for k in TERMS if getattr(self.effects, k) and (terms is None or k in terms)]

    def _first_colour(self, lvl: Level, refl) -> Any:
        """The first level's colour: its local colour, plus kr times the reflected colour ``refl`` (None: no
        reflection effect) and the background, each also kept as a term."""
        c = lvl.local
        if refl is not None:
            lvl.terms["reflection"] = lvl.kr * refl
            c = c + lvl.terms["reflection"]
        if self.effects.background:
            lvl.terms["background"] = lvl.bg
            c = c + lvl.bg
        return c

    def _write_first(
        self, out: dict[str, Any], bufs: dict[str, Any], lvl: Level, c, rays: int
    ) -> tuple[Any, list[Level]]:
        """The end of a fused trace with ``out``: the colour's writes queued after the first level's, the
        buffers into ``out`` with t, and the one kernel run (with the diagnostics, when recorded)."""
        self._queue_out(bufs, {"color": c}, rays)
        del bufs["zero"]
        out.update(bufs)
        out["t"] = dr.llvm.Float64(lvl.t)
        extra = [lvl.record[k] for k in ("tree", "shadow_margin") if k in lvl.record]
        dr.eval(out["t"], lvl.shape_id, *extra)  # runs the scatters too
        return c, [lvl]

    def _levels_looped(
        self, o, d, rays: int, depth: int, tree: bool = False, bufs: dict[str, Any] | None = None, wanted=()
    ) -> tuple[Level, Any]:
        """Levels 0 .. depth in one Dr.Jit loop, the first level its first iteration: the shading code is
        in the kernel once (a third less to compile), and what later steps read of the first level (t,
        hit point, normal, terms) is carried through the loop like every level's colour and id -- or,
        with ``bufs`` (``_out_buffers``), its hit point, normal and the ``wanted`` terms among ambient,
        diffuse and specular are written there by the first iteration and not carried (the level's p, n
        and those terms are then absent): carried, they cost an f64 render a fifth more time. ``tree``:
        each level's decision code is carried too, and the first level's shadow margins (computed in the
        first iteration only). Returns the first level and the colour, combined back to front
        as ``_reflected`` does (and with ``tree`` the ray-tree hash in its record)."""
        T, fx = self.T, self.effects
        shaded = [k for k in ("ambient", "diffuse", "specular") if getattr(fx, k)]
        carried = shaded if bufs is None else []
        zf = dr.zeros(T.Float, rays)

        def z3():
            return T.Array3(dr.zeros(T.Float, rays), dr.zeros(T.Float, rays), dr.zeros(T.Float, rays))

        o, d = T.Array3(o) + z3(), T.Array3(d) + z3()  # every loop variable as wide as the rays
        margins = tree and self._has_margins()
        first = [zf] + ([zf] if margins else []) + ([z3(), z3()] if bufs is None else []) + [z3() for _ in carried]
        local = [z3() for _ in range(depth + 1)]
        ids = [dr.full(T.Int, -2, rays) for _ in range(depth + 1)]
        codes = [dr.zeros(T.Int, rays) for _ in range(depth + 1)] if tree else []
        nf, m = len(first), depth + 1

        def body(k, active, ro, rd, *state):
            first, local = list(state[:nf]), list(state[nf : nf + m])
            ids, codes = list(state[nf + m : nf + 2 * m]), list(state[nf + 2 * m :])
            at0 = k == 0
            lvl, spawn = self.shade_level(ro, rd, None, 1, False, margins=at0 if tree else False, gate=True)
            new = [lvl.t] + ([lvl.record["shadow_margin"]] if margins else [])
            new += ([lvl.p, lvl.n] if bufs is None else []) + [lvl.terms[name] for name in carried]
            first = [dr.select(at0, a, b) for a, b in zip(new, first, strict=True)]
            if bufs is not None:
                vectors = {"position": lvl.p, "normal": lvl.n} | {
                    "term." + k: lvl.terms[k] for k in shaded if k in wanted
                }
                hit = lvl.shape_id >= 0

                def write(vectors, hit):
                    self._queue_out(bufs, vectors, rays, hit, ("position", "normal"))

                dr.if_stmt((vectors, hit), at0, write, lambda vectors, hit: None, label="first level")
            _keep_level(k, lvl, local, ids, codes)
            k = k + 1
            return (k, spawn & (k <= depth), *lvl.record["next"], *first, *local, *ids, *codes)

        state = dr.while_loop(
            (dr.zeros(T.UInt, rays), dr.full(T.Bool, True, rays), o, d, *first, *local, *ids, *codes),
            lambda k, active, *_: active,
            body,
            label="levels",
        )
        first, local = state[4 : 4 + nf], state[4 + nf : 4 + nf + m]
        ids, codes = state[4 + nf + m : 4 + nf + 2 * m], state[4 + nf + 2 * m :]
        refl, below = self._combine(local[1:], ids[1:], codes[1:])
        shape_id = ids[0]
        t, rest = first[0], first[2:] if margins else first[1:]
        p, n = rest[:2] if bufs is None else (None, None)
        kr = self._material_term(shape_id, "reflection")
        terms = dict(zip(carried, first[nf - len(carried) :], strict=True))
        lvl = Level(None, o, d, shape_id, t, p, n, local[0], kr, self._background(shape_id >= 0), terms)
        if tree:
            lvl.code = codes[0]
            lvl.record["tree"] = _tree_hash(T.UInt(codes[0]), below)
            if margins:
                lvl.record["shadow_margin"] = first[1]
        return lvl, self._first_colour(lvl, refl)

    def _reflected(self, active, ro, rd, depth: int, tree: bool = False) -> tuple[Any, Any]:
        """The colour ``trace`` gives the reflected rays (ro, rd) where ``active``, 0 elsewhere: levels 1 ..
        depth in a Dr.Jit loop (see ``_trace_fused``); and, with ``tree``, the hash of their ray trees (0
        where not active; without ``tree`` a constant 0)."""
        T = self.T
        n = dr.width(active)
        local = [T.Array3(dr.zeros(T.Float, n), dr.zeros(T.Float, n), dr.zeros(T.Float, n)) for _ in range(depth)]
        ids = [dr.full(T.Int, -2, n) for _ in range(depth)]
        codes = [dr.zeros(T.Int, n) for _ in range(depth)] if tree else []
        k = dr.zeros(T.UInt, n)

        def body(k, active, ro, rd, *levels):
            local, ids, codes = list(levels[:depth]), list(levels[depth : 2 * depth]), list(levels[2 * depth :])
            # depth_left 1: the next rays are made at every level (the last one's go unused)
            lvl, spawn = self.shade_level(ro, rd, None, 1, False, gate=True)
            _keep_level(k, lvl, local, ids, codes)
            k = k + 1
            return (k, spawn & (k < depth), *lvl.record["next"], *local, *ids, *codes)

        state = dr.while_loop(
            (k, active, ro, rd, *local, *ids, *codes), lambda k, active, *_: active, body, label="reflection levels"
        )
        return self._combine(state[4 : 4 + depth], state[4 + depth : 4 + 2 * depth], state[4 + 2 * depth :])

    def _combine(self, local, ids, codes) -> tuple[Any, Any]:
        """The colour of the first of these levels (each level's local colour and hit id, as a loop
        carried them; id -2: not reached), combined back to front as the wavefront's combining pass
        does, and the hash of their ray trees (``codes``: each level's decisions; none: a constant 0)."""
        T, zero3 = self.T, self._vec((0.0, 0.0, 0.0))
        c = None
        below = T.UInt(0)
        for j in range(len(local) - 1, -1, -1):
            shape_id = ids[j]
            reached = shape_id != -2
            cj = local[j] + self._material_term(shape_id, "reflection") * (zero3 if c is None else c)
            if self.effects.background:
                cj = cj + self._background(shape_id >= 0)
            c = dr.select(reached, cj, zero3)
            if codes:
                below = dr.select(reached, _tree_hash(T.UInt(codes[j]), below), T.UInt(0))
        return c, below

    # ---- whole images -----------------------------------------------------------------------
    def _to_numpy3(self, a, also=()) -> np.ndarray:
        """(N, 3) float64 from a Dr.Jit 3-vector of N rays, zeros canonical (see ``_interleave``); ``also``
        (arrays the caller reads next) evaluated in the same kernel as ``a``."""
        n = max(dr.width(a[k]) for k in range(3))
        return self._interleave(n, 1, {"v": a}, also=also)["v"].reshape(n, 3)

    def _scatter_out(self, out: dict[str, Any], vectors: dict[str, Any], n: int, hit=None, masked=()) -> None:
        """Queue the writes of 3-vectors (width n, or 1: a constant) into new float64 buffers out[name]
        of 4 n, (x, y, z, 0) per ray: they run in the next kernel, the one that computes them. NumPy
        views them as (n, 4)[:, :3] (``_view3``). The same values as ``_interleave``: the names in
        ``masked`` are 0 where ``hit`` is false, zeros canonical.

        Four, not three, per ray: Dr.Jit writes a power-of-two packet from a vector register with
        contiguous stores, where a 3-vector is three scattered stores per lane -- slow on x86 (AVX-512
        scatters): on three_balls 1024^2 one 3-vector buffer cost ~1.5 ms of scatters, a 4-packet ~0.25
        ms, for a third more bytes. Every buffer is allocated before the first write is queued:
        allocating one would run the kernel of the writes queued before it."""
        bufs = self._out_buffers(vectors, n)
        self._queue_out(bufs, vectors, n, hit, masked)
        del bufs["zero"]
        out.update(bufs)

    @staticmethod
    def _out_buffers(names, n: int) -> dict[str, Any]:
        """New float64 buffers of 4 n for ``_queue_out`` (and "zero", an opaque 0.0), allocated now:
        allocating one later would run the kernel of the writes queued before it."""
        F64 = dr.llvm.Float64
        bufs = {name: dr.empty(F64, 4 * n) for name in names}
        bufs["zero"] = dr.opaque(F64, 0.0)
        dr.eval(bufs)
        return bufs

    @staticmethod
    def _queue_out(bufs: dict[str, Any], vectors: dict[str, Any], n: int, hit=None, masked=(), active=True) -> None:
        """The writes of ``_scatter_out`` into buffers from ``_out_buffers`` (where ``active``)."""
        A64, A4 = dr.llvm.Array3f64, dr.llvm.Array4f64
        zero = bufs["zero"]
        i = dr.arange(dr.llvm.UInt32, n)
        for name, v in vectors.items():
            x = A64(v)
            if name in masked:
                x = dr.select(hit, x, 0.0)
            x = x + zero
            # One packet per ray: element j at 4 j + k, in one scatter. Three scalar scatters into one
            # buffer would each run the kernel of the writes queued before them.
            dr.scatter(bufs[name], A4(x[0], x[1], x[2], zero), i, active)

    @staticmethod
    def _view3(buf, h: int, w: int) -> np.ndarray:
        """A buffer written by ``_scatter_out`` as an (h, w, 3) NumPy view (no copy; strides 32 w, 32, 8)."""
        return np.asarray(buf).reshape(h, w, 4)[..., :3]

    def _interleave(
        self, w: int, h: int, vectors: dict[str, Any], shape_id=None, masked=(), also=()
    ) -> dict[str, np.ndarray]:
        """3-vectors (Dr.Jit, any float type) to (h, w, 3) float64 NumPy arrays in one kernel over 3 N
        lanes; the names in ``masked`` are 0 where ``shape_id`` < 0. ``also`` (arrays of width N) are
        evaluated with the vectors, in the kernel that computes them.

        Zeros are made canonical, x + 0.0 (-0.0 + 0.0 = +0.0), so a skipped term (exactly +0.0) and a
        computed zero (0 * negative = -0.0) give the same bits; the zero is opaque, or Dr.Jit's constant
        propagation would fold x + 0.0 into x."""
        F64, U32 = dr.llvm.Float64, dr.llvm.UInt32
        n = w * h
        with dr.scoped_set_flag(dr.JitFlag.FastMath, False):
            # What is read is evaluated first, together: a gather from an unevaluated expression evaluates
            # that expression alone, and a lazy trace's colour read component by component ran the whole
            # trace three times (and a fourth for ``also``'s shadow margins).
            dr.eval(*vectors.values(), *also, *([shape_id] if masked else []))
            zero = dr.opaque(F64, 0.0)
            j = dr.arange(U32, 3 * n)
            i = j // 3
            comp = j - 3 * i
            hit = dr.gather(self.T.Int, shape_id, i) >= 0 if masked else None
            bufs = {}
            for name, v in vectors.items():
                ftype = type(v[0])
                # A component that is one constant (the normal of a scene without shapes) is broadcast:
                # a gather from a width-1 array would read past its end.
                comps = [v[k] if dr.width(v[k]) == n else dr.full(ftype, v[k][0], n) for k in range(3)]
                x, y, z = (F64(dr.gather(ftype, c, i)) for c in comps)
                val = dr.select(comp == 0, x, dr.select(comp == 1, y, z))
                if name in masked:
                    val = dr.select(hit, val, 0.0)
                bufs[name] = val + zero
            dr.eval(bufs)
            dr.sync_thread()
        return {k: np.asarray(b).reshape(h, w, 3) for k, b in bufs.items()}

    def primary_rays(self, pixels: np.ndarray | None = None) -> tuple[Any, Any]:
        """camera.primary_rays computed in Dr.Jit: the same IEEE operations in the same order, so
        the same bits (tested), without a round trip through NumPy. ``pixels``: row-major indices of
        the pixels wanted (default every pixel)."""
        with dr.scoped_set_flag(dr.JitFlag.FastMath, False):  # FastMath turns / w into * (1 / w)
            uv = 0.0 if self.rules.pixel_sample == "corner" else 0.5
            if self.runtime:
                uv = dr.opaque(self.T.Float, uv)
            return self._rays(self.T.Float, self.T.Array3, uv, uv, pixels)

    def _rays(self, F, A3, u, v, pixels: np.ndarray | None = None) -> tuple[Any, Any]:
        """camera.rays_through in Dr.Jit arithmetic of type F (A3 its 3-vector): the same operations in
        the same order. u, v: sub-pixel offsets, numbers or arrays of F.

        Under ``runtime`` the pixel indices are an input array and the camera rules are values read at
        run time: the shift is always added (x + u >= +0, so adding +0.0 changes no bit) and the
        origin is a select between both rules' origins."""
        sc = self.scene
        w, h = sc.camera.width, sc.camera.height
        U32 = dr.llvm.UInt32
        if pixels is not None:
            idx = U32(aligned(pixels, np.uint32))
        elif self.runtime:
            idx = U32(aligned(np.arange(w * h), np.uint32))  # an input, like a subset's: the same kernel
        else:
            idx = dr.arange(U32, w * h)
        n = dr.width(idx)
        # Below LOOP_FIRST_LEVEL_BELOW rays, where a kernel's compile outweighs its runs, the width is a
        # value the kernel reads (the height always is), so a scene rendered at another size (a sweep's
        # sizes, a test's) reuses the compiled kernel; the row is then floor(idx / w) in float64 -- exact:
        # idx < 2^28 and w <= 2^14, so the quotient is within 2^-25 of idx / w, whose distance below the
        # next integer is at least 1 / w >= 2^-14 -- since a vector integer division by a run-time value is
        # a scalar division per lane. From there the width is compiled in: a run-time width cost the
        # float32 trace of three_balls at 1024^2 0.4 ms of 5.5 (interleaved A/B), float64 nothing.
        # dr.opaque also keeps Dr.Jit from turning the float division by a literal below into a
        # multiplication by its reciprocal (one more rounding), FastMath off or not.
        if n < LOOP_FIRST_LEVEL_BELOW:
            wi = dr.opaque(U32, w)
            yi = U32(dr.floor(dr.llvm.Float64(idx) / dr.llvm.Float64(wi)))
        else:
            wi = w
            yi = idx // w
        xi = idx - yi * wi
        sx, sy = self.rules.pixel_shift
        fx, fy = F(xi) + u, F(yi) + v
        if self.runtime:
            fx, fy = fx + dr.opaque(F, float(sx)), fy + dr.opaque(F, float(sy))
        else:
            if sx != 0:  # rule pixel_shift: added only when non-zero, so (0, 0) is the unshifted arithmetic
                fx = fx + float(sx)
            if sy != 0:
                fy = fy + float(sy)
        px = fx / dr.opaque(F, w) - 0.5
        py = -fy / dr.opaque(F, h) + 0.5
        pz = dr.zeros(F, n)
        cz = self.table.camera_z(F) if self.table is not None else self._k(("camera_z", F), -sc.camera.distance, F)
        dx, dy, dz = px - 0.0, py - 0.0, pz - cz
        inv = 1.0 / dr.sqrt(dx * dx + dy * dy + dz * dz)  # one division, three products
        d = A3(dx * inv, dy * inv, dz * inv)
        at_camera = A3(0.0, 0.0, cz) + dr.zeros(A3, n)
        if self.runtime:
            o = dr.select(dr.opaque(dr.llvm.Bool, self.rules.ray_origin == "camera"), at_camera, A3(px, py, pz))
        else:
            o = at_camera if self.rules.ray_origin == "camera" else A3(px, py, pz)
        return o, d

    def render(
        self,
        progress=None,
        diagnostics: bool = False,
        tile_pixels: int | None = None,
        terms: Collection[str] | None = None,
    ) -> RenderResult:
        """The image and its buffers. ``diagnostics`` adds what the harness needs to classify pixels
        (aux ray_tree: every decision of each pixel's ray tree, hashed; aux shadow_margin): ~20 % more
        time, so a plain render skips them.

        An image larger than ``tile_pixels`` (default ``TILE_PIXELS``) is traced in tiles of whole rows
        (``tiles``) and assembled: Dr.Jit's working memory is then one tile's, whatever the image size;
        the same bits as one pass (tested). For images too big to hold at all, write the tiles as they
        come (``minirt.io.images.write_tiles``).

        ``terms``: the terms the result holds (default all of ``TERMS``). Each costs the kernels 32 bytes
        a pixel of writes (a float64 3-vector as a 4-packet, ``_scatter_out``); a caller that reads only
        some asks for those: the colour and the terms asked for are the same bits either way (tested)."""
        sc = self.scene
        w, h = sc.camera.width, sc.camera.height
        rows = tile_rows(w, tile_pixels)
        if rows >= h:
            return self.render_rows(0, h, progress, diagnostics, terms)
        t0 = time.perf_counter()
        full: RenderResult | None = None
        for y0, tile in self.tiles(progress, diagnostics, tile_pixels, terms):
            if full is None:
                full = _empty_like(tile, h)
            _paste(full, tile, y0)
        assert full is not None
        full.meta["timings"] = {"total": time.perf_counter() - t0}
        return full

    def tiles(
        self,
        progress=None,
        diagnostics: bool = False,
        tile_pixels: int | None = None,
        terms: Collection[str] | None = None,
    ):
        """(first row, RenderResult of the rows from there) for each tile of whole rows, top to bottom."""
        sc = self.scene
        w, h = sc.camera.width, sc.camera.height
        rows = tile_rows(w, tile_pixels)
        count = -(-h // rows)
        for k in range(count):
            y0, y1 = k * rows, min(h, (k + 1) * rows)

            def sub(done: int, total: int, k=k) -> None:
                if progress:
                    progress(k * total + done, count * total)

            yield y0, self.render_rows(y0, y1, sub, diagnostics, terms)

    def render_rows(
        self, y0: int, y1: int, progress=None, diagnostics: bool = False, terms: Collection[str] | None = None
    ) -> RenderResult:
        """Rows y0 .. y1 - 1 of the image as a RenderResult of height y1 - y0 (the whole image: 0, height)."""
        sc = self.scene
        w = sc.camera.width
        h = y1 - y0
        pixels = None if (y0, y1) == (0, sc.camera.height) else np.arange(y0 * w, y1 * w, dtype=np.uint32)
        timings: dict[str, float] = {}
        t0 = time.perf_counter()
        o, d = self.primary_rays(pixels)
        bufs: dict[str, Any] = {}
        unknown = sorted(set(terms or ()) - set(TERMS))
        if unknown:
            raise ValueError(f"unknown term(s) {', '.join(unknown)}: the terms are {', '.join(TERMS)}")
        wanted = TERMS if terms is None else tuple(k for k in TERMS if k in terms)
        color, levels = self.trace(o, d, tree=diagnostics, out=bufs, terms=wanted)
        lvl0 = levels[0]
        dr.sync_thread()
        out = {k: self._view3(b, h, w) for k, b in bufs.items() if k != "t"}
        out["shape_id"] = np.asarray(lvl0.shape_id).reshape(h, w)
        out["hit"] = out["shape_id"] >= 0
        out["t"] = np.asarray(bufs["t"]).reshape(h, w)  # inf on a miss already (shade_level)
        del o, d, color, bufs
        col = out.pop("color")
        terms = {k[5:]: out.pop(k) for k in list(out) if k.startswith("term.")}
        geom = out
        timings["primary"] = time.perf_counter() - t0
        if progress:
            progress(1, max(1, sc.samples))
        # Pixels whose neighbours' ray trees differ lie near a decision (a silhouette or shadow edge seen
        # in a reflection, too). The top 24 bits of the 32-bit hash: exact in a float32 EXR channel; two
        # different neighbouring trees look alike with probability 2^-24.
        aux: dict[str, np.ndarray] = {}
        if diagnostics:
            aux["ray_tree"] = (np.asarray(lvl0.record["tree"]) >> 8).astype(np.float64).reshape(h, w)
        if diagnostics and "shadow_margin" in lvl0.record:
            aux["shadow_margin"] = np.asarray(lvl0.record["shadow_margin"]).astype(np.float64).reshape(h, w)
        del lvl0, levels
        if sc.samples > 1:
            col, terms, more = self._render_samples(progress, y0, y1, falloff=diagnostics, terms=wanted)
            aux.update(more)
        timings["total"] = time.perf_counter() - t0
        for k in wanted:  # a term the effects skip is exactly zero
            if k not in terms:
                terms[k] = np.zeros((h, w, 3))
        meta = {
            "backend": "reference",
            "version": _versions(),
            "scene": sc.name,
            "scene_sha256": sc.digest,
            "settings": {"precision": self.precision, "samples": sc.samples, "width": w, "height": sc.camera.height,
                         "max_depth": sc.max_depth, "prune": self.prune, "sample_seed": camera.SAMPLE_SEED},
            "rules": self.rules.as_dict(),
            "effects": {"simulated": self.effects.simulated(), "skipped": self.effects.skipped(),
                        **self.effects.as_dict()},
            "timings": timings,
            "aux": DIAGNOSTICS if diagnostics else {},
        }  # fmt: skip
        return RenderResult(backend="reference", width=w, height=h, color=col, terms=terms, aux=aux, meta=meta, **geom)

    def _render_samples(
        self,
        progress=None,
        y0: int = 0,
        y1: int | None = None,
        falloff: bool = False,
        terms: Collection[str] = TERMS,
    ) -> tuple[np.ndarray, dict[str, np.ndarray], dict[str, np.ndarray]]:
        """Average `samples` stratified, jittered rays per pixel (see camera.sample_offsets).

        Also returns the per-pixel sample variance (unbiased, of one sample; divide by n for the
        mean's) of the colour and of the diffuse term (when among ``terms``, the terms summed), for
        statistical comparisons. ``falloff``: also
        the mean and variance of each sample's diffuse term over its squared distance to the light
        (aux diffuse_r2, variance_diffuse_r2) -- what a physical renderer's point light averages over
        the pixel, so the harness compares like with like however much r varies across the pixel.

        Rays (``_sample_rays``) and the float64 sums stay in Dr.Jit; only the sub-pixel offsets come
        from NumPy (its seeded PCG64) and the sums go back once. The same additions in the same order
        as summing in NumPy, FastMath off (no fused multiply-adds), so the same bits.
        """
        sc = self.scene
        w, n = sc.camera.width, sc.samples
        y1 = sc.camera.height if y1 is None else y1
        h = y1 - y0
        pixels = None if (y0, y1) == (0, sc.camera.height) else np.arange(y0 * w, y1 * w, dtype=np.uint32)
        count = w * h
        # Samples per kernel: as many as SAMPLE_BATCH_BYTES of sub-pixel offsets hold (16 bytes a ray), on
        # the one-kernel trace (the wavefront's levels are kernels of their own: a sample each).
        per = max(1, SAMPLE_BATCH_BYTES // (16 * count)) if self._path(False) == "fused" else 1
        sums: dict[str, Any] = {}
        with dr.scoped_set_flag(dr.JitFlag.FastMath, False):
            s = 0
            while s < n:
                b = min(per, n - s)
                if per == 1:
                    u, v = camera.sample_offsets(n, s, count, start=y0 * w)
                    add = self._sample_terms(*self._sample_rays(u, v, pixels), terms, falloff)
                    sums = add if s == 0 else {k: sums[k] + add[k] for k in add}
                else:
                    uv = jitmem.empty((b, count, 2))
                    for j in range(b):
                        camera.sample_offsets_into(uv[j], n, s + j, start=y0 * w)
                    sums = self._sample_batch(uv, pixels, terms, falloff, sums)
                dr.eval(sums)  # one kernel per batch of samples; the graph never grows
                s += b
                if progress:
                    progress(s, n)
        got = {k: v.reshape(h * w, 3) for k, v in self._interleave(w, h, sums).items()}
        mean = got["color"] / n
        terms = {k[5:]: (v / n).reshape(h, w, 3) for k, v in got.items() if k.startswith("term.")}
        aux = {"variance": (np.maximum(got["color2"] - n * mean * mean, 0.0) / (n - 1)).reshape(h, w, 3)}
        if "diffuse2" in got:
            dm = got["term.diffuse"] / n
            aux["variance_diffuse"] = (np.maximum(got["diffuse2"] - n * dm * dm, 0.0) / (n - 1)).reshape(h, w, 3)
        if "diffuse_r2" in got:
            fm = got["diffuse_r2"] / n
            aux["diffuse_r2"] = fm.reshape(h, w, 3)
            aux["variance_diffuse_r2"] = (np.maximum(got["diffuse_r2_2"] - n * fm * fm, 0.0) / (n - 1)).reshape(h, w, 3)
        return mean.reshape(h, w, 3), terms, aux

    def _sample_terms(self, o, d, terms: Collection[str], falloff: bool) -> dict[str, Any]:
        """What one sample adds to ``_render_samples``' sums (Dr.Jit float64 3-vectors, lazy)."""
        A64 = dr.llvm.Array3f64
        c, levels = self.trace(o, d)
        add = {"color": A64(c)} | {"term." + k: A64(v) for k, v in levels[0].terms.items() if k in terms}
        add["color2"] = add["color"] * add["color"]
        if "term.diffuse" in add:
            add["diffuse2"] = add["term.diffuse"] * add["term.diffuse"]
        if falloff and "term.diffuse" in add:
            lvl = levels[0]
            to_light = A64(lvl.p) - self._k("light64", self.scene.light.position, dr.llvm.Float64)
            r2 = dr.squared_norm(to_light)
            add["diffuse_r2"] = dr.select((lvl.shape_id >= 0) & (r2 > 0), add["term.diffuse"] / r2, 0.0)
            add["diffuse_r2_2"] = add["diffuse_r2"] * add["diffuse_r2"]
        return add

    def _sample_names(self, terms: Collection[str], falloff: bool) -> list[str]:
        """The names of the sums ``_sample_terms`` adds to, known before any sample is traced."""
        names = ["color"] + ["term." + k for k in self._term_names(terms)] + ["color2"]
        if "term.diffuse" in names:
            names += ["diffuse2"] + (["diffuse_r2", "diffuse_r2_2"] if falloff else [])
        return names

    def _sample_batch(self, uv: np.ndarray, pixels, terms: Collection[str], falloff: bool, sums: dict[str, Any]):
        """``sums`` plus the samples whose sub-pixel offsets are ``uv`` ((samples, rays, 2) float64, from
        ``camera.sample_offsets_into``), summed in a Dr.Jit loop in one kernel: the sums stay in registers
        from one sample to the next instead of a kernel per sample reading and writing them (240 bytes a
        ray), and Python builds the trace's graph once. Sums start from +0.0 (``sums`` empty): 0 + x is x
        but for the sign of a zero, which ``_interleave`` makes canonical anyway, so the same bits as a
        kernel per sample."""
        F64, U32, A64 = dr.llvm.Float64, dr.llvm.UInt32, dr.llvm.Array3f64
        count = uv.shape[1]
        flat = F64(uv.reshape(-1))
        i = dr.arange(U32, count)
        if not sums:
            sums = {
                k: A64(dr.zeros(F64, count), dr.zeros(F64, count), dr.zeros(F64, count))
                for k in self._sample_names(terms, falloff)
            }
        names = list(sums)

        stride = dr.opaque(U32, count)  # a value, not a constant: one kernel for every image size

        def body(j, *acc):
            at = 2 * (j * stride + i)
            o, d = self._sample_rays(dr.gather(F64, flat, at), dr.gather(F64, flat, at + 1), pixels)
            add = self._sample_terms(o, d, terms, falloff)
            assert set(add) == set(names), (sorted(add), names)  # _sample_names says what _sample_terms adds
            return (j + 1, *(a + add[k] for a, k in zip(acc, names, strict=True)))

        state = dr.while_loop(
            (dr.zeros(U32, count), *sums.values()),
            lambda j, *_: j < dr.opaque(U32, uv.shape[0]),
            body,
            label="samples",
        )
        return dict(zip(names, state[1:], strict=True))

    def _sample_rays(self, u, v, pixels: np.ndarray | None = None) -> tuple[Any, Any]:
        """camera.rays_through(scene, rules, u, v) in Dr.Jit: float64 like NumPy (so the same bits), then
        rounded to the tracer's precision as ``_load`` would. u, v: NumPy or Dr.Jit float64 arrays."""
        F64 = dr.llvm.Float64
        with dr.scoped_set_flag(dr.JitFlag.FastMath, False):
            u, v = (aligned(x, np.float64) if isinstance(x, np.ndarray) else x for x in (u, v))
            o, d = self._rays(F64, dr.llvm.Array3f64, F64(u), F64(v), pixels)
            return self.T.Array3(o), self.T.Array3(d)

    def _load(self, a: np.ndarray) -> Any:
        return self.T.Array3(*(self.T.Float(aligned(a[:, i], self.T.np_dtype)) for i in range(3)))


# Pixels per tile: Dr.Jit's working set is ~330 B per pixel in float64 (the wavefront's levels, the rays,
# the read-out's interleaved buffers; measured: benchmarks/bench_scale.py, memory), so a tile of 2^20
# pixels costs ~350 MB above the finished image's NumPy buffers, and its kernels are long enough that
# the per-tile overhead is small (tiles of 1 Mpixel cost < 5 % more time than one pass).
TILE_PIXELS = 1 << 20

# Below this many rays a trace runs its first level as the loop's first iteration (``_levels_looped``): the
# kernel holds the intersection and shading code once, not twice (three_balls: ~910 Dr.Jit operations
# instead of ~1,380; LLVM's compile ~100 instead of ~150 ms), and at 256^2 it also runs faster (render
# 2.3 against 2.5 ms; with diagnostics 2.7 against 3.3). At 1024^2 the straight-line first level wins
# (f64 trace 9.6 against 10.0 ms, render 15.4 against 16.8: a first level before the loop folds the
# camera's constant origin into its arithmetic), so from 2^18 rays -- where a launch costs milliseconds
# and the kernel is compiled once for many -- the trace keeps it.
LOOP_FIRST_LEVEL_BELOW = 1 << 18

# Sub-pixel offsets per kernel of a supersampled render (``_sample_batch``), 16 bytes a ray: 1 Mi rays, 4
# samples of 512^2 a kernel (512^2 at 16 samples, three_balls: 142 ms a sample a kernel; 117, 112, 127 ms
# at 32, 16, 8 MiB a batch -- smaller batches let NumPy draw the next offsets while a kernel runs).
SAMPLE_BATCH_BYTES = 1 << 24


def _keep_level(k, lvl: Level, local: list, ids: list, codes: list) -> None:
    """In a loop over levels: slot k of the per-level lists (local colour, hit id, and with ``codes`` the
    decision code) takes this iteration's level's values, the other slots keep theirs."""
    for j in range(len(local)):
        here = k == j
        local[j] = dr.select(here, lvl.local, local[j])
        ids[j] = dr.select(here, lvl.shape_id, ids[j])
        if codes:
            codes[j] = dr.select(here, lvl.code, codes[j])


def _tree_hash(code, below) -> Any:
    """A ray's decisions (its level's code) and those of the tree below it (0: none), hashed (UInt32)."""
    return code * 0x9E3779B1 ^ (below * 0x85EBCA6B + 0x27D4EB2F)


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


def tile_rows(width: int, tile_pixels: int | None = None) -> int:
    """Rows per tile: as many whole rows as fit in ``tile_pixels`` (at least one)."""
    return max(1, (tile_pixels or TILE_PIXELS) // width)


def _empty_like(tile: RenderResult, height: int) -> RenderResult:
    """A whole image's RenderResult with the buffers of ``tile`` (uninitialised, then pasted)."""

    def big(a):
        return None if a is None else np.empty((height, *a.shape[1:]), dtype=a.dtype)

    return RenderResult(
        backend=tile.backend, width=tile.width, height=height, color=big(tile.color),
        terms={k: big(v) for k, v in tile.terms.items()}, aux={k: big(v) for k, v in tile.aux.items()},
        meta=dict(tile.meta), hit=big(tile.hit), shape_id=big(tile.shape_id), t=big(tile.t),
        position=big(tile.position), normal=big(tile.normal),
    )  # fmt: skip


def _paste(full: RenderResult, tile: RenderResult, y0: int) -> None:
    y1 = y0 + tile.height
    for name in ("color", "hit", "shape_id", "t", "position", "normal"):
        if getattr(tile, name) is not None:
            getattr(full, name)[y0:y1] = getattr(tile, name)
    for group in ("terms", "aux"):
        for k, v in getattr(tile, group).items():
            getattr(full, group)[k][y0:y1] = v


DIAGNOSTICS = {
    "ray_tree": "per pixel, a 24-bit hash of the shapes hit and the shadow (and, under clamp, light-side) decisions "
    "of its whole ray tree; neighbours with different values straddle an edge, possibly seen in a reflection",
    "shadow_margin": "per pixel, the distance from its shadow ray to the nearest ball silhouette in front of it "
    "(1e30: none): how far the hit point may move before the shadow decision can flip",
}

# From this many shapes on, "auto" traces through the shape table and the BVH (measured: benchmarks/bench_scale.py).
ACCEL_MIN_SHAPES = 16
ACCELS = ("unrolled", "bvh", "loop")
# From this many balls (through the shape table) Tracer.trace runs as a wavefront: the one-kernel trace's
# packets carry rays that stopped reflecting through every later level's tree traversal, which costs more
# than compacting them away once traversal dominates. Measured, 512^2, max_depth 3, warm trace, fused /
# wavefront: 16 balls 24.8 / 30.9 ms, 128: 84 / 92, 256: 134 / 140, 512: 188 / 177, 1,024: 285 / 247,
# 10,000: 804 / 597.
WAVEFRONT_MIN_BALLS = 384

F32_LIMIT = 1e18  # squares stay below float32's max (3.4e38); reciprocals above its min normal


def _check_float32_range(scene: Scene) -> None:
    """Refuse a scene float32 cannot hold: its squared lengths would overflow to inf and then NaN."""
    from minirt.errors import MinirtError

    values = [scene.camera.distance, *scene.light.position]
    for s in scene.shapes:
        values += [*s.center, s.radius] if isinstance(s, Ball) else [*s.point, s.distance]
    big = max(abs(v) for v in values)
    small = min([scene.camera.distance] + [s.radius for s in scene.shapes if isinstance(s, Ball)])
    if big > F32_LIMIT or small < 1 / F32_LIMIT:
        raise MinirtError(
            f"{scene.source or scene.name}: values from {small:g} to {big:g} are beyond float32's safe range "
            f"(1e-18 .. 1e18): use --precision f64"
        )


def _versions() -> dict[str, str]:
    from minirt.version import __version__

    return {"minirt": __version__, "drjit": dr.__version__}


def render(
    scene: Scene,
    rules: Rules,
    precision: str = "f64",
    prune: bool = True,
    progress=None,
    diagnostics: bool = False,
    terms: Collection[str] | None = None,
    runtime: bool | None = None,
) -> RenderResult:
    """Render a scene with the reference tracer (``diagnostics``: also aux ray_tree and shadow_margin;
    ``terms``: the terms to keep, default all; ``runtime``: see ``Tracer``)."""
    tr = Tracer(scene, rules, precision=precision, prune=prune, runtime=runtime)
    return tr.render(progress=progress, diagnostics=diagnostics, terms=terms)
