"""One level of TraceRay's shading: a ray's closest hit and its local colour -- ambient, the
shadow-tested diffuse and specular terms -- in the pseudo-code's order, plus what the next level and the
diagnostics need (the reflected ray, the reflection colour, the background, the decision code).

``shade_level`` shades a batch of rays (``Level``); the integrator (minirt.reference.integrator) chains
levels into the recursion and adds the reflections and the background back to front. ``tr`` holds the
settings of the tracer whose kernel is being built (minirt.reference.settings.TraceSettings): its types,
rules, effects and the scene's values (``tr.values``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import drjit as dr

from minirt.model.rules import SPECULAR_EXPONENT_MAX
from minirt.model.scene import Ball
from minirt.reference import interaction, shapes
from minirt.reference.settings import TraceSettings


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


def shadow_blocked(tr: TraceSettings, o, s, light_dist, record: bool = False) -> tuple[Any, list[Any]]:
    """Is the shadow ray blocked? Rule shadow_range: 'any' (anything with t > 0) or 'to-light'.

    Under 'any' only the existence of a root with t > 0 matters; for a ball the signs of the
    quantities ``shapes.ball_t`` computes already decide it (``shapes.ball_occludes``), without the
    square root and the division that give t: a quarter less time for the whole trace kernel on
    three_balls. The balls' distances are then computed only when ``record`` asks (the list: each
    shape's t along the shadow ray, in id order; empty without ``record``).
    """
    return tr.values.blocked(o, s, light_dist, record)


def shadow_margin(tr: TraceSettings, o, s, light_dist, hit) -> Any:
    """Per shadow ray, the absolute distance from the nearest ball silhouette in front of it (before
    the light under shadow_range "to-light"): how far its origin may move before the decision can
    flip. Large (1e30) when no ball is in front; planes' decisions are the light's side, not this."""
    F = tr.T.Float
    out = dr.full(F, 1e30, dr.width(s))
    to_light = tr.values.switch("shadow_to_light")  # a batch's: each ray its candidate's (a mask)

    def nearer(out, center, radius):
        r, _, b, gg = shapes.ball_ray(center, radius, o, s)
        front = -b > -r
        if to_light is True:
            front &= -b < light_dist + r
        elif to_light is not False:
            front &= (-b < light_dist + r) | ~to_light
        return dr.select(front, dr.minimum(out, dr.abs(dr.sqrt(gg) - r)), out)

    out = tr.values.each_ball(o, nearer, out)
    return dr.select(hit, out, F(1e30))


def shade_level(
    tr: TraceSettings, o, d, parent, depth_left: int, record: bool, margins: Any = False, gate: bool = False
) -> tuple[Level, Any]:
    """Intersect one level's rays and shade them locally; return the level and the next rays' mask.

    ``gate`` (not with ``record``): the shading -- hit point, normal, shadow ray, terms,
    next ray -- runs in a Dr.Jit conditional on the hit, which a packet of rays that all miss skips
    (half the packets of three_balls' first level, the sky); the misses get the values the shading
    gives them (zeros, p = o + 0 d), so the same bits either way."""
    shape_id, t = tr.values.closest(o, d)
    hit = shape_id >= 0
    t = dr.select(hit, t, math.inf)
    if not gate:
        return shade(tr, o, d, parent, shape_id, hit, t, depth_left, record, margins)
    fx, zero = tr.effects, tr.T.zero3()
    names = [k for k in ("ambient", "diffuse", "specular") if getattr(fx, k)]
    spawns = fx.reflection and depth_left > 0
    margins = margins if has_margins(tr) else False

    def on_hit(o, d, shape_id, hit, t):
        lvl, spawn = shade(tr, o, d, None, shape_id, hit, t, depth_left, False, margins)
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
        code, margin = dr.full(tr.T.Int, -4, n), [dr.full(tr.T.Float, 1e30, n)] if margins is not False else []
        return p, zero, zero, zero, [zero for _ in names], zero, zero, tr.T.Bool(False), code, margin

    p, n, local, kr, terms, ro, rd, spawn, code, margin = dr.if_stmt(
        (o, d, shape_id, hit, t), hit, on_hit, on_miss, label="shade"
    )
    lvl = Level(parent, o, d, shape_id, t, p, n, local, kr, background(tr, hit), dict(zip(names, terms, strict=True)))
    lvl.code = code
    if margins is not False:
        lvl.record["shadow_margin"] = margin[0]
    if not spawns:
        return lvl, None
    lvl.record["next"] = (ro, rd)
    return lvl, spawn


def shade(
    tr: TraceSettings, o, d, parent, shape_id, hit, t, depth_left: int, record: bool, margins: Any
) -> tuple[Level, Any]:
    """shade_level after the closest hit (shape_id, hit, t: inf on a miss). ``margins``: True, False, or
    a mask of the rays whose shadow margins are wanted (the others get 1e30, shadow_margin's none)."""
    fx, T, values = tr.effects, tr.T, tr.values
    zero = T.zero3()
    p, n = interaction.hit_point_and_normal(tr, shape_id, o, d, dr.select(hit, t, 0))
    ns = n
    two_sided = values.rule("two_sided")
    if two_sided is not False:
        flip = dr.dot(d, n) > 0  # shading normal faces the incoming ray
        ns = dr.select(flip if two_sided is True else flip & two_sided, -n, n)
    rec: dict[str, Any] = {}
    terms: dict[str, Any] = {}
    local = zero
    if fx.ambient:
        terms["ambient"] = dr.select(hit, values.material(shape_id, "ambient"), zero)
        local = local + terms["ambient"]
    r, r_dir, nr, raw_shading = _reflected(tr, shape_id, d, ns)
    bound = values.switch("offset_error_bound")  # a batch's: a mask (the bound computed for every ray)
    err = interaction.error_bound(tr, shape_id, p, o) if bound is not False else None
    outward = interaction.outward(tr, shape_id)
    clamp_all = values.rule("clamp_all")
    if fx.diffuse or fx.specular:
        lc = values.vec("light_color")
        s, light_dist, at_light = _to_light(tr, p)
        sn = dr.dot(s, ns)
        lit = hit & ~at_light
        shadow_rays = values.switch("shadow_rays")  # rule shadow_rays false: no shadow test at all
        if fx.shadows and shadow_rays is not False:
            tested = _shadow_test(tr, p, ns, err, s, outward, light_dist, hit, record, margins, rec)
            lit = tested if shadow_rays is True else dr.select(shadow_rays, tested, lit)
            if shadow_rays is not True and "shadow_margin" in rec:  # a batch's rays without a test: none
                rec["shadow_margin"] = dr.select(shadow_rays, rec["shadow_margin"], T.Float(1e30))
        if fx.diffuse:
            sd = sn  # s·n, or with raw_shading s·(the raw normal): the same sign
            if raw_shading is True:
                sd = dr.dot(s, nr)
            elif raw_shading is not False:
                sd = dr.select(raw_shading, dr.dot(s, nr), sn)
            if isinstance(clamp_all, bool):
                fac = dr.maximum(sd, 0) if clamp_all else sd  # "specular": s·n raw
            else:
                fac = dr.select(clamp_all, dr.maximum(sd, 0), sd)
            terms["diffuse"] = dr.select(lit, lc * values.material(shape_id, "diffuse") * fac, zero)
            local = local + terms["diffuse"]
        if fx.specular:
            terms["specular"] = _specular(tr, shape_id, r, s, sn, lit, lc, clamp_all)
            local = local + terms["specular"]
    bg = background(tr, hit)
    kr = values.material(shape_id, "reflection") if fx.reflection else zero
    spawn = None
    if fx.reflection and depth_left > 0:
        spawn = hit
        if tr.prune:
            spawn = hit & dr.any(kr != 0)
    lvl = Level(parent, o, d, shape_id, t, p, n, local, kr, bg, terms, rec)
    # The discrete decisions this ray's colour jumps with: which shape, lit or not, and under clamp = true
    # the side of the surface the light is on (the specular lobe is cut at s·n = 0 with (r·s)^e > 0; the
    # diffuse term and the cut at r·s = 0 are continuous, so clamp = "specular" adds none). Packed as an
    # integer.
    code = T.Int(shape_id) * 4
    if fx.diffuse or fx.specular:
        code = code + dr.select(lit, 1, 0)
        if fx.specular and clamp_all is not False:
            code = code + dr.select((sn > 0) if clamp_all is True else (sn > 0) & clamp_all, 2, 0)
    lvl.code = code
    if record:
        rec.update(shading_normal=ns, reflected=r, error_bound=err)
    if spawn is not None:
        ro = interaction.offset_origin(tr, p, ns, err, r_dir, outward)
        lvl.record["next"] = (ro, r_dir)
    return lvl, spawn


def _reflected(tr: TraceSettings, shape_id, d, ns) -> tuple[Any, Any, Any, Any]:
    """(r, the reflected ray's direction, the raw normal or None, rule raw_normals' "shading" switch) at a hit
    whose shading normal is ``ns``."""
    values = tr.values
    r = d - 2 * dr.dot(d, ns) * ns  # reflected incoming direction: the highlight's r·s takes it as computed
    # The reflected Ray's direction, normalised: the exercise's Ray holds a normalised direction, and its
    # ball intersection (Appendix 2) drops d·d = 1. r is of unit length only to within the normal's error,
    # which is relative to the ball's radius, not to the hit point: a ball of radius 20 hit 4e7 from the
    # origin has |n|^2 - 1 ~ 1e-10, and a ray of that length, solved as if unit, lands 1.5e-3 inside a
    # planet 1.6e7 away -- its shadow ray then starts inside and sees no blocker (the campaign's far_6005_0).
    r_dir = dr.normalize(r)
    # rules raw_normals_ball, raw_normals_plane: the normal as a solution that never normalises it has it, of
    # length r for a ball (p - c) and |n| as written for a plane (values.normal_length); the offset keeps the
    # unit one. Under ``runtime`` the switches are read at run time: one kernel for every value (a diagnosis
    # tries them all).
    raw_shading = _per_kind(tr, shape_id, "shading")
    raw_reflection = _per_kind(tr, shape_id, "reflection")
    nr = None
    if raw_shading is not False or raw_reflection is not False:
        nr = ns * values.normal_length(shape_id)
    if raw_reflection is not False:
        r_raw = d - 2 * dr.dot(d, nr) * nr  # the highlight's r·s takes it as computed
        r_unit = dr.normalize(r_raw)  # normalised, as above
        if raw_reflection is True:
            r, r_dir = r_raw, r_unit
        else:
            r, r_dir = dr.select(raw_reflection, r_raw, r), dr.select(raw_reflection, r_unit, r_dir)
    return r, r_dir, nr, raw_shading


def _to_light(tr: TraceSettings, p) -> tuple[Any, Any, Any]:
    """(s, the light's distance, unlit because the light is at the point) at hit points p (rule light)."""
    values, zero = tr.values, tr.T.zero3()
    lpos = values.vec("light")
    to_light = lpos - p
    light_dist = dr.norm(to_light)
    # The light exactly at the hit point has no direction: that point is unlit (not 0/0).
    at_light = ~(light_dist > 0)
    s = dr.select(at_light, zero, to_light * (1.0 / dr.select(at_light, 1, light_dist)))
    as_direction = values.rule("light_direction")
    if as_direction is not False:
        # rule light "direction": the light's position used as the direction towards it, the same s at
        # every point (a light at the origin has none: unlit, as above)
        l_len = dr.norm(lpos)
        at_light = ~(l_len > 0) if as_direction is True else dr.select(as_direction, ~(l_len > 0), at_light)
        s_fixed = dr.select(at_light, zero, lpos * (1.0 / dr.select(at_light, 1, l_len)))
        s = s_fixed if as_direction is True else dr.select(as_direction, s_fixed, s)
    return s, light_dist, at_light


def _shadow_test(tr: TraceSettings, p, ns, err, s, outward, light_dist, hit, record: bool, margins, rec) -> Any:
    """Lit or not: the shadow ray's test (its margins and, with ``record``, its rays recorded in ``rec``)."""
    T = tr.T
    so = interaction.offset_origin(tr, p, ns, err, s, outward)
    blocked, shadow_ts = shadow_blocked(tr, so, s, light_dist, record)
    lit = hit & ~blocked
    if margins is True:
        rec["shadow_margin"] = shadow_margin(tr, so, s, light_dist, hit)
    elif margins is not False:  # in a conditional: the loop's later levels skip the ball loop
        rec["shadow_margin"] = dr.if_stmt(
            (so, s, light_dist, hit, margins),
            margins,
            lambda so, s, light_dist, hit, _: shadow_margin(tr, so, s, light_dist, hit),
            lambda *_: T.Float(1e30),
            label="margins",
        )
    if record:
        rec.update(shadow_origin=so, shadow_dir=s, light_dist=light_dist, shadow_ts=shadow_ts)
    return lit


def _specular(tr: TraceSettings, shape_id, r, s, sn, lit, lc, clamp_all) -> Any:
    """The highlight (r·s)^e where the clamp rule lets it shine (``clamp_all``: shade's switch for clamp =
    true; rule specular_s: -s)."""
    rules, values, zero = tr.rules, tr.values, tr.T.zero3()
    clamp_specular = values.rule("clamp_specular")
    rs = dr.dot(r, s)
    negated = values.rule("specular_negated")
    if negated is not False:  # rule specular_s "-s": (r·(-s))^e, the incoming light's direction
        rs = -rs if negated is True else dr.select(negated, -rs, rs)
    bits = SPECULAR_EXPONENT_MAX.bit_length()
    # (r·s)^e: for e = 8 rs2, rs4, rs4 * rs4
    if tr.runtime:
        pw = _power_runtime(rs, values.number("specular_exponent"), bits)
    else:
        pw = _power(rs, rules.specular_exponent)
    on = lit
    if tr.runtime:
        on = lit & dr.select(clamp_all, (sn > 0) & (rs > 0), ~clamp_specular | (rs > 0))
    elif clamp_all:
        on = lit & (sn > 0) & (rs > 0)
    elif clamp_specular:
        on = lit & (rs > 0)
    return dr.select(on, lc * values.material(shape_id, "specular") * pw, zero)


def _per_kind(tr: TraceSettings, shape_id, use: str) -> Any:
    """Where the hit shape's normal is used unnormalised for ``use`` ("shading" or "reflection"): rules
    raw_normals_ball and raw_normals_plane, per shape kind. A Python bool where the answer is the same for
    every ray (compiled in), else a Dr.Jit mask (is the hit shape a ball, and the rules read at run time)."""
    values = tr.values
    ball = values.rule(f"raw_ball_{use}")
    plane = values.rule(f"raw_plane_{use}")
    kinds = {isinstance(s, Ball) for s in tr.scene.shapes}
    if kinds == {True}:
        return ball
    if kinds <= {False}:
        return plane
    if ball is plane:  # both compiled in, and equal
        return ball

    def mask(x):
        return tr.T.Bool(x) if isinstance(x, bool) else x

    return dr.select(values.is_ball(shape_id), mask(ball), mask(plane))


def has_margins(tr: TraceSettings) -> bool:
    """Whether shading records shadow margins when asked: only where shadow rays are cast (``shade``)."""
    fx = tr.effects
    return fx.shadows and tr.values.switch("shadow_rays") is not False and (fx.diffuse or fx.specular)


def background(tr: TraceSettings, hit) -> Any:
    """The background term of a ray that hit (``hit``) or missed: rule background."""
    zero = tr.T.zero3()
    none, on_hit = tr.values.switch("background_none"), tr.values.switch("background_on_hit")
    if not tr.effects.background or none is True:
        return zero
    bgc = tr.values.vec("background")
    if isinstance(on_hit, bool):
        out = dr.select(hit, bgc, zero) if on_hit else dr.select(hit, zero, bgc)
    else:  # a batch: each ray its candidate's
        out = dr.select(on_hit, dr.select(hit, bgc, zero), dr.select(hit, zero, bgc))
    return out if none is False else dr.select(none, zero, out)
