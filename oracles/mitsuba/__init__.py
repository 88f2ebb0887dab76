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

The package, one job a file (each opens with its parameters and conventions):

- ``variants.py``: importing Mitsuba and choosing its variant;
- ``planes.py``: the rectangles standing in for planes, sized to what the view can hit;
- ``exporter.py``: the scene as Mitsuba XML (sensor, BSDFs, shapes, emitter), ``minirt export``;
- ``render.py``: what both routes share -- the loaded scene, shape ids, the result's meta;
- ``rays.py``: the ray route (the harness's rays, a loop of stock shading calls);
- ``sensor.py``: the sensor route (Mitsuba's own sensor and integrators);
- ``accuracy.py``: what Mitsuba's float32 numbers are worth (meta["precision"], the bands);
- ``oracle.py``: MitsubaOracle, which puts them together, and its geometry tolerance.
"""

from __future__ import annotations

from minirt.oracles.mitsuba.accuracy import (
    BAND_K,
    DIR_ERR,
    NORMAL_DEG,
    RAY_EPSILON,
    T_REL,
    U32,
    band_eps,
    band_scales,
    shape_eps,
    silhouette_t_bound,
)
from minirt.oracles.mitsuba.exporter import VIEWING_GRID, scene_to_xml, sensor_params, viewing_distance
from minirt.oracles.mitsuba.oracle import MitsubaOracle
from minirt.oracles.mitsuba.planes import PlaneRect, plane_frames, plane_hits, sensor_frames
from minirt.oracles.mitsuba.variants import BACKEND, PACKAGE_VERSION, VARIANTS
from minirt.oracles.mitsuba.variants import load_mitsuba as load_mitsuba  # benchmarks/bench.py renders with it

__all__ = [
    "BACKEND",
    "BAND_K",
    "DIR_ERR",
    "NORMAL_DEG",
    "PACKAGE_VERSION",
    "RAY_EPSILON",
    "T_REL",
    "U32",
    "VARIANTS",
    "VIEWING_GRID",
    "MitsubaOracle",
    "PlaneRect",
    "band_eps",
    "band_scales",
    "plane_frames",
    "plane_hits",
    "scene_to_xml",
    "sensor_frames",
    "sensor_params",
    "shape_eps",
    "silhouette_t_bound",
    "viewing_distance",
]
