"""A student's tracer for the program tests: the exercise (problem 13.1) in NumPy, written from the
problem set alone -- it imports nothing of minirt -- and run by minirt as a program:

    python numpy_tracer.py [--rule NAME=VALUE ...] [--format pfm|png] SCENE.toml OUT

It reads minirt's scene format (tomllib), traces one ray a pixel, and writes OUT.pfm (the float colours,
unclamped) or OUT.ppm (8-bit, floor(c·255 + 0.5) of the clamped colour). Its rules are the exercise's
unless --rule changes one, with the names and values of minirt's rule table: offset (a number),
offset_along (normal|ray), ray_origin (image-plane|camera), pixel_sample (corner|center), specular_exponent,
clamp (false|true|specular), background (on-hit|on-miss|none), shadow_range (any|to-light), near_root_only,
two_sided, and the bugs of real solutions: t_max (the closest-hit search starts there), shadow_rays (false: no
shadow test), ball_normal (inward: c - p), light (direction: the light's position taken as the direction to
it), hit_point (origin: the hit point computed as t·d). The tests run it with a few of them changed and ask
minirt to name exactly those.
"""

import sys
import tomllib

import numpy as np

DEFAULTS = {
    "offset": 1e-6, "offset_along": "normal", "ray_origin": "image-plane", "pixel_sample": "corner",
    "specular_exponent": 8, "clamp": "false", "background": "on-hit", "shadow_range": "any",
    "near_root_only": "true", "two_sided": "false", "t_max": "inf", "shadow_rays": "true", "ball_normal": "outward",
    "light": "position", "hit_point": "ray",
}  # fmt: skip


def unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def dot(a, b):
    return np.sum(a * b, axis=-1)


class Tracer:
    def __init__(self, doc, rules):
        self.rules = rules
        self.cam = doc["camera"]
        self.light = np.array(doc["light"]["position"], float)
        self.light_color = np.array(doc["light"].get("color", [1, 1, 1]), float)
        render = doc.get("render", {})
        self.background = np.array(render.get("background", [0, 0, 0]), float)
        self.depth = render.get("max_depth", 3)
        mats = doc.get("materials", {})
        self.shapes = []
        for s in doc.get("shapes", []):
            m = {
                k: np.array(mats[s["material"]].get(k, [0, 0, 0]), float)
                for k in ("ambient", "diffuse", "specular", "reflection")
            }
            if s["type"] == "ball":
                self.shapes.append(("ball", np.array(s["center"], float), float(s["radius"]), m))
            else:
                n = np.array(s["normal"], float)
                length = np.linalg.norm(n)
                self.shapes.append(("plane", n / length, float(s["distance"]) / length, m))

    def hit(self, shape, o, d):
        kind, a, b, _ = shape
        if kind == "plane":
            denom = dot(d, a)
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (b - dot(o, a)) / denom
            return np.where((denom != 0) & (t > 0), t, np.inf)
        v = o - a
        p = dot(v, d)
        disc = p * p - (dot(v, v) - b * b)
        sq = np.sqrt(np.maximum(disc, 0.0))
        near, far = -p - sq, -p + sq
        t = np.where(near > 0, near, np.inf)
        if self.rules["near_root_only"] != "true":
            t = np.where((near <= 0) & (far > 0), far, t)
        return np.where(disc >= 0, t, np.inf)

    def closest(self, o, d):
        best = np.full(len(o), -1)
        t_best = np.full(len(o), float(self.rules["t_max"]))
        for k, s in enumerate(self.shapes):
            t = self.hit(s, o, d)
            closer = t < t_best
            best[closer], t_best[closer] = k, t[closer]
        return best, t_best

    def start(self, p, n, direction):
        along = n if self.rules["offset_along"] == "normal" else direction
        return p + float(self.rules["offset"]) * along

    def trace(self, o, d, depth):
        color = np.zeros((len(o), 3))
        ids, t = self.closest(o, d)
        if self.rules["background"] == "on-miss":
            color[ids < 0] = self.background
        for k, (kind, a, b, m) in enumerate(self.shapes):
            on = ids == k
            if on.any():
                color[on] = self.shade(kind, a, b, m, o[on], d[on], t[on], depth)
        return color

    def shade(self, kind, a, b, m, o, d, t, depth):
        ru = self.rules
        p = t[:, None] * d if ru["hit_point"] == "origin" else o + t[:, None] * d
        n = (p - a) / b if kind == "ball" else np.broadcast_to(a, p.shape)
        if kind == "ball" and ru["ball_normal"] == "inward":
            n = -n
        if ru["two_sided"] == "true":
            n = np.where((dot(d, n) > 0)[:, None], -n, n)
        color = np.broadcast_to(m["ambient"], p.shape).copy()
        to_light = self.light - p
        dist = np.linalg.norm(to_light, axis=-1)
        s = to_light / dist[:, None]
        if ru["light"] == "direction":
            s = np.broadcast_to(self.light / np.linalg.norm(self.light), p.shape)
        r = d - 2 * dot(d, n)[:, None] * n
        so = self.start(p, n, s)
        blocked = np.zeros(len(p), bool)
        for shape in self.shapes if ru["shadow_rays"] == "true" else ():
            ts = self.hit(shape, so, s)
            blocked |= ts < (np.inf if ru["shadow_range"] == "any" else dist)
        sn, rs = dot(s, n), dot(r, s)
        e = int(ru["specular_exponent"])
        if ru["clamp"] == "true":
            diff, spec = np.maximum(sn, 0.0), np.where((sn > 0) & (rs > 0), rs**e, 0.0)
        elif ru["clamp"] == "specular":
            diff, spec = sn, np.where(rs > 0, rs**e, 0.0)
        else:
            diff, spec = sn, rs**e
        lit = ~blocked
        color[lit] += (self.light_color * m["diffuse"]) * diff[lit, None] + (self.light_color * m["specular"]) * spec[
            lit, None
        ]
        if depth > 0:
            rd = unit(r)
            color += m["reflection"] * self.trace(self.start(p, n, rd), rd, depth - 1)
        if ru["background"] == "on-hit":
            color += self.background
        return color

    def render(self):
        w, h, dist = self.cam.get("width", 256), self.cam.get("height", 256), self.cam["distance"]
        y, x = np.divmod(np.arange(w * h, dtype=float), w)
        u = 0.0 if self.rules["pixel_sample"] == "corner" else 0.5
        plane = np.stack([(x + u) / w - 0.5, -(y + u) / h + 0.5, np.zeros_like(x)], axis=1)
        camera = np.array([0.0, 0.0, -dist])
        d = unit(plane - camera)
        o = plane if self.rules["ray_origin"] == "image-plane" else np.broadcast_to(camera, plane.shape).copy()
        return self.trace(o, d, self.depth).reshape(h, w, 3)


def write(path, color, fmt):
    h, w, _ = color.shape
    if fmt == "pfm":
        with open(path + ".pfm", "wb") as f:
            f.write(b"PF\n%d %d\n-1.0\n" % (w, h))
            f.write(color[::-1].astype("<f4").tobytes())
    else:
        levels = np.floor(np.clip(color, 0, 1) * 255 + 0.5).astype(np.uint8)
        with open(path + ".ppm", "wb") as f:
            f.write(b"P6\n%d %d\n255\n" % (w, h))
            f.write(levels.tobytes())


def main(argv):
    rules, fmt, args = dict(DEFAULTS), "pfm", []
    it = iter(argv)
    for a in it:
        if a == "--rule":
            k, _, v = next(it).partition("=")
            rules[k] = v
        elif a == "--format":
            fmt = next(it)
        else:
            args.append(a)
    scene, out = args
    with open(scene, "rb") as f:
        doc = tomllib.load(f)
    write(out, Tracer(doc, rules).render(), fmt)


if __name__ == "__main__":
    main(sys.argv[1:])
