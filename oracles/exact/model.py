"""The exercise's model for one ray tree, in ball arithmetic at one precision: every decision certified or
``Uncertain`` raised.

Numbers. The scene's binary64 numbers are exact rationals; python-flint's ``arb`` is a midpoint-radius
interval that contains the exact value of every expression evaluated in it. A decision (a sign, an
order) is *certified* when the interval lies strictly on one side of 0 -- or is exactly 0 (radius 0) --
and then it is the exact model's decision, whatever the precision. When an interval straddles 0 the
decision is not made: ``Uncertain`` is raised, and the caller (minirt.oracles.exact.render) tries again at
a higher precision; at the last one the pixel is an exact tie (a tangent ray, a shadow ray through an
occluder's silhouette exactly), reported as such and never guessed.

The primary ray is set up in exact rational arithmetic (python-flint's ``fmpq``) from the scene's numbers,
as the exercise specifies: image-plane point P = ((x + u + dx)/W - 1/2, -(y + v + dy)/H + 1/2, 0), direction
V = P - camera, origin P or the camera (rule ray_origin). Its decisions are rational signs, exact: a plane's
n·(origin) - a and n·V (a ray starting on a plane, a ray parallel to it), a ball's discriminant
(f·V)^2 - |V|^2 (|f|^2 - r^2) (a tangent ray), |f|^2 - r^2 (an origin on the sphere) and f·V, f = origin - C.
Distances t along the unit direction d = V/|V| are then (-(f·V) -+ sqrt(disc))/|V| and
(a - n·origin)/(n·V) |V|, evaluated in arb. Secondary rays (shadow, reflection) are arb throughout.

The model, rule by rule (minirt.model.rules; the reference, minirt.reference, does each in float64):

- A ball meets the ray o + t d (d unit) at t^2 + 2 b t + c = 0, b = f·d, c = |f|^2 - r^2; the
  discriminant b^2 - c = r^2 - |f - b d|^2. The near root is > 0 iff c > 0 and b < 0; the far root iff
  c < 0, or c >= 0 and b < 0 (the roots' product is c, their sum -2 b). near_root_only: only the near root.
- A plane {x: n·x = a} (n, a as the scene holds them, n normalised in binary64): t = (a - n·o)/(n·d), a
  hit iff n·d != 0 and t > 0. Its shading normal is n/|n| (exactly unit).
- Only t > 0 counts; the closest hit wins, an exact tie (equal t) keeps the lower shape id (Appendix 1's
  "t0 < t"): decided where both t are rational (two planes from a primary ray) or are the same root of
  the same numbers (a shape given twice), otherwise a tie.
- Offsets: a numeric offset moves the hit point by offset along the shading normal (offset_along
  "normal") or along the new ray ("ray"). An offset of 0 starts the secondary ray on its own surface
  exactly: there c = 0 (ball) or a - n·o = 0 (plane), known, not computed, so a root at t = 0 exactly
  does not count. "error-bound": pbrt-v4's bound on the hit point's rounding, gamma(6)(r + |p|) for a
  ball, gamma(4)(|a| + |p| + |o|) for a plane (gamma(n) = n u/(1 - n u), u = 2^-53, exactly), along the
  shading normal to the side the new ray leaves to (outward from a ball under near_root_only), of the
  exact hit point: the model's offset, without the rounding it bounds. The side of its own surface such
  an origin lies on is known by construction (the offset's purpose), and taken as known.
- shadow_range "to-light": an occluder counts only if its first valid root is < |L - p|.
- two_sided: the shading normal faces the ray (flipped where d·n > 0; 0 is not > 0).
- Shading: ambient + (lit) lc dc (s·n, or max(s·n, 0) under clamp = true) + (lit, gates) lc sc
  (r·s)^e + kr trace(reflected) + background (rule background), r = d - 2 (d·n) n; the specular gates
  are s·n > 0 and r·s > 0 (clamp true), r·s > 0 (clamp "specular"). A gate undecided at this precision
  takes both branches (the interval's union): a term that is 0 either way, or whose two values are
  within the colour's tolerance, needs no decision. The light exactly at the hit point: unlit.
- Reflection: up to the scene's max_depth levels, where the hit material reflects.

Robust evaluation (``slack``): the same model with every ray's origin and direction, every hit point and
each plane's a widened by a relative error ``slack`` (minirt.oracles.exact.render.SLACK, thousands of times a
float64 tracer's rounding of them). Where every decision is still certified, any tracer whose errors stay
within the slack makes the exact model's decisions, and its t, normal and colour lie within the widened
intervals: the reference differing there is certified wrong. Where a decision is not, the pixel is not
robust: the reference's own rounding may flip it, and it is not judged.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np
from flint import arb, ctx, fmpq

from minirt.model.rules import Rules
from minirt.model.scene import Ball, Scene

U64 = fmpq(1, 2**53)
OFFSET_SURE = 32  # see Model.offset_sure
# Balls are culled by a float64 test of each ray's line (Model.near_balls) from this many on; below, a ray is
# tested against every ball (the test costs about as much as a few balls' ball arithmetic).
CULL_FROM = 8
# The cull's margin on h^2 - r^2 (Model.near_balls): CULL_REL F^2 + CULL_RAD F (rad_o + F rad_w)
# + CULL_ROUND u F (|o| + |C|), F = |f| + r.
CULL_REL, CULL_RAD, CULL_ROUND = 2.0**-20, 256.0, 64.0
# From this many balls the line is first tested against groups of at most GROUP_SIZE neighbouring balls
# (Model.near_balls): 10,000 balls cost 150 us a ray one by one, a few dozen by groups.
GROUP_FROM, GROUP_SIZE = 512, 32
# The primary rays of a batch of pixels are culled against the balls all at once, in NumPy (``line_misses``):
# the same test as ``near_balls``, from one ball on (a batch's rays cost a few microseconds each, where the
# rational test of one ball costs about ten).
PRIMARY_CULL_FROM = 1


def primary_lines(scene: Scene, rules: Rules, indices, uv, slack: float) -> tuple[np.ndarray, ...]:
    """The primary rays of pixels (row-major indices, sub-pixel positions (N, 2)) as float64 lines for
    ``Model.line_misses``: origins, unit directions and the radii within which the exact rays (and their
    widened intervals under ``slack``, the robust evaluation's) lie.

    The image-plane point ((x + u) + dx)/W - 1/2 takes four roundings, each within u of a size at most
    |x + u + dx|/W + 1/2, so it lies within 8 u (|fx|/W + |fy|/H + 1) of the exact rational (twice the count);
    the direction V/|V| moves by at most twice V's error over |V|, plus 4 u for its own roundings. The robust
    model widens the origin by slack times its largest component and the unit direction by slack (Model.widen;
    raised by 2^-40 here, over the radii arb rounds up)."""
    cam = scene.camera
    w, h = cam.width, cam.height
    index = np.asarray(indices, dtype=np.int64)
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    y, x = np.divmod(index, w)
    sx, sy = rules.pixel_shift
    fx = (x + uv[:, 0]) + sx
    fy = (y + uv[:, 1]) + sy
    px, py = fx / w - 0.5, -fy / h + 0.5
    err = 8 * 2.0**-53 * (np.abs(fx) / w + np.abs(fy) / h + 1)
    v = np.stack([px, py, np.full(len(px), cam.distance)], axis=1)
    if rules.ray_origin == "camera":
        o = np.zeros_like(v)
        o[:, 2] = -cam.distance
        err_o = np.zeros(len(px))
    else:
        o = np.stack([px, py, np.zeros(len(px))], axis=1)
        err_o = err
    lv = np.sqrt(np.einsum("ij,ij->i", v, v))
    grow = 1 + 2.0**-40
    ro = slack * (np.abs(o).max(axis=1) + err_o) * grow + err_o
    rw = slack * grow + 2 * np.sqrt(3) * err / lv + 4 * 2.0**-53
    return o, v / lv[:, None], ro, rw


class Uncertain(Exception):
    """A decision this precision cannot certify (an interval straddling 0); ``what`` names it."""

    def __init__(self, what: str):
        super().__init__(what)
        self.what = what


@functools.lru_cache(maxsize=4096)
def q(x: float) -> fmpq:
    """A binary64 number as the exact rational it is (kept for the numbers a render asks for again and again:
    sub-pixel positions, shifts; fmpq is immutable)."""
    n, d = float(x).as_integer_ratio()
    return fmpq(n, d)


def gamma(n: int) -> fmpq:
    """pbrt's gamma(n) = n u / (1 - n u), u = 2^-53, as an exact rational."""
    return n * U64 / (1 - n * U64)


def sign(x: arb, what: str, *args) -> int:
    """The certified sign of x: 1, -1, or 0 when x is exactly 0; ``Uncertain`` otherwise, naming the decision
    ``what.format(*args)`` (formatted only then: most decisions are certified)."""
    if x > 0:
        return 1
    if x < 0:
        return -1
    if x.is_zero():
        return 0
    raise Uncertain(what.format(*args) if args else what)


def midpoint_sign(x: arb, what: str, *args) -> int:
    """The sign of the interval's midpoint: how a tie's picture takes a decision no precision certified."""
    m = x.mid()
    return (m > 0) - (m < 0)


def qsign(x: fmpq) -> int:
    """The sign of a rational: its numerator's (the denominator is positive); a comparison of two fmpq costs
    several times one of an fmpz with an int."""
    n = x.p
    return (n > 0) - (n < 0)


Vec = tuple[arb, arb, arb]


def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def add(a, b) -> Vec:
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


def sub(a, b) -> Vec:
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def scale(a, k) -> Vec:
    return (a[0] * k, a[1] * k, a[2] * k)


def norm(a) -> arb:
    return dot(a, a).sqrt()


def mul3(a, b) -> Vec:
    return (a[0] * b[0], a[1] * b[1], a[2] * b[2])


def union3(a: Vec, b: Vec) -> Vec:
    return (a[0].union(b[0]), a[1].union(b[1]), a[2].union(b[2]))


@dataclass
class Hit:
    """The closest hit of a ray: shape index, t (arb), the sign of d·n at the hit (0: tangent, exactly)."""

    shape: int
    t: arb
    dn_sign: int


@dataclass
class Level:
    """One level of the ray tree, as the buffers and the probe report it."""

    hit: Hit | None
    p: Vec | None = None
    n: Vec | None = None  # the shape's own normal (unflipped)
    terms: dict[str, Vec] = field(default_factory=dict)
    lit: bool | None = None
    color: Vec | None = None


class Model:
    """The scene's numbers at one working precision (``ctx.prec`` set by the caller) and the model's
    evaluation of a ray tree (``trace_primary``)."""

    def __init__(self, scene: Scene, rules: Rules, guess: bool = False, slack: float = 0.0):
        """``guess``: take every uncertain decision by its interval's midpoint (a tie's picture, never judged).
        ``slack``: the robust evaluation (module docstring): every ray's origin and direction and every hit
        point widened by this relative error, and each plane's a; 0: the exact model."""
        self.scene, self.rules = scene, rules
        self.sign = midpoint_sign if guess else sign
        self.guess = guess
        self.slack = slack
        zero = arb(0)
        self.zero3: Vec = (zero, zero, zero)
        self.balls: dict[int, tuple[Vec, arb, arb, tuple[fmpq, ...], fmpq]] = {}
        self.planes: dict[int, tuple[Vec, arb, Vec, tuple[fmpq, ...], fmpq]] = {}
        for k, s in enumerate(scene.shapes):
            if isinstance(s, Ball):
                cq = tuple(q(c) for c in s.center)
                r = arb(s.radius)
                self.balls[k] = (tuple(arb(c) for c in s.center), r, r * r, cq, q(s.radius))
            else:
                nq = tuple(q(c) for c in s.normal)
                n = tuple(arb(c) for c in s.normal)
                unit = scale(n, 1 / norm(n))
                a = arb(s.distance) if not slack else arb(s.distance, slack * abs(s.distance))
                self.planes[k] = (n, a, unit, nq, q(s.distance))
        self.mat = [
            {k: tuple(arb(c) for c in getattr(s.material, k)) for k in ("ambient", "diffuse", "specular", "reflection")}
            for s in scene.shapes
        ]
        self.reflective = [any(c != 0 for c in s.material.reflection) for s in scene.shapes]
        self.light: Vec = tuple(arb(c) for c in scene.light.position)
        self.lc: Vec = tuple(arb(c) for c in scene.light.color)
        self.lit_color = [
            any(lc != 0 and (dc != 0 or sc != 0) for lc, dc, sc in
                zip(scene.light.color, s.material.diffuse, s.material.specular, strict=True))
            for s in scene.shapes
        ]  # fmt: skip
        self.bg: Vec = tuple(arb(c) for c in scene.background)
        ball_shapes = [(k, s) for k, s in enumerate(scene.shapes) if isinstance(s, Ball)]
        self.ball_ids = np.array([k for k, _ in ball_shapes], dtype=np.int64)
        self.ball_c = np.array([s.center for _, s in ball_shapes], dtype=np.float64).reshape(-1, 3)
        self.ball_r = np.array([s.radius for _, s in ball_shapes], dtype=np.float64)
        self.ball_csize = np.abs(self.ball_c).sum(axis=1)
        self.groups = self._group_balls() if len(ball_shapes) >= GROUP_FROM else None
        keys = [self.key(k, 0) for k in range(len(scene.shapes))]
        alike: dict[tuple, list[int]] = {}
        for j, kj in enumerate(keys):  # one pass, not every pair: 10,000 balls took 3.5 s
            alike.setdefault(kj, []).append(j)
        self.same = [alike[kk] for kk in keys]  # the shapes of equal key, in order (shared lists, read only)
        self.exponent = rules.specular_exponent
        off = rules.offset
        self.offset = None if off == "error-bound" else arb(off)
        self.offset_f = None if self.offset is None else float(self.offset.mid())
        # per shape, |C| + r (ball) or |a| (plane): offset_sure's sizes
        self.sizes = [
            math.hypot(*s.center) + s.radius if isinstance(s, Ball) else abs(s.distance) for s in scene.shapes
        ]
        self.offset_zero = off != "error-bound" and off == 0 and not slack
        self.g6, self.g4 = arb(gamma(6)), arb(gamma(4))
        self.inv_r = {k: 1 / b[1] for k, b in self.balls.items()}  # frame's 1/r, at this model's precision
        # per plane, the one component of its normal that is not 0 (an axis-aligned plane), else None
        axes = {k: [i for i in range(3) if p[3][i] != 0] for k, p in self.planes.items()}
        self.plane_axis = {k: a[0] if len(a) == 1 else None for k, a in axes.items()}
        cam = scene.camera
        dist = q(cam.distance)
        camera_o = (fmpq(0), fmpq(0), -dist) if rules.ray_origin == "camera" else None
        self.primary_consts = (fmpq(cam.width), fmpq(cam.height), fmpq(1, 2), dist, camera_o)

    def _group_balls(self) -> tuple[list[np.ndarray], np.ndarray, np.ndarray, np.ndarray]:
        """Groups of at most GROUP_SIZE balls (median splits of the centres along the widest axis): each
        group's members (indices into the ball arrays), centre G (its centres' box midpoint), radius R >= |C -
        G| + r of every member (computed, then raised by 2^-40 of the sizes: above every rounding of it) and
        |G|_1 + 1.75 R (>= each member's |C|_1)."""
        stack, parts = [np.arange(len(self.ball_ids))], []
        while stack:
            idx = stack.pop()
            if len(idx) <= GROUP_SIZE:
                parts.append(idx)
                continue
            c = self.ball_c[idx]
            axis = int(np.argmax(c.max(axis=0) - c.min(axis=0)))
            idx = idx[np.argsort(c[:, axis], kind="stable")]
            stack += [idx[len(idx) // 2 :], idx[: len(idx) // 2]]
        centre = np.array([(self.ball_c[m].min(axis=0) + self.ball_c[m].max(axis=0)) / 2 for m in parts])
        radius = np.array(
            [
                np.max(np.linalg.norm(self.ball_c[m] - g, axis=1) + self.ball_r[m])
                for m, g in zip(parts, centre, strict=True)
            ]
        )
        sizes = np.abs(centre).sum(axis=1)
        radius = radius * (1 + 2.0**-40) + 2.0**-40 * (sizes + radius)
        return parts, centre, radius, sizes + 1.75 * radius

    @staticmethod
    def _line_gap(om, wu, ro, rw, c, r, csize) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per sphere (centre c, radius r, |c|_1 csize) and the line om + t wu: (h^2, the cull's margin on
        h^2 - r^2, F = |om - c| + r) -- ``near_balls``' test, for a ball or a group's bounding sphere."""
        f = om - c
        b = f @ wu
        g = f - b[:, None] * wu
        big = np.sqrt(np.einsum("ij,ij->i", f, f)) + r
        with np.errstate(over="ignore", invalid="ignore"):
            margin = (CULL_REL * big * big + CULL_RAD * big * (ro + big * rw)
                      + CULL_ROUND * 2.0**-53 * big * (np.abs(om).sum() + csize))  # fmt: skip
        return np.einsum("ij,ij->i", g, g), margin, big

    def line_misses(self, om: np.ndarray, wu: np.ndarray, ro: np.ndarray, rw: np.ndarray) -> np.ndarray:
        """``near_balls``' test for many lines at once, one ball at a time against every line: (N, balls) true
        where line k (origin om[k], unit direction wu[k], the exact line's origin within ro[k] and direction
        within rw[k] per component, as ``near_balls`` takes an interval's radii) passes outside the ball (in
        ``ball_ids`` order) by the cull's margin -- a certified miss at every precision, as there."""
        n, nb = len(om), len(self.ball_ids)
        out = np.zeros((n, nb), dtype=bool)
        osize = np.abs(om).sum(axis=1)
        with np.errstate(over="ignore", invalid="ignore"):
            for j in range(nb):
                f = om - self.ball_c[j]
                b = np.einsum("ij,ij->i", f, wu)
                g = f - b[:, None] * wu
                r = self.ball_r[j]
                big = np.sqrt(np.einsum("ij,ij->i", f, f)) + r
                margin = (CULL_REL * big * big + CULL_RAD * big * (ro + big * rw)
                          + CULL_ROUND * 2.0**-53 * big * (osize + self.ball_csize[j]))  # fmt: skip
                out[:, j] = np.einsum("ij,ij->i", g, g) - r * r > margin  # NaN: not culled
        return out

    def near_balls(self, o, w, keep=()) -> list[int]:
        """The balls whose surface the line o + t w may meet, in id order: every ball but those a float64 test
        shows the line to pass outside of by a wide margin (and always those in ``keep``). ``o``, ``w``: arb
        or exact rational vectors (w of any length; arb vectors with their radii).

        Why a ball culled would have been no candidate, bit for bit: ``ball_first`` (and the primary ray's
        rational test) take a ball only when its discriminant r^2 - h^2 may be >= 0, h the distance from C to
        the line, |f - (f·w) w| with f = o - C. In float64 on the midpoints, h^2 is computed to within 16 u F^2
        (F = |f| + r; a handful of roundings) plus 4 u F (|o| + |C|) from rounding o and C's difference;
        across the intervals (o and w within rad_o and rad_w per component) h^2 moves by at most
        2 F (sqrt(3) rad_o + 2 sqrt(3) F rad_w) + their squares, and ball arithmetic's own widening of the
        discriminant is a few times that (about 30 F (rad_o + F rad_w): products of radii through f, b, g and
        g·g) plus 2^-prec. A ball is culled only when the float h^2 - r^2 exceeds CULL_REL F^2 + CULL_RAD F
        (rad_o + F rad_w) + CULL_ROUND u F (|o| + |C|): then every value of the discriminant's interval is
        < 0, a certified miss at every precision, the answer the ball's own test gives. Non-finite numbers
        cull nothing.

        Groups (from GROUP_FROM balls): a group (G, R) is culled when D = h_G - R - 2^-30 F_G exceeds
        sqrt(delta_G) (1 + 2^-20), delta_G the margin above with F_G = |o - G| + R and |G|_1 + 1.75 R for |C|:
        every member then has h - r >= h_G - |C - G| - r >= D (h_G's float error is below 2^-31 F_G) and
        h + r >= D, so h^2 - r^2 > delta_G, which is at least its own margin (its F <= F_G, its |C|_1 within
        the bound): culled one by one it would have been culled too, by the exact h."""
        if len(self.ball_ids) < CULL_FROM:
            return list(self.balls)
        om = np.array([float(x.mid()) if isinstance(x, arb) else float(x) for x in o])
        wm = np.array([float(x.mid()) if isinstance(x, arb) else float(x) for x in w])
        ro = max(float(x.rad()) if isinstance(x, arb) else 0.0 for x in o)
        rw = max(float(x.rad()) if isinstance(x, arb) else 0.0 for x in w)
        length = math.sqrt(float(wm @ wm))
        if not (np.isfinite(om).all() and np.isfinite(wm).all() and math.isfinite(ro + rw)) or length == 0:
            return list(self.balls)
        wu = wm / length  # the line's direction (a rational primary V is not unit)
        rw = rw / length + 4 * 2.0**-53
        if self.groups is None:
            at = np.arange(len(self.ball_ids))
        else:
            parts, gc, gr, gsize = self.groups
            h2, delta, big = self._line_gap(om, wu, ro, rw, gc, gr, gsize)
            with np.errstate(over="ignore", invalid="ignore"):
                gap = np.sqrt(h2) - gr - 2.0**-30 * big
                culled = gap > np.sqrt(delta) * (1 + 2.0**-20)  # NaN: not culled
            kept = np.flatnonzero(~culled)
            at = np.sort(np.concatenate([parts[i] for i in kept])) if len(kept) else np.zeros(0, np.int64)
        r = self.ball_r[at]
        h2, margin, _ = self._line_gap(om, wu, ro, rw, self.ball_c[at], r, self.ball_csize[at])
        with np.errstate(invalid="ignore"):
            miss = h2 - r * r > margin  # NaN: not culled
        near = self.ball_ids[at[~miss]].tolist()
        if keep:
            near = sorted(set(near) | {k for k in keep if k in self.balls})
        return near

    def owned(self, own: tuple[int, int] | None) -> dict[int, int]:
        """Shape -> what is known of a ray's origin against it (``offset_origin``): the shape it leaves and
        every shape given with the same numbers (the same surface)."""
        if own is None:
            return {}
        k, side = own
        return {j: side for j in self.same[k]}

    def key(self, k: int, branch: int) -> tuple:
        """What a candidate's t is a function of, beside the ray: equal keys, equal t (module docstring)."""
        s = self.scene.shapes[k]
        if isinstance(s, Ball):
            return ("ball", s.center, s.radius, branch)
        return ("plane", s.normal, s.distance)

    # ---- the primary ray, rational ------------------------------------------------------------
    def primary(self, fx: fmpq, fy: fmpq) -> tuple[tuple[fmpq, ...], tuple[fmpq, ...]]:
        """Origin and direction V (not unit) of the ray through image-plane position (fx, fy) in pixels."""
        width, height, half, dist, camera_o = self.primary_consts
        px = fx / width - half
        py = -fy / height + half
        v = (px, py, dist)
        o = camera_o if camera_o is not None else (px, py, fmpq(0))
        return o, v

    def closest_primary(
        self, o: tuple[fmpq, ...], v: tuple[fmpq, ...], near: list[int] | None = None
    ) -> tuple[Hit | None, Vec, Vec]:
        """The closest hit of the primary ray, with its origin and unit direction as arb vectors. ``near``: the
        balls the ray may meet, culled for a batch of rays at once (``line_misses``), or None (``near_balls``)."""
        vv = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
        lv = arb(vv).sqrt()
        oa: Vec = tuple(arb(x) for x in o)
        d = tuple(arb(x) / lv for x in v)
        if self.slack:  # the robust evaluation: the ray widened, its decisions made on the widened ray
            oa, d = self.widen(oa), self.widen(d, unit=True)
            return self.closest(oa, d, None, near), oa, d
        cands: list[tuple[arb, int, int, fmpq | None]] = []  # (t, shape, dn sign, t/|V| when rational)
        for k in self.near_balls(o, v) if near is None else near:
            _, _, _, cq, rq = self.balls[k]
            f = (o[0] - cq[0], o[1] - cq[1], o[2] - cq[2])
            fv = f[0] * v[0] + f[1] * v[1] + f[2] * v[2]
            c = f[0] * f[0] + f[1] * f[1] + f[2] * f[2] - rq * rq
            disc = fv * fv - vv * c
            if disc < 0:
                continue
            sq = arb(disc).sqrt()
            cs, bs = qsign(c), qsign(fv)
            ds = 0 if disc == 0 else 1
            if cs > 0 and bs < 0:  # the near root, > 0
                cands.append(((-arb(fv) - sq) / lv, k, -ds, (-fv / vv) if ds == 0 else None, self.key(k, -1)))
            elif not self.rules.near_root_only and (cs < 0 or bs < 0):  # the far root, > 0
                cands.append(((-arb(fv) + sq) / lv, k, ds, (-fv / vv) if ds == 0 else None, self.key(k, 1)))
        for k, (_, _, _, nq, aq) in self.planes.items():
            i = self.plane_axis[k]  # rational and exact: an axis-aligned plane's zero components add nothing
            if i is None:
                den = nq[0] * v[0] + nq[1] * v[1] + nq[2] * v[2]
                num = aq - (nq[0] * o[0] + nq[1] * o[1] + nq[2] * o[2])
            else:
                den, num = nq[i] * v[i], aq - nq[i] * o[i]
            if den == 0 or qsign(num) * qsign(den) <= 0:
                continue
            s = num / den
            cands.append((arb(s) * lv, k, qsign(den), s, self.key(k, 0)))
        return self._nearest(cands), oa, d

    def widen(self, v: Vec, unit: bool = False) -> Vec:
        """v with every component widened by slack times |v|_inf (or, for a unit vector, by slack)."""
        if not self.slack:
            return v
        # float(c) is float(c.mid()) (the midpoint to nearest) at half the cost
        if unit:
            size = 1.0
        else:
            a, b, c = v
            size = max(abs(float(a)) + float(a.rad()), abs(float(b)) + float(b.rad()), abs(float(c)) + float(c.rad()))
        e = arb(0, self.slack * size)
        return (v[0] + e, v[1] + e, v[2] + e)

    def _nearest(self, cands) -> Hit | None:
        """The candidate with the least t; an exact tie keeps the lower shape id (decided where both t are
        rational, or both are the same root of the same shape's numbers -- a shape given twice -- else
        Uncertain)."""
        best = None
        for c in sorted(cands, key=lambda c: c[1]):
            if best is None:
                best = c
                continue
            gap = c[0] - best[0]
            if gap < 0:
                best = c
            elif not gap > 0:
                if c[3] is not None and best[3] is not None:
                    if c[3] < best[3]:
                        best = c
                    continue
                if c[4] == best[4]:  # the same numbers, the same root: the same t exactly
                    continue
                if self.guess:
                    if gap.mid() < 0:
                        best = c
                    continue
                raise Uncertain(f"depth tie between shapes {best[1]} and {c[1]}")
        return None if best is None else Hit(best[1], best[0], best[2])

    # ---- secondary rays, arb ------------------------------------------------------------------
    def ball_first(self, k: int, o: Vec, w: Vec, own: int | None = None) -> tuple[arb, int] | None:
        """The first valid root (t > 0; the near one, else under near_root_only false the far one) of the ray
        o + t w (w unit) at ball k and the sign of w·n there (-1 the near root, 1 the far one), None on a
        miss. ``own`` (the ray leaves this ball): 0, o lies exactly on it (an offset of 0); 1 or -1, o lies
        outside or inside it by construction (the error-bound offset's side), whatever o's interval says."""
        (c0, c1, c2), _, r2, _, _ = self.balls[k]
        w0, w1, w2 = w
        f = (f0, f1, f2) = (o[0] - c0, o[1] - c1, o[2] - c2)  # sub(o, center)
        b = f0 * w0 + f1 * w1 + f2 * w2  # dot(f, w)
        g0, g1, g2 = f0 - w0 * b, f1 - w1 * b, f2 - w2 * b  # sub(f, scale(w, b))
        disc = r2 - (g0 * g0 + g1 * g1 + g2 * g2)
        if own == 0:  # c = 0 exactly: roots 0 (never counts) and -2 b
            if self.rules.near_root_only:
                return None
            return (-2 * b, 1) if self.sign(b, "own ball {}'s far root", k) < 0 else None
        ds = self.sign(disc, "ball {}'s discriminant", k)
        if ds < 0:
            return None
        c = dot(f, f) - r2
        cs = own if own is not None else self.sign(c, "ray origin on ball {}", k)
        bs = self.sign(b, "ball {}: b", k)
        sq = disc.sqrt()
        if cs > 0 and bs < 0:
            return -b - sq, -1
        if not self.rules.near_root_only and (cs < 0 or (cs == 0 and bs < 0)):
            return -b + sq, 1
        return None

    def plane_t(self, k: int, o: Vec, w: Vec, own: int | None = None) -> tuple[arb, int] | None:
        """t of the ray at plane k and the sign of w·n, None on a miss; ``own``: as for ``ball_first`` (1: o
        lies on the side n points to)."""
        n, a, _, _, _ = self.planes[k]
        if own == 0:
            return None
        den = dot(n, w)
        ds = self.sign(den, "plane {}: n·d", k)
        if ds == 0:
            return None
        num = a - dot(n, o)
        ns = -own if own is not None else self.sign(num, "plane {}: ray origin on the plane", k)
        if ns * ds <= 0:
            return None
        return num / den, ds

    def closest(self, o: Vec, w: Vec, own: tuple[int, int] | None, near: list[int] | None = None) -> Hit | None:
        """The closest hit of the ray (o, w); ``own``: (the shape it leaves, ``ball_first``'s own) or None;
        ``near``: as for ``closest_primary`` (a primary ray's, which leaves no shape)."""
        mine = self.owned(own)
        cands = []
        for k in self.near_balls(o, w, mine) if near is None else near:
            got = self.ball_first(k, o, w, mine.get(k))
            if got is not None:  # d·n at the hit: (b + t)/r, the sign of the root's branch
                cands.append((got[0], k, got[1], None, self.key(k, got[1])))
        for k in self.planes:
            got = self.plane_t(k, o, w, mine.get(k))
            if got is not None:
                cands.append((got[0], k, got[1], None, self.key(k, 0)))
        return self._nearest(cands)

    def blocked(self, o: Vec, s: Vec, light_dist: arb, own: tuple[int, int] | None) -> bool:
        """Is the shadow ray (o, s) blocked (rule shadow_range)? ``own``: as for ``closest``."""
        mine = self.owned(own)
        to_light = self.rules.shadow_range != "any"
        for k in self.near_balls(o, s, mine):
            got = self.ball_first(k, o, s, mine.get(k))
            if got is not None and (not to_light or self.sign(light_dist - got[0], "ball {} against the light", k) > 0):
                return True
        for k in self.planes:
            got = self.plane_t(k, o, s, mine.get(k))
            if got is not None and (
                not to_light or self.sign(light_dist - got[0], "plane {} against the light", k) > 0
            ):
                return True
        return False

    # ---- shading --------------------------------------------------------------------------------
    def offset_origin(
        self, k: int, p: Vec, ns: Vec, flip: int, err: arb | None, direction: Vec, outward: bool
    ) -> tuple[Vec, tuple[int, int] | None]:
        """The secondary ray's origin from the hit point p on shape k (shading normal ns = flip n), and what is
        known of it by construction: (k, 0) on the surface exactly (an offset of 0), (k, side) on the side the
        error-bound offset put it (1: the side n points to), or None (computed from the origin)."""
        rules = self.rules
        if self.offset is not None:
            along = direction if rules.offset_along == "ray" else ns
            origin = add(p, scale(along, self.offset))
            if self.offset_zero:
                return origin, (k, 0)
            if rules.offset_along == "normal" and self.offset_sure(k, p, flip):
                return origin, (k, flip)
            return origin, None
        side = 1 if outward else (-1 if self.sign(dot(ns, direction), "side of the secondary ray") < 0 else 1)
        return add(p, scale(ns, side * err)), (k, side * flip)

    def offset_sure(self, k: int, p: Vec, flip: int) -> bool:
        """Does a numeric offset along the shading normal put the origin on its side (flip: 1 the side n points
        to) of shape k by construction? Exactly: always, except into a ball by more than its diameter. Robust:
        also only when the offset exceeds OFFSET_SURE u (|p| + |C| + r) -- a float64 tracer's error of its hit
        point across the surface (about 4 u of those sizes: the point's rounding, f = p - C's) 8 times over."""
        off = self.offset_f
        if k in self.balls and flip < 0 and off >= 2 * self.scene.shapes[k].radius:
            return False
        if not self.slack:
            return True
        reach = max(abs(float(c)) + float(c.rad()) for c in p) * math.sqrt(3)
        return off > OFFSET_SURE * 2.0**-53 * (reach + self.sizes[k])

    def frame(self, hit: Hit, o: Vec, d: Vec) -> tuple[Vec, Vec]:
        """The hit point p = o + t d and the hit shape's own normal there: (p - C)/r, or the plane's n/|n|."""
        k = hit.shape
        p = self.widen(add(o, scale(d, hit.t)))
        if k in self.balls:
            return p, scale(sub(p, self.balls[k][0]), self.inv_r[k])
        return p, self.planes[k][2]

    def trace(self, hit: Hit | None, o: Vec, d: Vec, depth_left: int, levels: list[Level] | None) -> Vec:
        """The colour of the ray (o, d) whose closest hit is ``hit``; ``levels``: each level appended."""
        rules = self.rules
        bg_rule = rules.background
        if hit is None:
            if levels is not None:
                levels.append(Level(None))
            return self.bg if bg_rule == "on-miss" else self.zero3
        k = hit.shape
        p, n = self.frame(hit, o, d)
        if k in self.balls:
            err = self.g6 * (self.balls[k][1] + norm(p)) if self.offset is None else None
        else:
            err = self.g4 * (abs(self.planes[k][1]) + norm(p) + norm(o)) if self.offset is None else None
        ns, flip = n, 1
        if rules.two_sided and hit.dn_sign > 0:
            ns, flip = scale(n, -1), -1
        mat = self.mat[k]
        terms: dict[str, Vec] = {"ambient": mat["ambient"]}
        local = mat["ambient"]
        dn = dot(d, ns)
        refl = self.widen(sub(d, scale(ns, 2 * dn)), unit=True)
        outward = self.offset is None and rules.near_root_only and k in self.balls
        lit = None
        if self.lit_color[k]:
            to_light = sub(self.light, p)
            light_dist = norm(to_light)
            if self.sign(light_dist, "light at the hit point") == 0:
                lit, s, sn = False, self.zero3, arb(0)
            else:
                s = self.widen(scale(to_light, 1 / light_dist), unit=True)
                sn = dot(s, ns)
                so, own = self.offset_origin(k, p, ns, flip, err, s, outward)
                lit = not self.blocked(self.widen(so), s, light_dist, own)
            zero = self.zero3
            if lit:
                fac = sn
                if rules.clamp is True:
                    fac = _gate(sn, sn, arb(0))
                dif = scale(mul3(self.lc, mat["diffuse"]), fac)
                rs = dot(refl, s)
                spec = scale(mul3(self.lc, mat["specular"]), rs**self.exponent)
                if rules.clamp is True:
                    spec = _gate3(sn, spec, zero)
                if rules.clamp in (True, "specular"):
                    spec = _gate3(rs, spec, zero)
            else:
                dif = spec = zero
            terms["diffuse"], terms["specular"] = dif, spec
            local = add(add(local, dif), spec)
        child = self.zero3
        level = Level(hit, p, n, terms, lit)
        if levels is not None:
            levels.append(level)
        if depth_left > 0 and self.reflective[k]:
            ro, own = self.offset_origin(k, p, ns, flip, err, refl, outward)
            ro = self.widen(ro)
            nxt = self.closest(ro, refl, own)
            child = self.trace(nxt, ro, refl, depth_left - 1, levels)
        terms["reflection"] = mul3(mat["reflection"], child)
        c = add(local, terms["reflection"])
        if bg_rule == "on-hit":
            terms["background"] = self.bg
            c = add(c, self.bg)
        level.color = c
        return c


def _gate(x: arb, yes: arb, no: arb) -> arb:
    """yes where x > 0, else no; both (their union) where x's sign is not certified."""
    if x > 0:
        return yes
    if x < 0 or x.is_zero():
        return no
    return yes.union(no)


def _gate3(x: arb, yes: Vec, no: Vec) -> Vec:
    if x > 0:
        return yes
    if x < 0 or x.is_zero():
        return no
    return union3(yes, no)


def set_precision(bits: int) -> None:
    ctx.prec = bits
