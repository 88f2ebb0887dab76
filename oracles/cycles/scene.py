"""The scene as a Cycles job: the exercise's scene in Blender's frame, planes as quads, the camera and
the light, written as the JSON that minirt/oracles/cycles/inside_blender.py builds in Blender.

Pure NumPy and standard library: nothing here imports ``bpy``. The conventions it bridges are listed in
the package's docstring (minirt.oracles.cycles); each function says which one it implements.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from minirt.model import camera
from minirt.model.rules import Rules
from minirt.model.scene import Ball, Plane, Scene
from minirt.oracles.base import median_light_distance, plane_frame

U32 = 2.0**-24  # float32 unit round-off

# Blender's frame: the exercise's (x, y, z) is Blender's (x, y, -z). The exercise's frame is left-handed
# (x right, y up, the camera looking along +z); Blender's is right-handed and its camera looks along its
# own -z with +x to the right. Negating z is exact in floating point, and the camera needs no rotation.
MIRROR = np.array([1.0, 1.0, -1.0])

# The sample-0 ray's sub-pixel position. Cycles' first sample of a pixel asks its pixel-filter table for
# the filter's centre, u = 0.5 (init_from_camera.h: integrate_camera_sample), and the table answers
# 0.5 + FILTER_CENTRE_BIAS: the box filter's table (film.cpp filter_table, util_cdf_invert with
# make_symmetric, 1024 entries; Blender passes width 1 for BOX whatever its filter_size) is symmetric
# about entry 511 (0.5), while lookup_table_read reads u = 0.5 at 511.5, halfway to entry 512 =
# 0.5 (1 + y_1), y_1 the inverted CDF at 1/511 = 1/511 (the box's CDF is linear). So the sample lies
# y_1 / 4 = 1/2044 pixel right of and above the centre. Measured on a plane (64 x 64, 4,096 rays):
# 4.8795e-4 +- 4e-8 pixels in both axes, against 1/2044 = 4.892e-4 (the 1.3e-6 left is the float32
# raster-to-camera transform). The camera's shift puts the sample ray where the rules want it.
FILTER_CENTRE_BIAS = 1.0 / 2044.0

# Beyond every hit the harness asks about: Cycles drops hits past clip_end (counted along the view axis).
CLIP_END = 1e30
# Blender's smallest clip_start; with rule ray_origin = "camera" the ray starts this far along the view
# axis, in front of the camera (a hit nearer than that is lost: the start band covers it).
CLIP_START_MIN = 1e-6

# Reflected rays are traced (here, in float64, to size the planes) on a grid of at most this many rays a
# side: only the colour image, which no check compares pixel by pixel, depends on them.
REFLECTION_GRID = 128
# How far (in scene sizes) a reflected ray's hit on a plane still grows that plane's quad. Beyond it the
# reflection sees the world instead of the plane. The quad's size sets its float32 error for every ray
# (abs_error), so a grazing reflection must not make it a million units wide.
REFLECTION_REACH = 64.0
PAD = 1e-3  # the quads' margin, relative to their size (and at least this much of the scene's size)


def to_blender(v) -> list[float]:
    """A point or direction of the exercise's frame in Blender's (see MIRROR)."""
    return [float(x) for x in np.asarray(v, dtype=np.float64) * MIRROR]


def scene_size(scene: Scene) -> float:
    """The scene's size: the camera distance, |C| + r of every ball, |distance| of every plane, at least 1."""
    sizes = [1.0, scene.camera.distance, float(np.linalg.norm(scene.light.position))]
    for s in scene.shapes:
        if isinstance(s, Ball):
            sizes.append(float(np.linalg.norm(s.center)) + s.radius)
        else:
            sizes.append(abs(s.distance))
    return max(sizes)


# ---------------------------------------------------------------------------------------------
# Planes as quads


@dataclass
class Quad:
    """The quad standing in for one plane: its frame and the box (in plane coordinates) it must cover."""

    plane: Plane
    n: np.ndarray = field(init=False)
    q: np.ndarray = field(init=False)
    t1: np.ndarray = field(init=False)
    t2: np.ndarray = field(init=False)
    lo: np.ndarray = field(init=False)
    hi: np.ndarray = field(init=False)

    def __post_init__(self):
        self.n = np.asarray(self.plane.normal, dtype=np.float64)
        self.q = np.asarray(self.plane.point, dtype=np.float64)
        self.t1, self.t2 = plane_frame(self.n)
        self.lo, self.hi = np.full(2, np.inf), np.full(2, -np.inf)

    def include(self, p: np.ndarray) -> None:
        """Grow the box to hold the points p (N, 3) projected onto the plane (non-finite rows ignored)."""
        p = np.atleast_2d(np.asarray(p, dtype=np.float64))
        p = p[np.all(np.isfinite(p), axis=1)]
        if len(p):
            r = p - self.q
            uv = np.stack([r @ self.t1, r @ self.t2], axis=1)
            self.lo, self.hi = np.minimum(self.lo, uv.min(axis=0)), np.maximum(self.hi, uv.max(axis=0))

    def hits(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        """t of each ray with the infinite plane (float64), inf when parallel or behind."""
        nd = d @ self.n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((self.q - o) @ self.n) / nd
        return np.where(np.isfinite(t) & (t > 0), t, np.inf)

    def half(self, size: float) -> np.ndarray:
        h = (self.hi - self.lo) / 2
        return h * (1 + PAD) + PAD * size

    def corners(self, size: float) -> np.ndarray:
        """The four corners (exercise frame), counter-clockwise about n."""
        c = self.q + ((self.lo + self.hi) / 2) @ np.stack([self.t1, self.t2])
        su, sv = self.half(size)
        u, v = su * self.t1, sv * self.t2
        return np.stack([c - u - v, c + u - v, c + u + v, c - u + v])

    def describe(self, size: float) -> dict[str, Any]:
        """The quad's centre, half-sizes and float32 error bounds (what meta["planes"] records).

        abs_error: Cycles' hit point on a triangle is interpolated from its corners (float32 coordinates of
        magnitude up to |c| + |S|), a few roundings of that: 8 u32 (|c| + |S|). normal_error: the error of a
        point's signed distance from the quad, which decides whether a ray starting on the plane meets it:
        the corners' float32 rounding moves the quad's plane by u32 |corner| <= u32 (|c| + |S|), and the
        intersector's own arithmetic adds a few roundings of that: the same 8 u32 (|c| + |S|)."""
        k = self.corners(size)
        c = k.mean(axis=0)
        reach = float(np.max(np.linalg.norm(k, axis=1)))
        return {
            "centre": c.tolist(),
            "half_size": self.half(size).tolist(),
            "abs_error": 8 * U32 * reach,
            "normal_error": 8 * U32 * reach,
        }


def pixel_corner_rays(scene: Scene, rules: Rules) -> tuple[np.ndarray, np.ndarray]:
    """The rays through the four corners of every pixel's square (rule pixel_shift included): every ray
    Cycles casts through a pixel -- its one sample or its box filter's -- lies between them."""
    n = scene.camera.width * scene.camera.height
    os_, ds = [], []
    for u, v in ((0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)):
        o, d = camera.rays_through(scene, rules, np.full(n, u), np.full(n, v))
        os_.append(o)
        ds.append(d)
    return np.concatenate(os_), np.concatenate(ds)


def first_hits(scene: Scene, o: np.ndarray, d: np.ndarray, t_min: np.ndarray | float = 0.0):
    """(t, shape index) of each ray's first hit beyond t_min, analytic float64 (inf, -1 where none)."""
    best = np.full(len(o), np.inf)
    sid = np.full(len(o), -1)
    for k, s in enumerate(scene.shapes):
        if isinstance(s, Ball):
            f = o - np.asarray(s.center, dtype=np.float64)
            b = np.einsum("ij,ij->i", f, d)
            disc = b * b - (np.einsum("ij,ij->i", f, f) - s.radius**2)
            root = np.sqrt(np.maximum(disc, 0.0))
            t = np.where(-b - root > t_min, -b - root, -b + root)
            t = np.where((disc >= 0) & (t > t_min), t, np.inf)
        else:
            nn = np.asarray(s.normal, dtype=np.float64)
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (s.distance - o @ nn) / (d @ nn)
            t = np.where(np.isfinite(t) & (t > t_min), t, np.inf)
        nearer = t < best
        best, sid = np.where(nearer, t, best), np.where(nearer, k, sid)
    return best, sid


def _grid_rays(scene: Scene, rules: Rules, side: int) -> tuple[np.ndarray, np.ndarray]:
    w, h = scene.camera.width, scene.camera.height
    small = scene.with_overrides(width=min(w, side), height=min(h, side))
    return camera.primary_rays(small, rules)


def quads(scene: Scene, rules: Rules) -> dict[int, Quad]:
    """Each plane's quad: the smallest box (in the plane's frame) covering every point a ray Cycles casts
    can meet on the plane -- as Mitsuba's rectangles are sized (oracles/mitsuba), with the same reasons:

    - the primary rays: the hits, with the infinite plane, of the rays through the corners of every pixel
      square, and of the rules' own ray of every pixel (Cycles' one sample), stretched along a grazing ray
      by its float32 direction's reach. (A pixel straddling the plane's horizon holds rays meeting it
      arbitrarily far: the samples of a many-sample render there may run past the quad. The statistical
      comparison leaves such edge pixels out.);
    - the shadow segments from a primary hit P to the light L: where one crosses plane B it does so at a
      point of B between the projections of P and L onto B (projection is affine and the crossing a
      convex combination of P and L), so B's box holds the projections of the light and of every hit:
      the other planes' hits above, and each ball whole (its centre +- r along B's frame);
    - the camera's projection, as Mitsuba's;
    - reflections (only the colour image depends on them): rays reflected off mirror shapes, followed up
      to max_depth bounces on a grid of at most REFLECTION_GRID^2 primary rays; their hits on a plane
      within REFLECTION_REACH scene sizes grow it, with their projections onto the other planes (their
      shadow segments).

    The box is padded by PAD of its size and of the scene's. A larger quad costs precision on every ray
    (its float32 corners: abs_error in describe), hence the smallest that covers."""
    planes = {k: Quad(s) for k, s in enumerate(scene.shapes) if isinstance(s, Plane)}
    if not planes:
        return planes
    size = scene_size(scene)
    o, d = pixel_corner_rays(scene, rules)
    o1, d1 = camera.primary_rays(scene, rules)
    hits = {}
    for k, qd in planes.items():
        t = qd.hits(o, d)
        hits[k] = o + np.where(np.isfinite(t), t, np.nan)[:, None] * d
        # The rules' own rays, Cycles' one sample each: a pixel whose upper corners pass above a plane's
        # horizon holds rays that meet the plane beyond every corner's hit (fuzz contact_3_14: the
        # sample at t = 161, the farthest corner hit ~100). A grazing ray's hit also moves along it by
        # t DIR_ERR / |n·d| with Cycles' float32 direction (DIR_ERR <= 32 u32, minirt.oracles.cycles.
        # precision): include it that far, 4 times over (Mitsuba's rectangles do the same).
        t1 = qd.hits(o1, d1)
        with np.errstate(divide="ignore", invalid="ignore"):
            spread = 4 * 32 * U32 / np.abs(d1 @ qd.n)
        far = np.where(np.isfinite(t1), t1 * (1 + np.where(spread < 1, spread, 0.0)), np.nan)
        hits[k] = np.concatenate([hits[k], o1 + far[:, None] * d1])
    extra = [np.asarray(scene.light.position, dtype=np.float64), np.asarray(scene.camera.position, dtype=np.float64)]
    for s in scene.shapes:
        if isinstance(s, Ball):
            extra += [np.asarray(s.center, dtype=np.float64) + s.radius * e for e in np.eye(3)]
            extra += [np.asarray(s.center, dtype=np.float64) - s.radius * e for e in np.eye(3)]
    for qd in planes.values():
        qd.include(np.array(extra))
        for p in hits.values():
            qd.include(p)
    for p in _reflection_points(scene, rules, size):
        for qd in planes.values():
            qd.include(p)
    return planes


def _reflection_points(scene: Scene, rules: Rules, size: float) -> list[np.ndarray]:
    """The points on planes that reflected rays meet (see quads)."""
    mirrors = [k for k, s in enumerate(scene.shapes) if any(v != 0 for v in s.material.reflection)]
    if not mirrors or scene.max_depth < 1 or not any(isinstance(s, Plane) for s in scene.shapes):
        return []
    o, d = _grid_rays(scene, rules, REFLECTION_GRID)
    t, sid = first_hits(scene, o, d)
    out = []
    reach = REFLECTION_REACH * size
    for _ in range(scene.max_depth):
        go = np.isfinite(t) & np.isin(sid, mirrors)
        if not go.any():
            break
        p = o[go] + t[go, None] * d[go]
        n = np.zeros_like(p)
        for k in np.unique(sid[go]):
            on = sid[go] == k
            s = scene.shapes[k]
            if isinstance(s, Ball):
                n[on] = (p[on] - np.asarray(s.center)) / s.radius
            else:
                n[on] = np.asarray(s.normal)
        d2 = d[go] - 2 * np.einsum("ij,ij->i", d[go], n)[:, None] * n
        o, d = p, d2
        t, sid = first_hits(scene, o, d, t_min=1e-9 * size)
        on_plane = np.isfinite(t) & (t < reach) & np.array([isinstance(scene.shapes[k], Plane) for k in sid])
        out.append(o[on_plane] + t[on_plane, None] * d[on_plane])
    return out


# ---------------------------------------------------------------------------------------------
# Camera


def camera_job(scene: Scene, rules: Rules, spp: int = 1) -> dict[str, Any]:
    """Blender's perspective camera on the exercise's rays (see the package's docstring: Camera).

    Field of view: the image plane is [-0.5, 0.5]^2 at distance d, so tan(fov_x / 2) = 0.5 / d: a sensor
    of width S and a focal length S d (both at least Blender's 1 mm). Non-square images: the exercise's
    pixels are 1/W wide and 1/H tall, so the pixel aspect ratio is H : W (Blender's pixel_aspect_x/y).
    Shift: Blender's shift is in units of the sensor's fitted side (here the width, 1 of the image plane),
    and moves the frame with it. The sample-0 ray goes through pixel (x, y) at Cycles' raster position
    (x + 0.5 + b, y + 0.5 + b) -- Cycles' rows count from the bottom -- b = FILTER_CENTRE_BIAS. The
    exercise's ray goes through (x + u + dx, y + v + dy) from the top-left (u = v = 0 for the corner,
    0.5 for the centre; (dx, dy) the rule pixel_shift): the frame moves by u - 0.5 - b + dx pixels to
    the right and 0.5 - v - b - dy up. With spp > 1 the box filter covers the pixel square [x, x + 1]
    x [y, y + 1], the same square the reference's stratified samples cover: the shift is then the
    pixel_shift alone.
    """
    w, h, dist = scene.camera.width, scene.camera.height, scene.camera.distance
    cw, ch = canvas(scene)
    # the frame is cw/w image planes wide: tan(fov/2) = 0.5 (cw/w) / d; Blender's lens and sensor are >= 1 mm
    sensor = max(1.0, cw / (w * dist))
    dx, dy = rules.pixel_shift
    if spp == 1:
        u = 0.0 if rules.pixel_sample == "corner" else 0.5
        sx, sy = u - 0.5 - FILTER_CENTRE_BIAS + dx, 0.5 - u - FILTER_CENTRE_BIAS - dy
    else:
        sx, sy = dx, -dy
    # a canvas larger than the image keeps the image in its top-left corner
    sx, sy = sx + (cw - w) / 2, sy - (ch - h) / 2
    near = dist if rules.ray_origin == "image-plane" else max(CLIP_START_MIN, 1e-7 * dist)
    return {
        "location": to_blender(scene.camera.position),
        "sensor_width": sensor,
        "lens": sensor * dist * w / cw,
        # shift in units of the frame's width (cw pixels, cw/w of the image plane); a pixel is 1/w of the
        # image plane wide and 1/h tall (the image plane is square): w/(h cw) of the unit
        "shift": [sx / cw, sy * w / (h * cw)],
        "clip_start": near,
        "clip_end": CLIP_END,
    }


# Blender renders at least 4 pixels a side: a smaller image is the top-left corner of a 4-pixel canvas
# with the same pixels (the camera's field and shift widened to match), cropped after reading.
MIN_SIDE = 4


def canvas(scene: Scene) -> tuple[int, int]:
    """The size Blender renders: the image's, at least MIN_SIDE a side."""
    return max(scene.camera.width, MIN_SIDE), max(scene.camera.height, MIN_SIDE)


def pixel_aspect(scene: Scene) -> list[float]:
    """Blender's pixel_aspect_x, _y (each in [1, 200]) for pixels 1/W wide and 1/H tall: the ratio H : W."""
    w, h = scene.camera.width, scene.camera.height
    return [1.0, w / h] if h <= w else [h / w, 1.0]


# ---------------------------------------------------------------------------------------------
# Light and materials

# Cycles' point light of power P watts radiates P / (4 pi) W/sr, and its Diffuse BSDF is dc / pi: the
# radiance of a lit point is dc P cos / (4 pi^2 r^2) (measured: 1 / (4 pi^2) to 6 digits). The oracle's
# light has radiant intensity I = lc, P = 4 pi lc -- Mitsuba's point light with intensity lc, so both
# physically based oracles give the same numbers and the harness's pi r^2 converts either.
LIGHT_POWER = 4 * math.pi


def light_job(scene: Scene, intensity_scale: float = 1.0) -> dict[str, Any]:
    """The point light: colour lc, power 4 pi (radiant intensity lc), times ``intensity_scale``."""
    return {
        "location": to_blender(scene.light.position),
        "color": [float(c) for c in scene.light.color],
        "energy": LIGHT_POWER * intensity_scale,
    }


def materials_job(scene: Scene) -> tuple[list[dict[str, Any]], list[int]]:
    """One Blender material per scene material (named as in the scene file), and each shape's index into them."""
    mats: list[dict[str, Any]] = []
    index: dict[Any, int] = {}
    of_shape = []
    for s in scene.shapes:
        m = s.material
        key = (m.name, m.diffuse, m.reflection, m.ambient, m.specular)
        if key not in index:
            index[key] = len(mats)
            name = m.name or f"material{len(mats)}"
            mats.append({"name": name, "diffuse": [float(v) for v in m.diffuse],
                         "reflection": [float(v) for v in m.reflection]})  # fmt: skip
        of_shape.append(index[key])
    return mats, of_shape


def viewing_distance(scene: Scene, rules: Rules, side: int = 64) -> float | None:
    """The median distance from the light to the points the camera's rays hit (a grid of at most side^2
    rays); None when nothing is hit. As Mitsuba's export: the distance at which the export's light, scaled
    by pi d^2, gives the exercise's brightness."""
    o, d = _grid_rays(scene, rules, side)
    t, _ = first_hits(scene, o, d, 1e-9)
    return median_light_distance(scene, o, d, t)


# ---------------------------------------------------------------------------------------------
# The job


def job(
    scene: Scene,
    rules: Rules,
    quads_: dict[int, Quad],
    spp: int = 1,
    bounces: int | None = None,
    world: tuple[float, float, float] | None = None,
    intensity_scale: float = 1.0,
) -> dict[str, Any]:
    """The scene as the JSON inside_blender.py builds (renders and passes are added by the caller)."""
    mats, of_shape = materials_job(scene)
    size = scene_size(scene)
    balls, planes = [], []
    for k, s in enumerate(scene.shapes):
        if isinstance(s, Ball):
            balls.append({"name": f"shape{k}", "index": k + 1, "material": of_shape[k],
                          "center": to_blender(s.center), "radius": float(s.radius)})  # fmt: skip
        else:
            qd = quads_[k]
            corners = [to_blender(c) for c in qd.corners(size)]
            # Blender's face normal follows the corners' order (right-handed); the mirror reversed it
            a, b, c = (np.asarray(corners[i]) for i in range(3))
            if np.dot(np.cross(b - a, c - a), to_blender(s.normal)) < 0:
                corners = corners[::-1]
            planes.append({"name": f"shape{k}", "index": k + 1, "material": of_shape[k], "corners": corners})
    return {
        "name": scene.name,
        "width": canvas(scene)[0],
        "height": canvas(scene)[1],
        "pixel_aspect": pixel_aspect(scene),
        "samples": spp,
        "seed": 0,
        "bounces": scene.max_depth if bounces is None else bounces,
        "world": [float(c) for c in (scene.background if world is None else world)],
        "materials": mats,
        "balls": balls,
        "planes": planes,
        "light": light_job(scene, intensity_scale),
        "camera": camera_job(scene, rules, spp),
        "passes": [],
        "renders": [],
    }
