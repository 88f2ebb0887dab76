"""Mitsuba 3 as an oracle: its own intersector and stock BSDF/emitter plugins on the harness's rays.

Package ``mitsuba`` 3.9.1, variant ``llvm_ad_rgb`` (``scalar_rgb`` when Dr.Jit's LLVM backend is
unusable: a per-ray loop, correct but slow -- keep images small). Two routes:

- ``mode = "rays"`` (default): the exact rays of :func:`minirt.model.camera.primary_rays` (float64,
  rounded to Mitsuba's float32) are traced with ``scene.ray_intersect``; shading is a loop of stock
  calls -- ``sample_emitter_direction`` with its visibility test (the shadow ray), ``bsdf.eval`` of
  the shape's BSDF, and ``conductor.sample`` to follow delta reflections only, up to ``max_depth``.
- ``mode = "sensor"``: Mitsuba's ``perspective`` sensor generates the rays itself and ``mi.render``
  renders them (``aov`` integrator for depth/position/normal/shape index around ``direct``; with
  spp > 1 also ``moment`` for the per-pixel variance). Square images only.

Conventions bridged (each one is a place where Mitsuba and the exercise differ):

- Handedness / mirror: the exercise's camera looks along +z with +x to the RIGHT of the image (a
  left-handed frame); Mitsuba's perspective camera puts camera +x on the LEFT. The exported sensor's
  ``to_world`` is look_at((0,0,-d) -> origin, up +y) times scale(-1, 1, 1), so a user opening the XML
  sees the exercise's image, not its mirror. (The custom-ray route needs no camera at all.)
- Pixel corner vs centre: a sensor sample is ``pixel + sampler.next_2d()``; the non-jittered
  stratified sampler at 1 spp gives the pixel centre. The exercise's ray goes through the pixel's
  top-left corner (rule pixel_sample = "corner"), so the principal point is shifted by half a pixel
  (``principal_point_offset_x = -0.5/W`` in the mirrored frame, ``_y = -0.5/H``); for
  pixel_sample = "center" no shift. With spp > 1 there is no shift either: the samples then cover
  the pixel square [x, x+1] x [y, y+1] whose top-left is the exercise's corner ray, the same square
  the reference tracer's stratified samples cover. Field of view: ``fov_axis = x``, ``fov = 2 atan(0.5 / d)`` (the
  image plane is [-0.5, 0.5]^2 at distance d); W != H (non-square pixels) cannot be expressed.
- Near clip: Mitsuba moves sensor ray origins onto the plane z_cam = near_clip and counts t from
  there. With near_clip = d the origins are exactly the exercise's image-plane points (rule
  ray_origin = "image-plane"); for "camera" near_clip is tiny (1e-7 d) and t is off by <= 1e-7 d.
- Planes: Mitsuba has no infinite plane. Each plane is a ``rectangle`` (local [-1,1]^2, normal +z)
  with ``to_world`` = [S_u t1, S_v t2, n, c] (t1, t2, n a right-handed orthonormal frame of the
  plane). In 3.9.1 a rectangle is a two-triangle mesh: the hit point is interpolated from corners
  of magnitude |c| + S and t = |p - o| is recomputed from it, so its absolute error grows like
  u32 (|c| + |S|). The rectangle is therefore the smallest one covering every point a ray of this
  view can hit: the bounding box (in plane coordinates) of (a) every primary ray's hit with the
  infinite plane (exact, float64, the harness's own rays), (b) the balls' and the light's
  projections, then (c) after tracing, every secondary ray (reflection) whose infinite-plane hit is
  nearer than what Mitsuba reported, and every shadow segment (hit point -> light) crossing the
  plane; if (c) finds points outside, the box grows and the render is repeated (at most
  ``_MAX_RESIZE`` times; the count is in meta, and ``plane_coverage_complete`` False if the last
  render still missed points: its shadow decisions are then not judged). The box is padded by 1e-3 of its size. See
  ``plane_frames`` and meta["planes"] (sizes and each plane's absolute error bound).
- Falloff and pi: a ``point`` emitter's ``intensity`` is radiant intensity (irradiance I / r^2),
  ``diffuse`` is reflectance / pi. Mitsuba's diffuse radiance is dc I max(0, n.s) / (pi r^2); the
  exercise's is n.s dc lc. We set I = lc and do NOT bend Mitsuba: ``color``/terms["diffuse"] are
  Mitsuba's numbers; aux["light_distance"] (r at each primary hit, as Mitsuba used it) and
  aux["diffuse_to_exercise"] = pi r^2 make terms["diffuse"] * pi r^2 = n.s dc lc (I = lc; divided by
  I it is n.s dc);
  aux["diffuse_exercise"] and aux["reflection_exercise"] apply the same factor per bounce.
  Mitsuba writes no 8-bit image of its own and its radiance is tiny in these units (1/(pi r^2)), so
  ``image8`` (the PNG) shows diffuse_exercise + reflection_exercise: viewable beside the other
  backends. The EXR's colour channels stay Mitsuba's own radiance.
- Falloff in the export (``minirt export SCENE --to mitsuba``): a file for people to open in
  Mitsuba, not for the checks. With I = lc its render would be near black (~1e-3 for a light 15 units
  away), so the exported light's intensity is lc * pi * d^2, d the *viewing distance*
  (:func:`viewing_distance`: the median distance from the light to the points the camera's rays hit,
  taken on a grid of at most 64 x 64 primary rays). At distance d Mitsuba's diffuse radiance then
  equals the exercise's n.s dc lc; nearer points come out brighter and farther ones darker (1/r^2).
  The median, not the mean, so that a far floor does not decide it; the hit points, not the look-at
  point (the image plane's centre, usually in front of every shape). The file states the factor in a
  comment. The oracle's own renders (``render``, ``check``) keep I = lc and convert per pixel.
- Ambient, Phong specular, background: Mitsuba has no ambient term and no (r.s)^8 lobe, and a miss
  returns black. They are not simulated; meta["unsupported_terms"] lists the ones the scene uses.
- One-sidedness: ``rectangle``/``diffuse``/``conductor`` are one-sided, so every BSDF is wrapped in
  ``twosided`` (rule two_sided = true). Geometric normals are NOT flipped toward the ray (like the
  reference's ``normal`` buffer).
- Mirrors: ``conductor`` with the default material "none" is a perfect mirror whose weight is
  ``specular_reflectance`` = the material's reflection colour kr: c = local + kr * trace(reflected).
- Shadows on planes: an infinite plane never shadows its own points, but the rectangle standing in for
  it can (float32 corner interpolation, abs_error in meta planes). With planes in the scene the
  visibility test is Mitsuba's ``ray_intersect`` on ``spawn_ray_to(light)`` (the stock test's own
  segment), with a hit on the plane the point lies on not counted.
- Mesh merging: Mitsuba's loader merges meshes that share a BSDF (two rectangles of one material) into
  one shape; scenes are loaded with ``optimize=False`` so that every plane keeps its own shape.
- Registry ids: in JIT variants ``si.shape`` (and the aov ``shape_index``) is a process-wide registry
  id. Shapes get ids "shape<k>" (k = index in the scene file); the registry ids of
  ``scene.shapes_dr()``, in the order of ``scene.shapes()``, are mapped back to k through those ids.
- Dr.Jit flags: none is changed (FastMath stays as Mitsuba's default; nothing here needs IEEE
  NaN/inf semantics beyond what Mitsuba itself guarantees).
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from minirt.jit.arrays import aligned
from minirt.model import camera
from minirt.model.backend import GeometryTolerance, Margins, Series, Setting, Truth
from minirt.model.result import RenderResult, geometry_from_flat, to8
from minirt.model.rules import Rules
from minirt.model.scene import Ball, Plane, Scene
from minirt.oracles.base import Oracle

BACKEND = "mitsuba"
PACKAGE_VERSION = "3.9.1"
VARIANTS = ("llvm_ad_rgb", "scalar_rgb")  # preferred first
U32 = 2.0**-24  # float32 unit round-off
# Mitsuba's spawn_ray offset: a secondary ray leaves si.p + n * RAY_EPSILON (1 + max|p|) (include/mitsuba/core
# math.h: RayEpsilon = Epsilon * 1500, Epsilon = 2^-24 in float32). Where a rectangle's own float32 error
# exceeds it, the stock integrator's shadow ray can re-hit the rectangle (the sensor route; the custom rays
# restart past the error slab instead).
RAY_EPSILON = 2.0**-24 * 1500
# Growths of the plane rectangles before giving up. Each growth can uncover more: a reflection that now
# hits a grown rectangle far away, whose shadow segment crosses another plane outside its rectangle (a
# fuzzed scene with two far-reaching planes and four bounces needed 4). The last growth is always
# rendered; if growth still goes on after this many, meta["plane_coverage_complete"] is False.
_MAX_RESIZE = 8
_PAD = 1e-3

# ---------------------------------------------------------------------------------------------
# Precision (used by the tests and recorded in meta["precision"]).
#
# Mitsuba's sphere (float32 in *_ad_* variants) solves |o + t d - c|^2 = r^2 with f = o - c in
# float32. Away from the silhouette the roots carry a few roundings of magnitude |f|: relative t
# error ~ 8 u32 |f| / t. At the silhouette the discriminant D = r^2 - h^2 (h the ray's distance from
# the centre) cancels: its absolute error is ~ 4 u32 |f|^2, and t moves by dD / (2 sqrt(D)), so the
# relative error grows like u32 |f|^2 / (r t sqrt(2 m)) with m = |h - r| / r the band margin. The
# hit/miss decision flips where D's error reaches D = 2 r^2 m, i.e. at m ~ 2 u32 |f|^2 / r^2.
# Rectangles add an absolute error ~ 8 u32 (|c| + |S|) (see the module docstring).
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
    for k, s in enumerate(scene.shapes):
        on = shape_id == k
        if not isinstance(s, Ball) or not on.any():
            continue
        f = o[on] - np.asarray(s.center)
        b = np.einsum("ij,ij->i", f, d[on])
        hh = np.linalg.norm(f - b[:, None] * d[on], axis=1)
        m = np.maximum(np.abs(s.radius - hh) / s.radius, 1e-30)
        out[on] = 4 * U32 * np.einsum("ij,ij->i", f, f) / (s.radius * np.sqrt(2 * m))
    return out


# ---------------------------------------------------------------------------------------------
# Mitsuba import and variant selection.

_state: dict[str, Any] = {}


def _load_mitsuba() -> tuple[Any, str]:
    """Import mitsuba and set the first usable variant; raises ImportError/RuntimeError with a reason."""
    if "mi" in _state:
        mi = _state["mi"]
        if mi.variant() != _state["variant"]:
            mi.set_variant(_state["variant"])
        return mi, _state["variant"]
    import mitsuba as mi

    if getattr(mi, "__version__", "") != PACKAGE_VERSION:
        raise RuntimeError(f"mitsuba {PACKAGE_VERSION} is required, found {getattr(mi, '__version__', '?')}")
    problems = []
    for variant in VARIANTS:
        if variant not in mi.variants():
            problems.append(f"{variant}: not built")
            continue
        if variant.startswith("llvm"):
            from minirt.jit.engine import llvm_status

            ok, why = llvm_status()
            if not ok:
                problems.append(f"{variant}: {why}")
                continue
        try:
            mi.set_variant(variant)
            mi.load_dict({"type": "scene"})  # smoke test: a kernel-free load
        except Exception as e:  # a variant that cannot run is not fatal: try the next one
            problems.append(f"{variant}: {type(e).__name__}: {e}")
            continue
        _state.update(mi=mi, variant=variant, problems=problems)
        return mi, variant
    raise RuntimeError("no usable Mitsuba variant (" + "; ".join(problems) + ")")


def _one_line(e: BaseException) -> str:
    text = f"{type(e).__name__}: {e}".strip()
    return " ".join(text.split())[:300]


# ---------------------------------------------------------------------------------------------
# Geometry helpers (pure NumPy).


def _frame(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A right-handed orthonormal frame (t1, t2) with t1 x t2 = n (Duff et al.'s branchless form)."""
    sign = math.copysign(1.0, n[2])
    a = -1.0 / (sign + n[2])
    b = n[0] * n[1] * a
    t1 = np.array([1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0]])
    t2 = np.array([b, sign + n[1] * n[1] * a, -n[1]])
    return t1, t2


class PlaneRect:
    """The rectangle standing in for one plane: frame, centre (in plane coordinates) and half-sizes."""

    def __init__(self, plane: Plane):
        self.n = np.asarray(plane.normal, dtype=np.float64)
        self.q = np.asarray(plane.point, dtype=np.float64)
        self.t1, self.t2 = _frame(self.n)
        self.lo = np.array([np.inf, np.inf])
        self.hi = np.array([-np.inf, -np.inf])

    def uv(self, p: np.ndarray) -> np.ndarray:
        r = np.atleast_2d(p) - self.q
        return np.stack([r @ self.t1, r @ self.t2], axis=1)

    def include(self, p: np.ndarray) -> bool:
        """Grow the box to contain points p (N, 3); True if it grew."""
        p = np.atleast_2d(p)
        p = p[np.all(np.isfinite(p), axis=1)]
        if len(p) == 0:
            return False
        uv = self.uv(p)
        lo, hi = np.minimum(self.lo, uv.min(axis=0)), np.maximum(self.hi, uv.max(axis=0))
        grew = bool(np.any(lo < self.lo) or np.any(hi > self.hi))
        self.lo, self.hi = lo, hi
        return grew

    def outside(self, p: np.ndarray) -> np.ndarray:
        """Which points p (N, 3) lie outside the (padded) rectangle."""
        uv = self.uv(p)
        c, s = self.centre_uv(), self.half()
        return np.any(np.abs(uv - c) > s, axis=1)

    def centre_uv(self) -> np.ndarray:
        return (self.lo + self.hi) / 2

    def half(self) -> np.ndarray:
        h = (self.hi - self.lo) / 2
        return h * (1 + _PAD) + _PAD * max(float(np.max(h)), 1.0)

    def to_world(self) -> np.ndarray:
        cu, cv = self.centre_uv()
        su, sv = self.half()
        c = self.q + cu * self.t1 + cv * self.t2
        m = np.eye(4)
        m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = su * self.t1, sv * self.t2, self.n, c
        return m

    def abs_error(self) -> float:
        """Bound on the hit point's absolute error: corners of magnitude |c| + |S| interpolated in float32."""
        m = self.to_world()
        return 8 * U32 * (float(np.linalg.norm(m[:3, 3])) + float(np.hypot(*self.half())))

    def normal_error(self) -> float:
        """Bound on the error of a point's signed distance from the rectangle, which decides t >= 0: Mitsuba
        takes the ray to the rectangle's frame (to_object, float32) and solves t = -o.z / d.z. The local z
        row of to_object is the unit normal with offset -n·c; rounding the centre c to float32 and the
        inverse's cofactors (whose relative error is a few u, the in-plane scales cancelling) moves that
        offset by a few u |c|: 8 u32 |c|. The half size does not enter (it scales x and y only), so a
        rectangle 3.5e6 wide with its centre 2.4e6 away errs by 1.1 across its plane, not 2.3 (fuzz
        shadow_within_position_error: with abs_error its start band held 806 of 1032 hit pixels, now 0)."""
        return 8 * U32 * float(np.linalg.norm(self.to_world()[:3, 3]))

    def describe(self) -> dict[str, Any]:
        m = self.to_world()
        return {
            "centre": m[:3, 3].tolist(),
            "half_size": self.half().tolist(),
            "abs_error": self.abs_error(),
            "normal_error": self.normal_error(),
        }


def plane_hits(plane: PlaneRect, o: np.ndarray, d: np.ndarray) -> np.ndarray:
    """t of each ray with the infinite plane (float64), inf when parallel or behind."""
    nd = d @ plane.n
    with np.errstate(divide="ignore", invalid="ignore"):
        t = ((plane.q - o) @ plane.n) / nd
    return np.where(np.isfinite(t) & (t > 0), t, np.inf)


def plane_frames(scene: Scene, o: np.ndarray, d: np.ndarray) -> dict[int, PlaneRect]:
    """Initial rectangles: primary-ray hits, balls and the light projected (see the module docstring)."""
    rects = {}
    light = np.asarray(scene.light.position, dtype=np.float64)
    for k, s in enumerate(scene.shapes):
        if not isinstance(s, Plane):
            continue
        r = PlaneRect(s)
        t = plane_hits(r, o, d)
        r.include(o + np.where(np.isfinite(t), t, np.nan)[:, None] * d)
        # A grazing ray's hit moves along it by t DIR_ERR / |n·d| with the float32 direction: include that
        # far (4x) too, or Mitsuba's hit lands past the rectangle's edge (fuzz grazing_2026_46: |n·d| 1.7e-6,
        # the hit 6 % farther, beyond a rectangle sized by it). Rays with |n·d| <= 4 DIR_ERR are in the band.
        with np.errstate(divide="ignore", invalid="ignore"):
            spread = 4 * DIR_ERR / np.abs(d @ r.n)
        far = np.where(np.isfinite(t) & (spread < 1), t * (1 + spread), np.nan)
        r.include(o + far[:, None] * d)
        pts = [light, r.q, np.asarray(scene.camera.position)]
        for b in scene.shapes:
            if isinstance(b, Ball):
                c = np.asarray(b.center)
                pts += [c + b.radius * r.t1, c - b.radius * r.t1, c + b.radius * r.t2, c - b.radius * r.t2]
        r.include(np.array(pts))
        rects[k] = r
    return rects


def sensor_frames(scene: Scene, rules: Rules) -> dict[int, PlaneRect]:
    """Rectangles for the sensor route, which cannot grow them after tracing (Mitsuba's own rays and its
    stock ``direct`` integrator): ``plane_frames`` of the rays through every pixel square's four corners
    (the sensor's samples lie inside those squares, and a square's hits on a plane lie inside its
    corners' hits), plus each plane's projection of every such ray's hit on the other planes. A shadow
    segment from a hit P to the light L crosses plane B at a point of B lying between the projections of
    P and L onto B; both are in B's box, which is convex, so B covers every first shadow segment. (A
    fuzzed scene, random_7_5: a shadow segment passed beyond a rectangle sized for the primary rays
    alone, and 6 of its pixels came out lit, 21 sigma on that plane's mean.)"""
    os_, ds = [], []
    for u, v in ((0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)):
        n = scene.camera.width * scene.camera.height
        o, d = camera.rays_through(scene, rules, np.full(n, u), np.full(n, v))
        os_.append(o)
        ds.append(d)
    o, d = np.concatenate(os_), np.concatenate(ds)
    rects = plane_frames(scene, o, d)
    hits = {k: o + np.where(np.isfinite(t := plane_hits(r, o, d)), t, np.nan)[:, None] * d for k, r in rects.items()}
    for k, r in rects.items():
        for j, p in hits.items():
            if j != k:
                r.include(p)
    return rects


# ---------------------------------------------------------------------------------------------
# The scene as Mitsuba XML: numbers and fixed keywords only.


def _num(x: float) -> str:
    x = float(x)
    if not math.isfinite(x):
        raise ValueError(f"non-finite number {x!r} cannot be written to XML")
    return repr(x)


def _rgb(c) -> str:
    return ", ".join(_num(v) for v in c)


def _comment(text: str) -> str:
    """Text safe inside <!-- -->: XML-escaped, no '--', no control characters, one line."""
    from xml.sax.saxutils import escape

    s = "".join(ch if ch.isprintable() else "?" for ch in str(text))
    s = escape(s).replace("-", "&#45;")  # '--' and a trailing '-' are illegal in comments
    return s[:200]


def _unbounded(name: str, rgb) -> str:
    """An sRGB reflectance allowed above 1 (2 dc, 2 kr can exceed 1; `<rgb>` would reject them)."""
    return (
        f'<spectrum type="srgb" name="{name}"><rgb name="color" value="{_rgb(rgb)}"/>'
        '<boolean name="unbounded" value="true"/></spectrum>'
    )


def _bsdf_xml(m, indent: str, bsdf_id: str) -> list[str]:
    """twosided(diffuse), twosided(conductor) or twosided(blendbsdf(0.5: 2 dc diffuse, 2 kr conductor)),
    declared under ``bsdf_id`` for the shapes to reference.

    The render uses the shape's BSDF for the local (diffuse) term and a separate ``conductor`` with
    kr for reflections; the blend gives a user who renders the file the same two lobes: 0.5 * 2 dc
    and 0.5 * 2 kr are exact in float32.
    """
    has_d = any(v != 0 for v in m.diffuse)
    has_r = any(v != 0 for v in m.reflection)
    i2, i3 = indent + "    ", indent + "        "
    if has_d and has_r:
        inner = [
            f'{i2}<bsdf type="blendbsdf">',
            f'{i3}<float name="weight" value="0.5"/>',
            f'{i3}<bsdf type="diffuse">{_unbounded("reflectance", [2 * v for v in m.diffuse])}</bsdf>',
            f'{i3}<bsdf type="conductor">{_unbounded("specular_reflectance", [2 * v for v in m.reflection])}</bsdf>',
            f"{i2}</bsdf>",
        ]
    elif has_r:
        inner = [f'{i2}<bsdf type="conductor"><rgb name="specular_reflectance" value="{_rgb(m.reflection)}"/></bsdf>']
    else:
        inner = [f'{i2}<bsdf type="diffuse"><rgb name="reflectance" value="{_rgb(m.diffuse)}"/></bsdf>']
    return [f'{indent}<bsdf type="twosided" id="{bsdf_id}">', *inner, f"{indent}</bsdf>"]


def _matrix(m: np.ndarray) -> str:
    return " ".join(_num(v) for v in np.asarray(m, dtype=np.float64).reshape(-1))


def sensor_params(scene: Scene, rules: Rules, spp: int = 1) -> dict[str, Any]:
    """The perspective sensor reproducing the exercise's rays (square images; see the docstring)."""
    w, h, d = scene.camera.width, scene.camera.height, scene.camera.distance
    corner = rules.pixel_sample == "corner" and spp == 1  # spp > 1: the whole pixel square, as the reference
    # camera-to-world: look_at((0,0,-d) -> 0, up +y) is the identity rotation plus a translation;
    # scale(-1, 1, 1) mirrors camera x so that image columns run toward world +x.
    to_world = np.array([[-1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, -d], [0, 0, 0, 1.0]])
    return {
        "fov": math.degrees(2 * math.atan(0.5 / d)),
        "near_clip": d if rules.ray_origin == "image-plane" else 1e-7 * d,
        # beyond every hit the harness asks about: 1e7, or 1e4 camera distances for a camera set far back
        # (Mitsuba refuses near_clip >= far_clip: a fuzzed f32 scene with its camera 2.5e7 away)
        "far_clip": max(1e7, 1e4 * d),
        "principal_point_offset_x": _principal_offset(-0.5 if corner else 0.0, rules.pixel_shift[0], w),
        "principal_point_offset_y": _principal_offset(-0.5 if corner else 0.0, rules.pixel_shift[1], h),
        "to_world": to_world,
        "width": w,
        "height": h,
    }


def _principal_offset(base: float, shift: float, size: int) -> float:
    """The sensor's principal point offset for a sub-pixel offset `base` (pixels from the centre) plus the
    rule pixel_shift (pixels): one pixel is 1/size of the film. Unshifted, exactly base / size."""
    return (base + shift) / size if shift != 0 else base / size


VIEWING_GRID = 64  # rays per side at most for viewing_distance: a median, it needs no more


def viewing_distance(scene: Scene, rules: Rules) -> float | None:
    """The median distance from the light to the points the camera's primary rays hit (at most a
    VIEWING_GRID^2 grid of them, analytic float64 intersections); None when no ray hits anything."""
    w, h = scene.camera.width, scene.camera.height
    small = scene.with_overrides(width=min(w, VIEWING_GRID), height=min(h, VIEWING_GRID))
    o, d = camera.primary_rays(small, rules)
    best = np.full(len(o), np.inf)
    for s in scene.shapes:
        if isinstance(s, Ball):
            f = o - np.asarray(s.center, dtype=np.float64)
            b = np.einsum("ij,ij->i", f, d)
            disc = b * b - (np.einsum("ij,ij->i", f, f) - s.radius**2)
            root = np.sqrt(np.maximum(disc, 0.0))
            t = np.where(-b - root > 1e-9, -b - root, -b + root)
            t = np.where((disc >= 0) & (t > 1e-9), t, np.inf)
        else:
            n = np.asarray(s.normal, dtype=np.float64)
            den = d @ n
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (s.distance - o @ n) / den
            t = np.where(np.isfinite(t) & (t > 1e-9), t, np.inf)
        best = np.minimum(best, t)
    hit = np.isfinite(best)
    if not hit.any():
        return None
    p = o[hit] + best[hit, None] * d[hit]
    return float(np.median(np.linalg.norm(p - np.asarray(scene.light.position, dtype=np.float64), axis=1)))


def scene_to_xml(
    scene: Scene,
    rules: Rules,
    rects: dict[int, PlaneRect] | None = None,
    spp: int = 1,
    light_distance: float | None = None,
) -> str:
    """The scene as a Mitsuba 3 XML file. Only numbers, fixed keywords and generated ids are written;
    the scene's name goes into a comment, escaped. ``rects`` defaults to the primary-ray rectangles.

    ``light_distance`` d (the export's, for viewing; None for the oracle's own renders): the light's
    intensity becomes lc * pi * d^2, so that Mitsuba's diffuse at distance d from the light equals
    the exercise's, and a comment in the file says so."""
    if rects is None:
        o, d = camera.primary_rays(scene, rules)
        rects = plane_frames(scene, o, d)
    sp = sensor_params(scene, rules)
    if light_distance is None:
        intensity = scene.light.color
        falloff = [
            "     light falls off as 1/r^2 (the exercise has neither). Planes are rectangles sized to the view. -->",
        ]
    else:
        factor = math.pi * light_distance**2
        intensity = tuple(c * factor for c in scene.light.color)
        falloff = [
            "     light falls off as 1/r^2 (the exercise has neither). Planes are rectangles sized to the view.",
            f"     For viewing, the light's intensity is the exercise's light colour times pi d^2 = {_num(factor)},",
            f"     with d = {_num(light_distance)} the median distance from the light to the points the camera sees.",
            "     At distance d Mitsuba's diffuse (dc I n.s / (pi r^2)) then equals the exercise's (dc lc n.s);",
            "     nearer points are brighter, farther ones darker. minirt's own checks use I = lc instead. -->",
        ]
    lines = [
        '<?xml version="1.0" encoding="utf-8"?>',
        f"<!-- minirt scene {_comment(scene.name)}, exported by oracles/mitsuba.py for Mitsuba {PACKAGE_VERSION}. -->",
        "<!-- Render with: mitsuba scene.xml (writes scene.exr). Not representable in Mitsuba and left out:",
        "     ambient, the (r.s)^8 specular lobe, the background colour. Diffuse is dc/pi and the point",
        *falloff,
        '<scene version="3.0.0">',
        f'    <default name="spp" value="{int(spp)}"/>',
        '    <integrator type="direct">',
        '        <integer name="emitter_samples" value="1"/>',
        '        <integer name="bsdf_samples" value="0"/>',
        "    </integrator>",
        '    <sensor type="perspective" id="camera">',
        '        <string name="fov_axis" value="x"/>',
        f'        <float name="fov" value="{_num(sp["fov"])}"/>',
        f'        <float name="near_clip" value="{_num(sp["near_clip"])}"/>',
        f'        <float name="far_clip" value="{_num(sp["far_clip"])}"/>',
        f'        <float name="principal_point_offset_x" value="{_num(sp["principal_point_offset_x"])}"/>',
        f'        <float name="principal_point_offset_y" value="{_num(sp["principal_point_offset_y"])}"/>',
        f'        <transform name="to_world"><matrix value="{_matrix(sp["to_world"])}"/></transform>',
        '        <sampler type="stratified">',
        '            <integer name="sample_count" value="$spp"/>',
        '            <boolean name="jitter" value="false"/>',
        "        </sampler>",
        '        <film type="hdrfilm">',
        f'            <integer name="width" value="{int(sp["width"])}"/>',
        f'            <integer name="height" value="{int(sp["height"])}"/>',
        '            <string name="pixel_format" value="rgb"/>',
        '            <rfilter type="box"/>',
        "        </film>",
        "    </sensor>",
        '    <emitter type="point" id="light">',
        f'        <point name="position" x="{_num(scene.light.position[0])}" y="{_num(scene.light.position[1])}" '
        f'z="{_num(scene.light.position[2])}"/>',
        f'        <rgb name="intensity" value="{_rgb(intensity)}"/>',
        "    </emitter>",
    ]
    # One BSDF per distinct material, referenced by its shapes, rather than one per shape: the same
    # parameters give the same numbers, and Mitsuba's BSDF calls dispatch over as many instances as there
    # are materials (a 10,000-ball render: 70 -> 65 s). Shapes that share a BSDF stay apart: the scene is
    # loaded with optimize=False.
    bsdfs: dict[str, str] = {}  # (diffuse, reflection), what a BSDF is made of -> its id

    def lobes(m) -> str:
        return repr((m.diffuse, m.reflection))  # repr: -0.0 and 0.0 write different files, so stay apart

    for s in scene.shapes:
        key = lobes(s.material)
        if key not in bsdfs:
            bsdfs[key] = f"bsdf{len(bsdfs)}"
            lines += _bsdf_xml(s.material, "    ", bsdfs[key])
    for k, s in enumerate(scene.shapes):
        ref = bsdfs[lobes(s.material)]
        if isinstance(s, Ball):
            cx, cy, cz = (_num(v) for v in s.center)
            lines += [
                f'    <shape type="sphere" id="shape{k}">',
                f'        <point name="center" x="{cx}" y="{cy}" z="{cz}"/>',
                f'        <float name="radius" value="{_num(s.radius)}"/>',
            ]
        else:
            lines += [
                f'    <shape type="rectangle" id="shape{k}">',
                f'        <transform name="to_world"><matrix value="{_matrix(rects[k].to_world())}"/></transform>',
            ]
        lines.append(f'        <ref id="{ref}"/>')
        lines.append("    </shape>")
    lines.append("</scene>")
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------------------------
# The oracle.


def _unsupported_terms(scene: Scene, mode: str) -> list[str]:
    mats = [s.material for s in scene.shapes]
    out = []
    if any(any(v != 0 for v in m.ambient) for m in mats):
        out.append("ambient")
    if any(any(v != 0 for v in m.specular) for m in mats):
        out.append("specular")
    if any(v != 0 for v in scene.background):
        out.append("background")
    if mode == "sensor" and scene.max_depth > 0 and any(any(v != 0 for v in m.reflection) for m in mats):
        out.append("reflection")  # the `direct` integrator does not follow delta reflections
    return out


class MitsubaOracle(Oracle):
    name: ClassVar[str] = "mitsuba"
    shades: ClassVar[bool] = True
    display_name: ClassVar[str] = "Mitsuba"
    shading_model: ClassVar[str | None] = "physical"
    float32: ClassVar[bool] = True
    # a check keeps its render and figures (1,400 bytes a pixel); a render keeps 220 and runs with 430
    # (Dr.Jit's and Mitsuba's working buffers): measured with the others (minirt.jobs.memory)
    check_kept: ClassVar[int] = 1400
    render_kept: ClassVar[int] = 220
    render_running: ClassVar[int] = 430
    export_as: ClassVar[str | None] = "mitsuba"
    export_what: ClassVar[str] = "XML scene"
    supported: ClassVar[dict[str, tuple[Any, ...]]] = {
        # A miss returns black and a hit gets no background: exactly "none"; "on-miss" stays preferred
        # (the closest of the exercise's two, equal when the background is 0).
        "background": ("on-miss", "none"),
        # Mitsuba's sphere returns the nearest root with t >= 0: from inside, the far one.
        "near_root_only": (False,),
        # sample_emitter_direction tests visibility only up to the light (maxt = dist (1 - eps)).
        "shadow_range": ("to-light",),
        # One-sided diffuse/conductor are wrapped in `twosided`: both faces shade, as if facing the ray.
        "two_sided": (True,),
        # BSDFs return 0 when the light is below the surface: max(0, n.s).
        "clamp": (True,),
        # spawn_ray offsets by Mitsuba's own error bound (si.p + n * ray_epsilon * (1 + max|p|)).
        "offset": ("error-bound",),
        # Its offsets lie along the normal ("ray" needs a numeric offset anyway).
        "offset_along": ("normal",),
        # ray_origin, pixel_sample and pixel_shift: any (custom rays are minirt.model.camera's, so they honour all
        # three; the sensor via near_clip and the principal point offsets).
        # specular_exponent: any (no specular lobe is simulated; see unsupported_terms).
    }

    def available(self) -> tuple[bool, str]:
        try:
            _load_mitsuba()
        except Exception as e:
            return False, _one_line(e)
        return True, self.version()

    def version(self) -> str:
        try:
            mi, variant = _load_mitsuba()
        except Exception as e:
            return f"mitsuba unavailable ({_one_line(e)})"
        return f"mitsuba {mi.__version__} ({variant})"

    # ---- export ------------------------------------------------------------------------------
    def options(self, precision: str = "f64", samples: int | None = None, timeout: float | None = None) -> dict:
        """--samples N: Mitsuba's own sensor with N samples per pixel (its stochastic image), not the rays."""
        opts: dict[str, Any] = {"precision": precision}
        if samples:
            opts.update(mode="sensor", spp=samples)
        return opts

    def geometry_tolerance(self, result: RenderResult, ref: RenderResult, measured: Margins) -> GeometryTolerance:
        """This oracle's recorded precision as per-pixel tolerances, each with its derivation."""
        h, w = ref.height, ref.width
        p = result.meta.get("precision") or {}
        m = measured.image(h, w)
        t_ref = np.where(ref.hit, ref.t, 0.0)
        ties = None
        eps = p["band_k"] * p["band_eps"]
        plane_abs = max([pl.get("abs_error", 0.0) for pl in result.meta.get("planes", {}).values()] or [0.0])
        # A shadow or hit decision moved by the rectangle's absolute error: relative to the smallest radius.
        band = m["margin"] < eps
        # Rays starting on a plane (t ~ 0): Mitsuba 3 has no minimum distance (Ray3f carries maxt only), and
        # whether its rectangle lies in front of the origin is decided in float32: the error of the origin's
        # signed distance from the rectangle (its normal_error, older documents: its abs_error), plus the
        # origin rounded to float32 and taken to the rectangle's local frame (a few roundings of terms <= |o|:
        # 4 u32 |o|). Balls: the relative origin margin above (band_eps) covers it.
        plane_normal = max(
            [pl.get("normal_error", pl.get("abs_error", 0.0)) for pl in result.meta.get("planes", {}).values()] or [0.0]
        )
        start_err = plane_normal + 4 * U32 * m["origin_norm"]
        starts = measured.start_band(h, w, t_min=0.0, plane_err=start_err.reshape(-1))
        # each shape's own band (oracles.mitsuba.band_scales)
        if measured.scaled is not None and p.get("band_scale"):
            band, ties = measured.per_shape_band(p, h, w)
        band = band | starts
        # A plane's t = n·(Q - o)/(n·d): the rectangle's absolute error and the float32 rounding of the ray's
        # direction (dir_err) move t by (plane_abs + t dir_err)/|n·d| -- large where the ray grazes the plane.
        inv_nd = 1.0 / m["hit_nd"]
        dir_err = p.get("dir_err", 0.0)
        t_abs = p["t_rel"] * t_ref + plane_abs + (plane_abs + dir_err * t_ref) * inv_nd
        # near a ball's silhouette the float32 discriminant is ill-conditioned: the oracle's per-pixel bound
        t_abs = t_abs + result.aux.get("t_silhouette_bound", 0.0)
        nd = np.full((h, w), p["normal_deg"])
        why = {
            "band": f"margin < each shape's own band (at most band_k*band_eps = {eps:.3g}; a ball's discriminant "
            "error against r^2 - h^2, exact in the margin): {p.get('why', '')}; or a ray starting within "
            f"normal_error + 4 u32 |o| = {plane_normal:.3g} + 4 u32 |o| of a plane (float32 decides t > 0 there)",
            "t": f"t_rel*t + plane_abs + (plane_abs + dir_err*t)/|n·d| = {p['t_rel']:.3g}*t + {plane_abs:.3g} + "
            f"({plane_abs:.3g} + {dir_err:.3g}*t)/|n·d| (float32 roots; rectangles interpolate their corners; "
            "a plane's t is conditioned by 1/|n·d|, n·d of the hit plane, inf for balls) + per pixel "
            "4 u32 |f|^2/(r sqrt(2m)) near a ball's silhouette (aux t_silhouette_bound)",
            "normal": f"{p['normal_deg']} deg (float32 normals)",
        }
        summary = {
            "band_eps": eps,
            "t_rel": p["t_rel"],
            "plane_abs": plane_abs,
            "plane_normal_error": plane_normal,
            "normal_deg": p["normal_deg"],
            "start_band_pixels": int(starts.sum()),
        }
        return GeometryTolerance(band=band, t_abs=t_abs, normal_deg=nd, why=why, summary=summary, ties=ties)

    def export(self, scene: Scene, rules: Rules, out_dir: Path, options: dict[str, Any] | None = None) -> list[Path]:
        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        path = out_dir / "scene.xml"
        spp = int((options or {}).get("spp", 1))
        d = viewing_distance(scene, rules)  # the light scaled for viewing (module docstring: falloff)
        path.write_text(scene_to_xml(scene, rules, spp=spp, light_distance=d), encoding="utf-8")
        return [path]

    # ---- render ------------------------------------------------------------------------------
    def render(self, scene: Scene, rules: Rules, options: dict[str, Any] | None = None, progress=None) -> RenderResult:
        opts = dict(options or {})
        w, h = scene.camera.width, scene.camera.height
        mode = opts.get("mode", "rays")
        try:
            t0 = time.perf_counter()
            mi, variant = _load_mitsuba()
            t_import = time.perf_counter() - t0
        except Exception as e:
            return RenderResult.failed(BACKEND, w, h, "skip", f"mitsuba unavailable: {_one_line(e)}", options=opts)
        if mode not in ("rays", "sensor"):
            return RenderResult.failed(BACKEND, w, h, "error", f"unknown mode {mode!r} (rays or sensor)")
        if mode == "sensor" and w != h:
            return RenderResult.failed(
                BACKEND, w, h, "skip",
                f"sensor mode needs a square image ({w}x{h}: the perspective sensor has square pixels)",
                options=opts,
            )  # fmt: skip
        try:
            if mode == "sensor":
                res = _SensorRender(mi, variant, scene, rules, opts).run()
            else:
                res = _RayRender(mi, variant, scene, rules, opts).run()
        except Exception as e:  # any Mitsuba exception becomes a result, never an exception
            return RenderResult.failed(BACKEND, w, h, "error", f"mitsuba failed: {_one_line(e)}", options=opts)
        res.meta["timings"]["import"] = t_import
        return res

    # ---- the sweep (minirt.sweep): what accuracy costs in time -----------------------------------
    sweep_knobs: ClassVar[dict[str, Any]] = {
        "spp": (1, 4, 16, 64, 256, 1024),
        "converged_spp": 4096,  # its own converged answer (see ``sweep``)
    }
    SWEEP_SEED = 0
    SWEEP_CONVERGED_SEED = 1  # a different seed: the converged render must not share the rows' samples

    def sweep(self, scene: Scene, rules: Rules, knobs: dict[str, Any]) -> list[Series]:
        """One knob, spp: 1, 4, ..., 1024 samples per pixel of Mitsuba's own sensor (``independent``
        sampler, box filter), against Mitsuba's own 4096 spp (another seed): its shading differs from the
        exercise by design (no ambient, 1/(pi r^2) falloff), so only it can be its own limit. Its colours
        are radiance (~1e-3 here): errors are measured after matching exposure ("color_exposure")."""
        k = self.turned(knobs)
        n = k["converged_spp"]
        seed = self.SWEEP_CONVERGED_SEED
        converged = Truth(f"mitsuba/{n}spp", self.name, {"mode": "sensor", "spp": n, "seed": seed},
                          describe={"mode": "sensor", "spp": n, "seed": seed})  # fmt: skip
        spp = tuple(
            Setting(s, s, {"mode": "sensor", "spp": s, "seed": self.SWEEP_SEED}, f"Mitsuba at {s} spp",
                    f"mitsuba {s} spp")
            for s in k["spp"]
        )  # fmt: skip
        return [
            Series(self.name, "spp", spp, self.adapt(rules), converged, "color_exposure", metric="rmse",
                   cost="samples per pixel", theory="spp^-0.5 (independent sampler)",
                   knobs={"mitsuba_spp": k["spp"], "converged_mitsuba_spp": n})
        ]  # fmt: skip


class _Base:
    def __init__(self, mi, variant: str, scene: Scene, rules: Rules, opts: dict[str, Any]):
        self.mi, self.variant, self.scene, self.rules, self.opts = mi, variant, scene, rules, opts
        self.jit = not variant.startswith("scalar")
        self.passes: list[str] = []
        self.timings: dict[str, float] = {}

    def load(self, rects: dict[int, PlaneRect], spp: int = 1) -> Any:
        t0 = time.perf_counter()
        xml = scene_to_xml(self.scene, self.rules, rects, spp=spp)
        self.plane_abs = {k: r.abs_error() for k, r in rects.items()}  # the rectangles' float32 error
        self.self_hit_segments = 0  # shadow segments that hit their own rectangle first (this render)
        # optimize=False: Mitsuba merges meshes that share a BSDF (two rectangles of one material) into
        # one shape with an empty id, and each plane's shape id would be lost.
        ms = self.mi.load_string(xml, optimize=False)
        # registry id (or, in scalar variants, the position in scene.shapes()) -> index in the scene file
        lut: dict[int, int] = {}
        mshapes = ms.shapes()
        if self.jit:
            reg = np.asarray(self.mi.UInt32(self._dr().reinterpret_array(self.mi.UInt32, ms.shapes_dr())))
        else:
            reg = np.arange(len(mshapes))
        for r, s in zip(reg, mshapes, strict=True):
            lut[int(r)] = int(s.id().removeprefix("shape"))
        self.lut = lut
        self.timings["setup"] = self.timings.get("setup", 0.0) + time.perf_counter() - t0
        return ms

    def _dr(self):
        import drjit as dr

        return dr

    def map_ids(self, reg: np.ndarray, hit: np.ndarray) -> np.ndarray:
        out = np.full(reg.shape, -1, dtype=np.int32)
        for r, k in self.lut.items():
            out[(reg == r) & hit] = k
        return out

    def meta(self, mode: str, extra: dict[str, Any]) -> dict[str, Any]:
        sc = self.scene
        origins = camera.primary_rays(sc, self.rules)[0]
        eps = shape_eps(sc, origins)  # one pass over the origins per ball, for band_eps and the scales
        scales = band_scales(sc, origins, eps)
        return {
            "backend": BACKEND,
            "version": f"mitsuba {self.mi.__version__} ({self.variant})",
            "scene": sc.name,
            "scene_sha256": sc.digest,
            "settings": {"variant": self.variant, "mode": mode, "width": sc.camera.width,
                         "height": sc.camera.height, "max_depth": sc.max_depth},
            "options": dict(self.opts),
            "rules": self.rules.as_dict(),
            "passes": self.passes,
            "timings": self.timings,
            "emitter": {"type": "point", "intensity": list(sc.light.color), "position": list(sc.light.position)},
            "unsupported_terms": _unsupported_terms(sc, mode),
            "precision": {
                "t_rel": T_REL,
                "dir_err": DIR_ERR,
                "normal_deg": NORMAL_DEG,
                "band_eps": max(eps, default=U32),
                "band_k": BAND_K,
                "band_scale": scales["scale"],
                "band_inside_scale": scales["inside"],
                "band_origin_scale": scales["origin"],
                "band_tie_scale": scales["tie"],
                "why": (
                    "float32 sphere roots: relative t error ~8 u32 |f|/t away from silhouettes (t_rel = 64 u32); "
                    "at a silhouette the discriminant r^2-h^2 has absolute error ~4 u32 |f|^2, so hit/miss flips "
                    "for band margin m < K eps with eps = u32 max|f|^2/r^2 (per shape: band_scale, band_inside_scale, "
                    "band_origin_scale, band_tie_scale) and t errs by ~u32 |f|^2/(r t sqrt(2m)); "
                    "rectangles (2-triangle meshes) add an absolute error 8 u32 (|c|+|S|) per plane (meta.planes)"
                ),
            },
            **extra,
        }  # fmt: skip


class _RayRender(_Base):
    """The harness's rays through Mitsuba's intersector and a loop of stock shading calls."""

    def run(self) -> RenderResult:
        sc, rules = self.scene, self.rules
        w, h = sc.camera.width, sc.camera.height
        o64, d64 = camera.primary_rays(sc, rules)
        # Mitsuba sees the rays in float32: every float64 check below uses the same rounded rays.
        o32, d32 = o64.astype(np.float32).astype(np.float64), d64.astype(np.float32).astype(np.float64)
        rects = plane_frames(sc, o32, d32)
        mats = [s.material for s in sc.shapes]
        lit = any(v != 0 for v in sc.light.color) and any(any(v != 0 for v in m.diffuse) for m in mats)
        reflective = [k for k, m in enumerate(mats) if any(v != 0 for v in m.reflection)]
        depth = sc.max_depth if reflective else 0
        resizes = 0
        t_render = 0.0
        while True:
            ms = self.load(rects)
            self.passes = ["intersect(primary)"]
            t0 = time.perf_counter()
            levels = self.trace(ms, o32, d32, lit, reflective, depth)
            t_render += time.perf_counter() - t0
            rendered = {f"shape{k}": r_.describe() for k, r_ in rects.items()}  # before coverage grows them
            grew = self.check_coverage(rects, levels)
            if not grew or resizes >= _MAX_RESIZE:
                break
            resizes += 1
        self.timings["render"] = t_render
        lvl0 = levels[0]
        geom = geometry_from_flat(w, h, lvl0["sid"], lvl0["t"], lvl0["p"], lvl0["n"])
        # back to front: c = local + kr * c_child (Mitsuba units) and the same in exercise units
        child = child_x = None
        for lvl in reversed(levels):
            c, cx = lvl["local"].copy(), lvl["local_x"].copy()
            lvl["refl"] = np.zeros_like(c)
            lvl["refl_x"] = np.zeros_like(c)
            if child is not None:
                lvl["refl"][lvl["child_idx"]] = lvl["kr"][lvl["child_idx"]] * child
                lvl["refl_x"][lvl["child_idx"]] = lvl["kr"][lvl["child_idx"]] * child_x
                c, cx = c + lvl["refl"], cx + lvl["refl_x"]
            child, child_x = c, cx
        color = child.reshape(h, w, 3)
        terms = {"diffuse": lvl0["local"].reshape(h, w, 3), "reflection": lvl0["refl"].reshape(h, w, 3)}
        r = np.where(geom["hit"], lvl0["dist"].reshape(h, w), 0.0)
        aux = {
            "t_silhouette_bound": silhouette_t_bound(sc, o32, d32, geom["shape_id"].ravel()).reshape(h, w),
            "light_distance": r,
            "diffuse_to_exercise": math.pi * r * r,
            "diffuse_exercise": lvl0["local_x"].reshape(h, w, 3),
            "reflection_exercise": lvl0["refl_x"].reshape(h, w, 3),
        }
        extra = {
            "planes": rendered,  # the rectangles this render used
            "plane_resizes": resizes,
            # False: the rectangles still missed points a traced ray could hit after _MAX_RESIZE growths
            "plane_coverage_complete": not grew,
            # shadow segments whose first hit was their own rectangle, restarted past its float32 slab
            "shadow_self_hits": self.self_hit_segments,
            "image8_shows": "diffuse + reflection only, x pi r^2",
            "parameters": {"reflection_depth": depth, "shading": "diffuse" if lit else "none",
                           "reflective_shapes": reflective},
            "aux": {
                "t_silhouette_bound": "the margin-dependent part of the t error bound on balls (silhouette_t_bound)",
                "light_distance": "Mitsuba's emitter distance r at each primary hit (0 on a miss)",
                "diffuse_to_exercise": "pi r^2: terms.diffuse * pi r^2 = n.s dc lc (emitter.intensity = lc, so "
                "terms.diffuse * pi r^2 / intensity = n.s dc)",
                "diffuse_exercise": "terms.diffuse * pi r^2: the exercise's diffuse term",
                "reflection_exercise": "terms.reflection with the same correction applied at every bounce",
            },
        }  # fmt: skip
        image8 = to8(aux["diffuse_exercise"] + aux["reflection_exercise"])  # display only: see the docstring
        return RenderResult(
            backend=BACKEND, width=w, height=h, color=color, terms=terms, aux=aux, image8=image8,
            meta=self.meta("rays", extra), **geom,
        )  # fmt: skip

    # -- coverage of the rectangles -------------------------------------------------------------
    def check_coverage(self, rects: dict[int, PlaneRect], levels: list[dict[str, Any]]) -> bool:
        """Grow rectangles to every plane point a traced ray could have hit; True if any grew."""
        light = np.asarray(self.scene.light.position, dtype=np.float64)
        grew = False
        for k, r in rects.items():
            for lvl in levels:
                o, d, t_mi = lvl["o"], lvl["d"], lvl["t"]
                t = plane_hits(r, o, d)
                # the infinite plane would be the nearest hit, but Mitsuba reported nothing that near
                miss = np.isfinite(t) & (lvl["sid"] != k) & (t < t_mi * (1 - 1e-4))
                p = o[miss] + t[miss, None] * d[miss]
                if len(p) and np.any(r.outside(p)):
                    grew |= r.include(p)
                if lvl.get("shadow") is not None:
                    so = lvl["shadow"]
                    sd = light - so
                    ts = plane_hits(r, so, sd)  # segment parameter in (0, 1) crosses the plane
                    cross = ts < 1
                    p = so[cross] + ts[cross, None] * sd[cross]
                    if len(p) and np.any(r.outside(p)):
                        grew |= r.include(p)
        return grew

    # -- one batch of rays per level ------------------------------------------------------------
    def trace(self, ms, o, d, lit: bool, reflective: list[int], depth: int) -> list[dict[str, Any]]:
        levels = []
        idx = None
        for level in range(depth + 1):
            if level > 0:
                self.passes.append(f"intersect(reflection {level})")
            lvl = self.shade(ms, o, d, lit, reflective if level < depth else [], level)
            lvl["parent"] = idx
            levels.append(lvl)
            if level < depth:
                spawn = lvl.get("spawn")
                if spawn is None or not np.any(spawn):
                    break
                ci = np.nonzero(spawn)[0]
                lvl["child_idx"] = ci
                o, d = lvl["next_o"][ci], lvl["next_d"][ci]
                idx = ci
        return levels

    def shade(self, ms, o, d, lit: bool, reflective: list[int], level: int) -> dict[str, Any]:
        if self.jit:
            return self._shade_batch(ms, o, d, lit, reflective, level)
        parts = [self._shade_batch(ms, o[i : i + 1], d[i : i + 1], lit, reflective, level) for i in range(len(o))]
        out: dict[str, Any] = {}
        for key in parts[0] if parts else []:
            vals = [p[key] for p in parts]
            out[key] = None if vals[0] is None else np.concatenate(vals)
        return out

    def _np(self, x) -> np.ndarray:
        return np.atleast_1d(np.asarray(x, dtype=np.float64))

    def _np3(self, v) -> np.ndarray:
        return np.stack([self._np(v[i]) for i in range(3)], axis=1)

    def _f32(self, a: np.ndarray) -> Any:
        """Host values as Mitsuba's float: the one value of a one-ray batch in scalar mode, else an array
        at a 64-byte boundary (minirt.jit.arrays: so the same kernels are not compiled again)."""
        return float(a[0]) if not self.jit else self.mi.Float(aligned(a, np.float32))

    def _ray(self, o: np.ndarray, d: np.ndarray) -> Any:
        """Mitsuba rays from (N, 3) origins and directions."""
        f32, mi = self._f32, self.mi
        return mi.Ray3f(
            o=mi.Point3f(*(f32(o[:, i]) for i in range(3))), d=mi.Vector3f(*(f32(d[:, i]) for i in range(3)))
        )

    def _shade_batch(self, ms, o, d, lit: bool, reflective: list[int], level: int) -> dict[str, Any]:
        mi = self.mi
        n = len(o)
        scalar = not self.jit
        ray = self._ray(o, d)
        si = ms.ray_intersect(ray)
        valid = si.is_valid()
        hit, sid = self._hits(ms, si, n)
        out: dict[str, Any] = {
            "o": o, "d": d, "sid": sid,
            "t": np.where(hit, self._np(si.t), np.inf),
            "p": np.where(hit[:, None], self._np3(si.p), 0.0),
            "n": np.where(hit[:, None], self._np3(si.n), 0.0),
            "local": np.zeros((n, 3)), "local_x": np.zeros((n, 3)), "dist": np.zeros(n),
            "kr": np.zeros((n, 3)), "shadow": None,
        }  # fmt: skip
        if scalar and not hit[0]:
            return out  # scalar variants: si.bsdf() of a miss is a null pointer (eval would crash)
        if lit:
            if f"emitter+visibility(level {level})" not in self.passes:
                self.passes += [f"emitter+visibility(level {level})", f"bsdf.eval(level {level})"]
            ctx = mi.BSDFContext()
            planes = [k for k, sh in enumerate(self.scene.shapes) if isinstance(sh, Plane)]
            # With planes, the visibility test is Mitsuba's own ray_intersect on the shadow segment
            # (spawn_ray_to: Mitsuba's offsets, stops short of the light), except that a plane's hit on
            # itself does not count: an infinite plane never shadows its own points, but the
            # rectangle standing in for it can, through its float32 corners (abs_error in meta planes;
            # a fuzzed scene's 77,000-unit rectangle shadowed 458 of its own pixels).
            ds, em_w = ms.sample_emitter_direction(si, mi.Point2f(0.5, 0.5), not planes, valid)
            bsdf = si.bsdf(ray)
            f = bsdf.eval(ctx, si, si.to_local(ds.d), valid)
            local = self._np3(f * em_w)
            if planes:
                s2 = ms.ray_intersect(si.spawn_ray_to(ds.p))
                hit2, sid2 = self._hits(ms, s2, n, hit)
                own = np.isin(sid, planes) & (sid2 == sid)

                blocked = hit2 & ~own
                if own.any():  # past the rectangle's hit on itself, the rest of the segment still counts
                    blocked |= own & self._past_own_plane(ms, si, ds, sid, own, n, hit)

                local = np.where(blocked[:, None], 0.0, local)
            dist = self._np(ds.dist)
            local = np.where(hit[:, None], local, 0.0)
            out["local"] = local
            out["dist"] = np.where(hit, dist, 0.0)
            # intensity I = lc, so local * pi r^2 = dc lc max(0, n.s): the exercise's diffuse term
            out["local_x"] = np.where(hit[:, None], local * (math.pi * dist * dist)[:, None], 0.0)
            out["shadow"] = out["p"][hit]  # shadow segments start (about) here; coverage check only
        if reflective:
            self.passes.append(f"conductor.sample(level {level})")
            spawn = np.zeros(n, dtype=bool)
            next_o, next_d = np.zeros((n, 3)), np.zeros((n, 3))
            ctx = mi.BSDFContext()
            # One conductor per reflection colour, sampled for every ray that hit a shape of that colour:
            # shapes with the same colour have the same BSDF, and a lane's sample depends on its own ray
            # alone, so the same numbers as a call per shape -- whose masked batch calls (kernels, read-backs)
            # made a 1,024-ball check at 128x128 take 9 minutes in this loop.
            by_colour: dict[tuple[float, ...], list[int]] = {}
            for k in reflective:
                by_colour.setdefault(tuple(self.scene.shapes[k].material.reflection), []).append(k)
            for kr, shapes in by_colour.items():
                mask_np = np.isin(sid, shapes)
                if not mask_np.any():
                    continue
                cond = self.conductor(kr)
                mask = mi.Bool(bool(mask_np[0])) if scalar else mi.Bool(mask_np)
                bs, weight = cond.sample(ctx, si, 0.5, mi.Point2f(0.5, 0.5), mask)
                nray = si.spawn_ray(si.to_world(bs.wo))
                ok = mask_np & self._np(mask & (bs.pdf > 0)).astype(bool)
                out["kr"][ok] = self._np3(weight)[ok]
                next_o[ok], next_d[ok] = self._np3(nray.o)[ok], self._np3(nray.d)[ok]
                spawn |= ok & np.any(out["kr"] != 0, axis=1)
            out.update(spawn=spawn, next_o=next_o, next_d=next_d)
        return out

    def _past_own_plane(self, ms, si, ds, sid, own, n: int, hit) -> np.ndarray:
        """Whether the shadow segments ``own`` (whose first hit was the rectangle of the plane their point
        lies on) are blocked beyond that rectangle's float32 slab.

        The rectangle lies within abs_error of the plane (meta planes), so a segment leaving a point on it
        in direction s is within that slab for 2 abs_error / |n·s| of its length: every hit on the
        rectangle there is a self-hit. Restarting at the self-hit (Mitsuba's spawn_ray_to, an offset of
        ~1e-4 at these scales) lands inside the slab again and again on a huge rectangle (a fuzzed scene:
        abs_error 2.7e-3, 24 shadows lost behind another plane); so the segment restarts past the slab. An
        occluder within that stretch is within the oracle's own position error of the point (the harness
        does not judge those: shadow_margin)."""
        p, sd, seg = self._np3(si.p), self._np3(ds.d), self._np(ds.dist)
        skip = np.zeros(n)
        for k, err in self.plane_abs.items():
            on = own & (sid == k)
            if on.any():
                nd = np.abs(sd[on] @ np.asarray(self.scene.shapes[k].normal))
                skip[on] = 2 * err / np.maximum(nd, 1e-12)
        go = own & (skip < seg)
        self.self_hit_segments += int(own.sum())
        o2 = p + skip[:, None] * sd
        maxt = np.where(go, (seg - skip) * (1 - 1e-4), 0.0)  # stops short of the light, as spawn_ray_to does

        ray = self._ray(o2, sd)
        ray.maxt = self._f32(maxt)
        hit3, sid3 = self._hits(ms, ms.ray_intersect(ray), n, hit)
        return go & hit3 & (sid3 != sid)

    def _hits(self, ms, si, n: int, among: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Which of n rays hit (within ``among``), and the scene index of the shape each hit."""
        mi, dr = self.mi, self._dr()
        hit = self._np(si.is_valid()).astype(bool)
        if among is not None:
            hit = hit & among
        reg = self._np(dr.reinterpret_array(mi.UInt32, si.shape) if self.jit else 0).astype(np.int64)
        if not self.jit:
            reg = np.array([self._scalar_index(ms, si) if hit[0] else -1])
        return hit, self.map_ids(np.broadcast_to(reg, (n,)), hit)

    def _scalar_index(self, ms, si) -> int:
        for i, s in enumerate(ms.shapes()):
            if s == si.shape:
                return i
        return -1

    def conductor(self, kr: tuple[float, ...]):
        """A perfect mirror (Mitsuba's ``conductor``, two-sided) of reflection colour kr."""
        cache = self.__dict__.setdefault("_conductors", {})
        if kr not in cache:
            cache[kr] = self.mi.load_dict(
                {
                    "type": "twosided",
                    "b": {"type": "conductor", "specular_reflectance": {"type": "rgb", "value": list(kr)}},
                }
            )
        return cache[kr]


class _SensorRender(_Base):
    """Mitsuba's own perspective sensor and integrators (aov + direct; moment for spp > 1)."""

    def run(self) -> RenderResult:
        mi = self.mi
        sc, rules = self.scene, self.rules
        w, h = sc.camera.width, sc.camera.height
        spp = int(self.opts.get("spp", 1))
        seed = int(self.opts.get("seed", 0))
        rects = sensor_frames(sc, rules)
        ms = self.load(rects, spp=spp)
        t0 = time.perf_counter()
        sensor = ms.sensors()[0]  # the exported sensor: stratified, no jitter, box filter
        aov = {"type": "aov", "aovs": "dd.y:depth,pp:position,nn:geo_normal,si:shape_index",
               "direct": {"type": "direct", "emitter_samples": 1, "bsdf_samples": 0}}  # fmt: skip
        if spp > 1:
            # jittered: the same sensor with the `independent` sampler; `moment` adds second moments
            sensor = mi.load_dict(self._sensor_dict("independent", spp, seed))
            integ = mi.load_dict({"type": "moment", "nested": aov})
            self.passes = ["sensor(independent)", "aov", "direct", "moment"]
        else:
            integ = mi.load_dict(aov)
            self.passes = ["sensor(stratified, no jitter)", "aov", "direct"]
        self.timings["setup"] = self.timings.get("setup", 0.0) + time.perf_counter() - t0
        t0 = time.perf_counter()
        mi.render(ms, sensor=sensor, integrator=integ, spp=spp, seed=seed)
        bitmap = sensor.film().bitmap()  # channels by name (the developed tensor drops some)
        names = [bitmap.struct_()[i].name for i in range(bitmap.channel_count())]
        img = np.array(bitmap, copy=True).astype(np.float64).reshape(h, w, len(names))
        self.timings["render"] = time.perf_counter() - t0

        def ch(*keys: str) -> np.ndarray:
            return np.stack([img[..., names.index(k)] for k in keys], axis=-1)

        meta_extra: dict[str, Any] = {"channels": names, "spp": spp, "seed": seed, "ray_epsilon": RAY_EPSILON,
                                      "planes": {f"shape{k}": r.describe() for k, r in rects.items()},
                                      "sensor": {k: (v.tolist() if isinstance(v, np.ndarray) else v)
                                                 for k, v in sensor_params(sc, rules).items()}}  # fmt: skip
        aux: dict[str, np.ndarray] = {}
        geom: dict[str, Any] = {}
        if spp == 1:
            color = ch("direct.R", "direct.G", "direct.B")
            depth, shp = ch("dd.y.T")[..., 0], ch("si.I")[..., 0]
            pos, nrm = ch("pp.X", "pp.Y", "pp.Z"), ch("nn.X", "nn.Y", "nn.Z")
            hit = depth > 0  # depth is 0 on a miss; a hit has t > 0
            sid = self.map_ids(np.rint(shp).astype(np.int64), hit)
            geom = geometry_from_flat(w, h, sid.reshape(-1), depth.reshape(-1), pos.reshape(-1, 3), nrm.reshape(-1, 3))
        else:
            rgb = ("direct.R", "direct.G", "direct.B")
            color = ch(*(f"nested.{c}" for c in rgb))
            second = ch(*(f"m2_nested.{c}" for c in rgb))
            aux["variance"] = np.maximum(second - color * color, 0.0)
            aux["coverage"] = (ch("nested.dd.y.T")[..., 0] > 0).astype(np.float64)
            meta_extra["variance"] = "per-sample variance of the colour (divide by spp for the mean's variance)"
        terms = {"diffuse": color.copy()}
        return RenderResult(
            backend=BACKEND, width=w, height=h, color=color, terms=terms, aux=aux,
            meta=self.meta("sensor", meta_extra), **geom,
        )  # fmt: skip

    def _sensor_dict(self, sampler_type: str, spp: int, seed: int) -> dict[str, Any]:
        mi = self.mi
        sp = sensor_params(self.scene, self.rules, spp)
        return {
            "type": "perspective",
            "fov_axis": "x",
            "fov": sp["fov"],
            "near_clip": sp["near_clip"],
            "far_clip": sp["far_clip"],
            "principal_point_offset_x": sp["principal_point_offset_x"],
            "principal_point_offset_y": sp["principal_point_offset_y"],
            "to_world": mi.ScalarTransform4f(sp["to_world"].tolist()),
            "sampler": {"type": sampler_type, "sample_count": spp, "seed": seed},
            "film": {"type": "hdrfilm", "width": sp["width"], "height": sp["height"], "pixel_format": "rgb",
                     "rfilter": {"type": "box"}},
        }  # fmt: skip
