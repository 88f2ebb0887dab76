"""A deliberately plain transcription of the problem set's pseudo-code, for tests only.

Per pixel, recursive, pure Python floats (float64) and the math module: TraceRay exactly as the
problem set writes it, with each model rule as an `if`. It shares nothing with the fast tracer but
the scene model, so agreement between the two checks the vectorised wavefront, the masks and the
back-to-front combination. It also flags "fragile" rays: a decision (hit or miss, closest shape,
shadow blocked or not) within rounding of flipping, where the two may legitimately differ.
"""

from __future__ import annotations

import math

from minirt.model.rules import Rules
from minirt.model.scene import Ball, Scene

FRAGILE = 1e-9  # relative closeness of a decision that float64 rounding could flip


def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def add(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


def sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def mul(a, k):
    return (a[0] * k, a[1] * k, a[2] * k)


def cmul(a, b):
    return (a[0] * b[0], a[1] * b[1], a[2] * b[2])


def norm(a):
    return math.sqrt(dot(a, a))


def normalize(a):
    n = norm(a)
    return (a[0] / n, a[1] / n, a[2] / n)


def gamma(n, u=2.0**-53):
    return n * u / (1 - n * u)


class Plain:
    def __init__(self, scene: Scene, rules: Rules):
        self.scene, self.rules = scene, rules
        self.fragile = False

    # -- Ball::Intersect, Plane::Intersect (appendix 2, stable forms) --
    def intersect(self, shape, o, d):
        if isinstance(shape, Ball):
            r = shape.radius
            f = sub(o, shape.center)
            b = dot(f, d)
            g = sub(f, mul(d, b))
            lg = norm(g)
            if abs(lg - r) <= FRAGILE * r:
                self.fragile = True
            disc = (r - lg) * (r + lg)
            if disc < 0:
                return math.inf
            sq = math.sqrt(disc)
            q = -(b + math.copysign(sq, b))
            lf = norm(f)
            c = (lf - r) * (lf + r)
            t0, t1 = (c / q, q) if q != 0 else (0.0, 0.0)
            tn, tf = min(t0, t1), max(t0, t1)
            if tn > 0:
                return tn
            if not self.rules.near_root_only and tf > 0:
                return tf
            return math.inf
        n = shape.normal
        denom = dot(n, d)
        # Parallel to within rounding (a unit d's components err by a few ulps: 64 u = 7e-15 covers them):
        # whether it hits, and where, is rounding's choice. Flagged under hit_point "origin" only: there a
        # point off its surface sends shadow rays along a plane at the light's own height, whose tiny
        # component differs in sign between the two implementations' rounding orders (rules, 3 of 400
        # pixels); elsewhere both compute such a ray identically and flagging it would hide 2.5 % of rules.
        if self.rules.hit_point == "origin" and 0 < abs(denom) <= 64 * 2.0**-53:
            self.fragile = True
        if denom == 0:
            return math.inf
        t = dot(n, sub(shape.point, o)) / denom
        return t if 0 < t < math.inf else math.inf

    # -- Scene::Intersect (appendix 1) --
    def closest(self, o, d):
        best, t_best, ts = None, self.rules.t_max, []  # rule t_max: the search starts there
        for k, s in enumerate(self.scene.shapes):
            t = self.intersect(s, o, d)
            ts.append(t)
            if t < t_best:
                best, t_best = k, t
        finite = sorted(t for t in ts if t < math.inf)
        if len(finite) >= 2 and finite[1] - finite[0] <= FRAGILE * finite[1]:
            self.fragile = True
        return best, t_best

    def normal(self, shape, p):
        if isinstance(shape, Ball):
            sign = -1.0 if self.rules.ball_normal == "inward" else 1.0  # rule ball_normal: c - p
            if self.rules.offset == "error-bound":
                n = normalize(sub(p, shape.center))
                return add(shape.center, mul(n, shape.radius)), mul(n, sign)
            return p, mul(sub(p, shape.center), sign / shape.radius)
        return p, shape.normal

    def start(self, shape, p, n, direction, o):
        if self.rules.offset != "error-bound":
            if self.rules.offset_along == "ray":
                return add(p, mul(direction, self.rules.offset))
            return add(p, mul(n, self.rules.offset))
        lp = norm(p)
        # the plane's bound counts the ray's origin o: p = o + t d is off its plane by a few u |o| too
        if isinstance(shape, Ball):
            err = gamma(6) * (shape.radius + lp)
        else:
            err = gamma(4) * (abs(shape.distance) + lp + norm(o))
        side = -1.0 if dot(n, direction) < 0 else 1.0
        if isinstance(shape, Ball) and self.rules.near_root_only:
            side = 1.0  # start outside the ball: near_root_only sees nothing of it from inside
        delta = mul(n, side * err)
        q = add(p, delta)
        out = []
        for qi, di in zip(q, delta, strict=True):
            if di > 0:
                out.append(math.nextafter(qi, math.inf))
            elif di < 0:
                out.append(math.nextafter(qi, -math.inf))
            else:
                out.append(qi)
        return tuple(out)

    # -- Scene::TraceRay --
    def trace(self, o, d, depth):
        sc, ru = self.scene, self.rules
        black = (0.0, 0.0, 0.0)
        k, t = self.closest(o, d)
        if k is None:
            return sc.background if ru.background == "on-miss" else black
        shape = sc.shapes[k]
        m = shape.material
        # rule hit_point: "origin" computes the hit point as t·d, without the ray's start
        p, n = self.normal(shape, mul(d, t) if ru.hit_point == "origin" else add(o, mul(d, t)))
        if ru.two_sided and dot(d, n) > 0:
            n = mul(n, -1.0)
        color = add(black, m.ambient)
        to_light = sub(sc.light.position, p)
        dist = norm(to_light)
        s = (to_light[0] / dist, to_light[1] / dist, to_light[2] / dist)
        if ru.light == "direction":  # rule light: the light's position taken as the direction to it
            s = normalize(sc.light.position)
        r = sub(d, mul(n, 2 * dot(d, n)))
        raw = ru.raw_normals_ball if isinstance(shape, Ball) else ru.raw_normals_plane
        flip = -1.0 if ru.two_sided and dot(d, self.normal(shape, p)[1]) > 0 else 1.0
        # rules raw_normals_*: GetNormal without the normalisation: p - c (c - p inward), a plane's normal as written
        if isinstance(shape, Ball):
            nr = mul(sub(p, shape.center), flip * (-1.0 if ru.ball_normal == "inward" else 1.0))
        else:
            nr = mul(mul(shape.normal, shape.written), flip)
        if raw in ("reflection", "both"):
            r = sub(d, mul(nr, 2 * dot(d, nr)))
        r_dir = normalize(r)  # the reflected Ray's direction is normalised (Appendix 2 drops d·d)
        so = self.start(shape, p, n, s, o)
        blocked = False
        for other in sc.shapes if ru.shadow_rays else ():  # rule shadow_rays: false, no test at all
            ts = self.intersect(other, so, s)
            limit = math.inf if ru.shadow_range == "any" else dist
            if ts < limit:
                blocked = True
            if ru.shadow_range == "to-light" and ts < math.inf and abs(ts - dist) <= FRAGILE * dist:
                self.fragile = True
        if not blocked:
            sn = dot(s, n)
            rs = dot(r, mul(s, -1.0) if ru.specular_s == "-s" else s)  # rule specular_s
            sd = dot(s, nr) if raw in ("shading", "both") else sn
            e = ru.specular_exponent
            if ru.clamp is True:
                diff = max(sd, 0.0)
                spec = rs**e if (sn > 0 and rs > 0) else 0.0
            elif ru.clamp == "specular":
                diff = sd
                spec = rs**e if rs > 0 else 0.0
            else:
                diff, spec = sd, rs**e
            color = add(color, mul(cmul(sc.light.color, m.diffuse), diff))
            color = add(color, mul(cmul(sc.light.color, m.specular), spec))
        if depth > 0:
            result = self.trace(self.start(shape, p, n, r_dir, o), r_dir, depth - 1)
            color = add(color, cmul(result, m.reflection))
        if ru.background == "on-hit":
            color = add(color, sc.background)
        return color


def render_plain(scene: Scene, rules: Rules, origins, directions):
    """Colours (N, 3) and fragile flags (N,) for the given primary rays."""
    colors, fragile = [], []
    for o, d in zip(origins, directions, strict=True):
        p = Plain(scene, rules)
        colors.append(p.trace(tuple(map(float, o)), tuple(map(float, d)), scene.max_depth))
        fragile.append(p.fragile)
    return colors, fragile
