"""Scene generators for adversarial fuzzing: families of hard cases for the tracer and its oracles.

Each family draws one small scene (1-6 shapes) from a ``random.Random`` around one hard case:

- ``random``: the plain random scene (1-4 balls, 0-2 planes around the view, random materials).
- ``start``: rays that start on or near a surface: a plane through a row or column of the image plane
  (normal not parallel to z) or offset from it by a tiny gap, the plane z = gap, balls crossing or
  touching the image plane, a ball whose surface passes (within a gap) through a pixel's ray origin.
- ``grazing``: planes almost parallel to a pixel's ray (|n·d| from 1e-12 to 1e-2) and balls whose
  silhouette passes through a pixel corner or centre (radius off by 0 or 1e-16 .. 1e-4, relative).
- ``contact``: balls resting on a plane and on each other, gaps 1e-9 .. 1e-3 or exact contact.
- ``far``: far balls on a pixel's ray (distance/radius 10 .. 1e8) and planet-sized ground balls
  (radius 1e6 .. 1e8).
- ``scaled``: a small base scene scaled about the origin by 1e-3 .. 1e6 (or exactly 2^k).
- ``f32``: a small cluster translated 1e4 .. 1e8 along the view, its detail (radii, gaps) below
  float32's resolution there, seen through a camera far enough back to frame it.

``scene_text(family, seed, index, width, height)`` is the scene file of one draw: the same text for
the same arguments on every machine. Random streams are seeded from strings (``random.Random`` hashes
them with SHA-512), and the numbers are made with IEEE-754 basic operations and square roots only
(no libm ``pow``, ``exp``, trigonometry), which round the same everywhere; floats are written with
``repr``, so they read back bit for bit. Ranges spanning decades are drawn log-uniformly.

Note on ``scaled``: the image plane is the unit square at z = 0 whatever the scale, so a scaled
scene is not seen as its base scene: scaling by k > 1 zooms in by k (the field of view narrows), by
k < 1 widens it. The geometry is exactly similar (for k = 2^k' bit-exactly), the view is not.
"""

from __future__ import annotations

import json
import math
import random
import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from minirt.model.toml_out import dump_toml

Vec = tuple[float, float, float]
Doc = dict[str, Any]

_LN10 = 2.302585092994046  # ln(10) rounded to float64


# ---------------------------------------------------------------------------------------------
# Deterministic numbers


def _exp(x: float) -> float:
    """e^x for |x| <= 3 by its Taylor series: only + * /, so the same bits on every IEEE machine."""
    term, total = 1.0, 1.0
    for k in range(1, 40):
        term = term * x / k
        total += term
    return total


def pow10(u: float) -> float:
    """10^u, deterministic (the integer part from a decimal literal, the fraction by ``_exp``)."""
    e = math.floor(u)
    return _exp((u - e) * _LN10) * float(f"1e{e}")


def log_uniform(rng: random.Random, lo: float, hi: float) -> float:
    """A value in [lo, hi], log-uniformly; lo and hi are powers of ten (1e-12, 10, 1e8), so their
    exponents are integers known exactly and no libm logarithm enters the draw."""
    a, b = _decade(lo), _decade(hi)
    return min(max(pow10(rng.uniform(a, b)), lo), hi)


def _decade(x: float) -> int:
    k = round(math.log10(x))
    if float(f"1e{k}") != x:
        raise ValueError(f"not a power of ten: {x!r}")
    return k


def _signed(rng: random.Random, x: float) -> float:
    return x if rng.random() < 0.5 else -x


def _unit(rng: random.Random) -> Vec:
    """A uniformly distributed unit vector (rejection from the cube, normalised with sqrt)."""
    while True:
        v = (rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(-1, 1))
        n2 = _dot(v, v)
        if 1e-4 < n2 <= 1:
            return _scale(v, 1 / math.sqrt(n2))


def _dot(a: Vec, b: Vec) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _add(a: Vec, b: Vec) -> Vec:
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


def _sub(a: Vec, b: Vec) -> Vec:
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def _scale(a: Vec, s: float) -> Vec:
    return (a[0] * s, a[1] * s, a[2] * s)


def _norm(a: Vec) -> float:
    return math.sqrt(_dot(a, a))


def _perpendicular(rng: random.Random, d: Vec) -> Vec:
    """A random unit vector perpendicular to the unit vector d."""
    while True:
        r = _unit(rng)
        u = _sub(r, _scale(d, _dot(r, d)))
        n = _norm(u)
        if n > 0.1:
            return _scale(u, 1 / n)


def image_point(x: float, y: float, width: int, height: int) -> tuple[float, float]:
    """The image-plane point of pixel position (x, y) (x, y may hold the sub-pixel 0.5), computed as
    minirt.model.camera does: x / W - 0.5, -y / H + 0.5."""
    return float(x) / width - 0.5, -float(y) / height + 0.5


def pixel_ray(px: float, py: float, distance: float) -> Vec:
    """The unit direction from the camera (0, 0, -distance) to (px, py, 0), as minirt.model.camera computes it."""
    dx, dy, dz = px - 0.0, py - 0.0, 0.0 - (-distance)
    n = math.sqrt(dx * dx + dy * dy + dz * dz)
    return (dx / n, dy / n, dz / n)


def _g(x: float) -> str:
    return f"{x:.3g}"


# ---------------------------------------------------------------------------------------------
# Scaling


def scale_scene(doc: Doc, factor: float) -> Doc:
    """The scene scaled about the origin by ``factor``: camera distance, light, ball centres and radii,
    plane distances (normals unchanged). A power of two scales every coordinate exactly."""
    if not (math.isfinite(factor) and factor > 0):
        raise ValueError(f"scale factor must be a positive finite number, got {factor!r}")
    out = json.loads(json.dumps(doc))  # a deep copy of plain data
    out["camera"]["distance"] = float(out["camera"]["distance"]) * factor
    out["light"]["position"] = [float(c) * factor for c in out["light"]["position"]]
    for s in out.get("shapes", []):
        if s["type"] == "ball":
            s["center"] = [float(c) * factor for c in s["center"]]
            s["radius"] = float(s["radius"]) * factor
        else:
            s["distance"] = float(s["distance"]) * factor
    return out


def scale_scene_text(text: str, factor: float) -> str:
    """``scale_scene`` on a scene file's text (comments are not kept)."""
    return dump_toml(scale_scene(tomllib.loads(text), factor))


# ---------------------------------------------------------------------------------------------
# Building scenes


class _Scene:
    """One scene being drawn: camera, light, render settings and three random materials up front,
    shapes added by the family."""

    def __init__(
        self, rng: random.Random, width: int, height: int, distance: float, samples: int | None = None
    ) -> None:
        self.rng = rng
        self.distance = distance
        self.width, self.height = width, height
        self.profile = rng.choice(["exercise", "exercise", "conventional", "conventional", "eth2014"])
        self.doc: Doc = {
            "scene": {},
            "camera": {"distance": distance, "width": width, "height": height},
            "light": {"position": [0.0, 4.0, 0.0]},
            "render": {
                "background": _vec3(rng, 0, 0.3),
                "max_depth": rng.randint(0, 3),
                "profile": self.profile,
                "samples": samples if samples is not None else rng.choice([1, 1, 4]),
            },
            "materials": {f"m{k}": _material(rng) for k in range(3)},
            "shapes": [],
        }

    @property
    def sample(self) -> float:
        """The sub-pixel position this profile's single primary ray goes through (0 corner, 0.5 centre)."""
        return 0.5 if self.profile == "eth2014" else 0.0

    def light(self, position: Vec) -> None:
        self.doc["light"]["position"] = [float(c) for c in position]

    def ball(self, center: Vec, radius: float) -> int:
        shape = {"type": "ball", "center": [float(c) for c in center], "radius": float(radius)}
        return self._add(shape)

    def plane(self, normal: Vec, distance: float) -> int:
        shape = {"type": "plane", "normal": [float(c) for c in normal], "distance": float(distance)}
        return self._add(shape)

    def _add(self, shape: Doc) -> int:
        shape["material"] = f"m{self.rng.randint(0, 2)}"
        self.doc["shapes"].append(shape)
        return len(self.doc["shapes"]) - 1

    def context_balls(self, count: int) -> None:
        """Ordinary balls in front of the camera, for something to reflect and cast shadows."""
        for _ in range(count):
            c = (self.rng.uniform(-1.5, 1.5), self.rng.uniform(-1.2, 1.2), self.rng.uniform(1, 7))
            self.ball(c, self.rng.uniform(0.15, 1))

    def done(self, description: str) -> Doc:
        self.doc["scene"]["description"] = description
        return self.doc


def _vec3(rng: random.Random, lo: float, hi: float) -> list[float]:
    return [round(rng.uniform(lo, hi), 3) for _ in range(3)]


def _material(rng: random.Random) -> Doc:
    return {
        "ambient": _vec3(rng, 0, 0.2),
        "diffuse": _vec3(rng, 0, 1),
        "specular": _vec3(rng, 0, 0.8) if rng.random() < 0.6 else [0.0, 0.0, 0.0],
        "reflection": _vec3(rng, 0, 0.5) if rng.random() < 0.5 else [0.0, 0.0, 0.0],
    }


def _random_light(rng: random.Random) -> Vec:
    return (rng.uniform(-6, 6), rng.uniform(-2, 8), rng.uniform(-4, 6))


# ---------------------------------------------------------------------------------------------
# The families


def _random(rng: random.Random, width: int, height: int) -> Doc:
    """The plain random scene: the draws, their order and their rounding of the first fuzzer, which the
    scenes in tests/scenes/fuzz_*.toml came from."""
    cam = {"distance": round(rng.uniform(0.8, 4), 3), "width": width, "height": height}
    light = {"position": _vec3(rng, -8, 8)}
    profile = rng.choice(["exercise", "conventional"])
    render = {"background": _vec3(rng, 0, 0.3), "max_depth": rng.randint(0, 4), "profile": profile}
    render["samples"] = rng.choice([1, 1, 4])
    materials = {}
    for k in range(3):
        spec = _vec3(rng, 0, 0.8) if rng.random() < 0.6 else [0.0, 0.0, 0.0]
        refl = _vec3(rng, 0, 0.5) if rng.random() < 0.5 else [0.0, 0.0, 0.0]
        materials[f"m{k}"] = {"ambient": _vec3(rng, 0, 0.2), "diffuse": _vec3(rng, 0, 1), "specular": spec}
        materials[f"m{k}"]["reflection"] = refl
    shapes: list[Doc] = []
    for _ in range(rng.randint(1, 4)):
        c = [round(rng.uniform(-2, 2), 3), round(rng.uniform(-1.5, 1.5), 3), round(rng.uniform(-1, 8), 3)]
        r = round(rng.uniform(0.1, 1.5), 3)
        shapes.append({"type": "ball", "center": c, "radius": r, "material": f"m{rng.randint(0, 2)}"})
    balls = len(shapes)
    for _ in range(rng.randint(0, 2)):
        n = _vec3(rng, -1, 1)
        if not any(n):
            n = [0.0, 1.0, 0.0]
        dist = round(rng.uniform(-3, 3), 3)
        shapes.append({"type": "plane", "normal": n, "distance": dist, "material": f"m{rng.randint(0, 2)}"})
    planes = len(shapes) - balls
    description = f"random: {balls} ball(s), {planes} plane(s) around the view"
    return {
        "scene": {"description": description},
        "camera": cam,
        "light": light,
        "render": render,
        "materials": materials,
        "shapes": shapes,
    }


def _gap(rng: random.Random, lo: float, hi: float, p_zero: float) -> float:
    return 0.0 if rng.random() < p_zero else log_uniform(rng, lo, hi)


def _gap_words(gap: float) -> str:
    return "exact" if gap == 0 else f"gap {_g(gap)}"


def _start(rng: random.Random, width: int, height: int) -> Doc:
    sc = _Scene(rng, width, height, rng.uniform(0.8, 4), samples=rng.choice([1, 1, 1, 4]))
    sc.light(_random_light(rng))
    kind = rng.choice(["row", "column", "image-plane", "crossing", "tangent", "through-pixel"])
    gap = _signed(rng, _gap(rng, 1e-12, 1e-3, p_zero=0.3))
    where = "centre" if rng.random() < 0.5 else "corner"
    sub = 0.5 if where == "centre" else 0.0
    if kind in ("row", "column"):
        # The plane contains the line of image-plane points of one row (or column) of pixel corners or
        # centres, tilted about it: normal (0, ±1, t) contains {(x, py, 0)}: n·p = ±py for every x.
        tilt = _signed(rng, log_uniform(rng, 1e-3, 10))
        if kind == "row":
            y = rng.randint(0, height - 1 if sub else height)
            _, py = image_point(0, y + sub, width, height)
            normal = (0.0, _signed(rng, 1.0), tilt)
            base, line = normal[1] * py, f"row y = {y}{' + 0.5' if sub else ''} (py = {py!r})"
        else:
            x = rng.randint(0, width - 1 if sub else width)
            px, _ = image_point(x + sub, 0, width, height)
            normal = (_signed(rng, 1.0), 0.0, tilt)
            base, line = normal[0] * px, f"column x = {x}{' + 0.5' if sub else ''} (px = {px!r})"
        sc.plane(normal, base + gap * _norm(normal))
        text = f"plane through the image plane's {line}, tilt {_g(tilt)}, {_gap_words(gap)}"
    elif kind == "image-plane":
        s = _signed(rng, 1.0)
        sc.plane((0.0, 0.0, s), s * gap)
        text = f"plane z = {gap!r} parallel to the image plane, {_gap_words(gap)}"
    elif kind == "crossing":
        r = rng.uniform(0.05, 1)
        c = (rng.uniform(-0.45, 0.45), rng.uniform(-0.45, 0.45), r * rng.uniform(-0.95, 0.95))
        sc.ball(c, r)
        text = f"ball crossing the image plane, centre z = {_g(c[2])}, radius {_g(r)}"
    elif kind == "tangent":
        r = rng.uniform(0.05, 1)
        z = _signed(rng, r + abs(gap))
        sc.ball((rng.uniform(-0.45, 0.45), rng.uniform(-0.45, 0.45), z), r)
        side = "in front of" if z > 0 else "behind"
        text = f"ball touching the image plane from {side} it, {_gap_words(abs(gap))}"
    else:
        # a ball whose surface passes (within gap, along its radius) through one pixel's ray origin
        x, y = rng.randint(0, width - 1), rng.randint(0, height - 1)
        px, py = image_point(x + sub, y + sub, width, height)
        r = rng.uniform(0.05, 1)
        u = _unit(rng)
        sc.ball(_add((px, py, 0.0), _scale(u, r + gap)), r)
        text = f"ball surface through the image-plane {where} of pixel ({x}, {y}), {_gap_words(gap)}"
    sc.context_balls(rng.randint(0, 2))
    return sc.done(f"start: {text}")


def _grazing(rng: random.Random, width: int, height: int) -> Doc:
    sc = _Scene(rng, width, height, rng.uniform(0.8, 4), samples=1)
    sc.light(_random_light(rng))
    words = []
    for _ in range(rng.randint(1, 2)):
        x, y = rng.randint(0, width - 1), rng.randint(0, height - 1)
        own = rng.random() < 0.7  # the profile's own sample point, else the other one
        sub = sc.sample if own else 0.5 - sc.sample
        where = "centre" if sub else "corner"
        px, py = image_point(x + sub, y + sub, width, height)
        d = pixel_ray(px, py, sc.distance)
        u = _perpendicular(rng, d)
        if rng.random() < 0.5:
            eps = _signed(rng, log_uniform(rng, 1e-12, 1e-2))
            normal = _add(u, _scale(d, eps))
            point = _add((px, py, 0.0), _scale(d, rng.uniform(0.5, 8)))
            sc.plane(normal, _dot(normal, point))
            words.append(f"plane with n·d = {_g(eps)} to the ray of pixel ({x}, {y})'s {where}")
        else:
            camera = (0.0, 0.0, -sc.distance)
            along = sc.distance + rng.uniform(1, 8)
            center = _add(_add(camera, _scale(d, along)), _scale(u, rng.uniform(0.1, 1.5)))
            v = _sub(center, camera)
            miss = _norm(_sub(v, _scale(d, _dot(v, d))))  # the ray's distance from the centre
            rel = _signed(rng, _gap(rng, 1e-16, 1e-4, p_zero=0.3))
            sc.ball(center, miss + miss * rel)  # not miss * (1 + rel): 1 + 1e-16 rounds to 1
            off = "exactly" if rel == 0 else f"radius off by {_g(rel)} (relative)"
            words.append(f"ball whose silhouette passes through pixel ({x}, {y})'s {where}, {off}")
    sc.context_balls(rng.randint(0, 2))
    return sc.done("grazing: " + "; ".join(words))


def _contact(rng: random.Random, width: int, height: int) -> Doc:
    sc = _Scene(rng, width, height, rng.uniform(1, 3))
    words = []
    # Dyadic values (multiples of 1/64) make exact contact exact in floating point.
    h = rng.randint(32, 96) / 64
    gap0 = _gap(rng, 1e-9, 1e-3, p_zero=0.25)
    if gap0 == 0 or rng.random() < 0.5:
        normal: Vec = (0.0, 1.0, 0.0)
    else:
        normal = _add((0.0, 1.0, 0.0), (rng.uniform(-0.3, 0.3), 0.0, rng.uniform(-0.3, 0.3)))
        normal = _scale(normal, 1 / _norm(normal))
    sc.plane(normal, -h)
    r1 = rng.randint(16, 64) / 64
    foot = (rng.randint(-48, 48) / 64, 0.0, rng.randint(128, 320) / 64)
    foot = _add(foot, _scale(normal, -h - _dot(foot, normal)))  # onto the plane
    if normal == (0.0, 1.0, 0.0):
        foot = (foot[0], -h, foot[2])
    c1 = _add(foot, _scale(normal, r1 + gap0))
    b1 = sc.ball(c1, r1)
    words.append(f"ball {b1} on plane 0, {_gap_words(gap0)}")
    balls = [(b1, c1, r1)]
    for _ in range(rng.randint(1, 3)):
        on, c, r = rng.choice(balls)
        r2 = rng.randint(8, 48) / 64
        g = _gap(rng, 1e-9, 1e-3, p_zero=0.25)
        if g == 0:
            axis = rng.choice([(0.0, 1.0, 0.0), (1.0, 0.0, 0.0), (-1.0, 0.0, 0.0), (0.0, 0.0, -1.0)])
        else:
            axis = _unit(rng)
            if axis[1] < 0:
                axis = (axis[0], -axis[1], axis[2])
        c2 = _add(c, _scale(axis, r + r2 + g))
        b2 = sc.ball(c2, r2)
        words.append(f"ball {b2} on ball {on}, {_gap_words(g)}")
        balls.append((b2, c2, r2))
    # the light above the contacts, so shadow rays pass through the gaps
    top = max(c[1] + r for _, c, r in balls)
    sc.light((c1[0] + rng.uniform(-3, 3), top + rng.uniform(0.5, 6), c1[2] + rng.uniform(-3, 3)))
    return sc.done("contact: " + "; ".join(words))


def _far(rng: random.Random, width: int, height: int) -> Doc:
    sc = _Scene(rng, width, height, rng.uniform(0.8, 4))
    camera = (0.0, 0.0, -sc.distance)
    words = []
    planet = rng.random() < 0.5
    if planet:
        big = log_uniform(rng, 1e6, 1e8)
        below = rng.uniform(0.3, 2)
        sc.ball((0.0, -below - big, rng.uniform(0, 10)), big)
        words.append(f"ground ball of radius {_g(big)}, its top {_g(below)} below the camera")
        for _ in range(rng.randint(0, 2)):
            r = rng.uniform(0.1, 0.8)
            sc.ball((rng.uniform(-1.5, 1.5), -below + r + rng.uniform(0, 0.5), rng.uniform(2, 8)), r)
    for _ in range(rng.randint(0 if planet else 1, 3)):
        # above a planet, only rays looking up (py >= 0) clear its horizon
        top = math.floor(height / 2 - sc.sample) if planet else height - 1
        x, y = rng.randint(0, width - 1), rng.randint(0, max(top, 0))
        d = pixel_ray(*image_point(x + sc.sample, y + sc.sample, width, height), sc.distance)
        ratio = log_uniform(rng, 10, 1e8)
        r = log_uniform(rng, 1e-2, 1e2)
        sc.ball(_add(camera, _scale(d, ratio * r)), r)
        words.append(f"ball on the ray of pixel ({x}, {y}), distance/radius {_g(ratio)}, radius {_g(r)}")
    sc.light(_random_light(rng))
    return sc.done("far: " + "; ".join(words))


def _scaled(rng: random.Random, width: int, height: int) -> Doc:
    sc = _Scene(rng, width, height, rng.uniform(0.8, 4))
    sc.light(_random_light(rng))
    sc.context_balls(rng.randint(1, 3))
    if rng.random() < 0.6:
        sc.plane(_unit(rng), rng.uniform(-3, 3))
    if rng.random() < 0.3:
        k = rng.randint(-10, 19)
        factor = math.ldexp(1.0, k)
        words = f"2^{k} (factor {factor!r})"
    else:
        factor = log_uniform(rng, 1e-3, 1e6)
        words = f"factor {factor!r}"
    doc = scale_scene(sc.done(""), factor)
    doc["scene"]["description"] = f"scaled: a small scene scaled by {words}"
    return doc


def _f32(rng: random.Random, width: int, height: int) -> Doc:
    far = log_uniform(rng, 1e4, 1e8)
    view = rng.uniform(2, 8)  # the width seen at the cluster
    sc = _Scene(rng, width, height, far / view)
    ulp32 = math.ldexp(1.0, math.frexp(far)[1] - 24)  # float32's spacing at the cluster's depth
    home = (rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), far)
    words = [f"cluster at z = {_g(far)} (float32 spacing {_g(ulp32)})"]
    detail = ulp32 * log_uniform(rng, 1e-4, 1e2)  # ulp32 a power of two: exact
    r0 = rng.uniform(0.2, 1)
    c0 = home
    sc.ball(c0, r0)
    kinds = []
    for _ in range(rng.randint(1, 3)):
        kind = rng.choice(["tiny", "near", "inside"])
        if kind == "tiny":  # a ball smaller than float32's spacing, beside the big one
            c = _add(c0, (rng.uniform(-1.5, 1.5), rng.uniform(-1, 1), -rng.uniform(0.5, 1.5)))
            sc.ball(c, detail)
            kinds.append(f"ball of radius {_g(detail)}")
        elif kind == "near":  # a ball a gap below float32's spacing from the first
            r = rng.uniform(0.1, 0.6)
            sc.ball(_add(c0, _scale(_unit(rng), r0 + r + detail)), r)
            kinds.append(f"ball {_g(detail)} from ball 0")
        else:  # two concentric-ish surfaces closer than float32 can tell
            sc.ball(_add(c0, (0.0, 0.0, -detail)), r0 + detail)
            kinds.append(f"shell {_g(detail)} around ball 0")
    if rng.random() < 0.6:
        # a back wall at the cluster's depth: a plane distance float32 rounds by ulp32 / 2
        back = far + rng.uniform(1, 4)
        sc.plane((rng.uniform(-0.2, 0.2), rng.uniform(-0.2, 0.2), 1.0), back)
        kinds.append(f"wall at z ~ {_g(back)}")
    sc.light((rng.uniform(-5, 5), rng.uniform(0, 6), far - rng.uniform(2, 10)))
    words.append(", ".join(kinds))
    return sc.done("f32: " + "; ".join(words))


@dataclass(frozen=True)
class Family:
    name: str
    summary: str
    build: Callable[[random.Random, int, int], Doc]  # the scene as a TOML document (plain data)

    def function(self, rng: random.Random, width: int, height: int) -> str:
        """One scene of this family drawn from rng, as TOML text (a description, no name)."""
        return dump_toml(self.build(rng, width, height))


FAMILIES: dict[str, Family] = {
    f.name: f
    for f in (
        Family("random", "random balls and planes around the view, random materials and light", _random),
        Family("start", "rays starting on or near a plane or ball at the image plane (gaps 0, 1e-12 .. 1e-3)", _start),
        Family("grazing", "planes almost parallel to a pixel's ray, balls tangent to one (|n·d| >= 1e-12)", _grazing),
        Family("contact", "balls resting on a plane and on each other, gaps 0 or 1e-9 .. 1e-3", _contact),
        Family("far", "balls 10 .. 1e8 radii away on a pixel's ray; planet-sized grounds (1e6 .. 1e8)", _far),
        Family("scaled", "a small scene scaled about the origin by 1e-3 .. 1e6 or 2^k", _scaled),
        Family("f32", "a cluster 1e4 .. 1e8 away with detail below float32's spacing there", _f32),
    )
}


def rng_for(family: str, seed: int, index: int) -> random.Random:
    """The random stream of one scene: seeded from a string (SHA-512 inside), the same everywhere."""
    return random.Random(f"{family}:{seed}:{index}")


def scene_document(family: str, seed: int, index: int, width: int, height: int) -> Doc:
    if family not in FAMILIES:
        raise KeyError(f"unknown family {family!r} (known: {', '.join(FAMILIES)})")
    doc = FAMILIES[family].build(rng_for(family, seed, index), width, height)
    doc["scene"] = {"name": f"{family}_{seed}_{index}", **doc["scene"]}
    return doc


def scene_text(family: str, seed: int, index: int, width: int, height: int) -> str:
    """The TOML text of scene ``index`` of ``family`` under ``seed``, ``width`` x ``height`` pixels:
    the same text for the same arguments on every machine."""
    return dump_toml(scene_document(family, seed, index, width, height))
