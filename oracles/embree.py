"""Embree oracle (through trimesh): the scene's primary-ray geometry from a tessellated copy.

Embree (Intel's ray-triangle kernel library, here through ``embreex`` and trimesh's
``trimesh.ray.ray_pyembree.RayMeshIntersector``) intersects triangles only, in float32. The scene is
converted, the exact primary rays of ``minirt.model.camera.primary_rays`` are cast, and the first hit of
each ray comes back as hit mask, shape id, t, position and normal. No colour: geometry only.

Conventions bridged:

- Balls become icospheres (``trimesh.creation.icosphere``, ``options={"subdivisions": N}``, default
  4, 20·4^N faces -- lower for scenes of thousands of balls: ``MAX_DEFAULT_FACES``), scaled by r and
  moved to the centre. Their vertices lie on the sphere, so the
  polyhedron P is inscribed: the inner ball of radius r(1 - g) is inside P, which is inside the
  ball, where g, the *radial gap*, is 1 - min over faces of distance(centre, face plane) / r,
  computed exactly from the unit mesh (cached per level; about 0.2054 / 4^N). Consequences, used
  for the error bounds recorded with every result (``meta["precision"]``, ``aux``):
  * hit/miss: a ray passing at distance h from the centre hits P if h <= r(1 - g) and misses it if
    h > r; only the silhouette margin |h - r|/r < g can disagree with the analytic ball;
  * t: the faceted hit lies between the ball's and the inner ball's intersections along the ray, so
    |t - t_ref| <= b0 - a0 (inner minus outer near root; far roots from inside a ball), at most
    r·(1 - (1 - g)^2) / cos θ with cos θ = |n·d| the reference's incidence, and at most
    r·sqrt(1 - (1 - g)^2) for any ray that crosses the inner ball (off the silhouette band);
  * a ray *starting* in the shell (| |o - C| - r | / r < g, e.g. image-plane origins inside a ball
    that crosses the image plane) may start outside P and miss it: an "origin band" that
    ``minirt.reference.band`` does not model yet;
  * normal: Embree returns the *face* normal, not the analytic one. It differs from the analytic
    normal at the radial projection of the hit point by at most the mesh's largest angle between a
    face normal and its vertices' normals (α, computed from the mesh), and the analytic normals at
    the faceted and the analytic hit points differ by at most asin(Δt / (r(1 - g))). Per pixel
    bound α + asin(Δt_bound / (r(1 - g))); global one with the largest Δt off the band.
- Planes become one quad (two triangles, wound so the face normal is the plane's normal) centred
  on the foot Q0 of the perpendicular from the image-plane centre, half-side R = T_far + ρ0: every
  ray origin (camera, image-plane square) is within ρ0 of the image-plane centre, so every plane
  point within T_far of an origin is within R of it, and so inside the quad. The far distance is
  T_far = FAR_FACTOR · S with S the scene's size (camera distance, |C| + r of every ball, |a| of
  every plane, at least 1). Why FAR_FACTOR = 32: trimesh moves the mesh to its bounding-box corner
  before rounding to float32, so the quad's size E sets Embree's absolute error for *every*
  triangle, balls included (about EMBREE_ULPS · 2^-24 · E); with E ≈ 64 S that stays below the
  level-4 gap for balls down to S/40 in radius. What is lost: plane hits farther than T_far, i.e.
  rays with |n·d| < h_max / T_far (h_max: the largest distance of an origin from the plane), the
  grazing band recorded as ``grazing_abs`` -- measured: 2 rows at a floor's horizon at 256x256
  (exercise.toml, 517 pixels), a fraction of a row at 64x64.
  When a ball's inner ball holds every ray origin (a dome around the camera), no ray gets farther
  than max |x - C| + r over the origins x, and T_far is capped there (nothing is lost then).
- float32 inside Embree decides only *which* triangle is hit first. t, position and normal are
  recomputed in float64 from that triangle: the face's plane (float64 vertices) for a ball, the
  scene's own plane (point-normal form, as the reference) for a plane. So float32 widens only the
  hit/miss and ordering bands, by ``eps32_rel`` (EMBREE_ULPS · 2^-24 · E / r).
- First hit: ``intersects_id(..., multiple_hits=False)`` is a single Embree query per ray with
  t in (0, inf): the closest triangle in front of the origin (trimesh offsets rays only for its
  multiple-hit loop, which is not used). t is the distance from the origin along the unit direction.
  Embree does not cull back faces, so from inside a ball it sees the far side: rule
  ``near_root_only = false`` is the only value supported.
- Ids: all shapes go into one mesh in scene order, with a per-face shape index
  (``mesh.face_attributes["shape_id"]``); exported nodes are named "shape0", "shape1", ... and never
  carry the scene's names.
"""

from __future__ import annotations

import functools
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from minirt.io.atomic import write_all
from minirt.model import camera
from minirt.model.result import RenderResult, geometry_from_flat
from minirt.model.roots import ball_roots
from minirt.model.rules import Rules
from minirt.model.scene import Ball, Plane, Scene
from minirt.model.series import Series, Setting, Truth
from minirt.model.tolerance import GeometryTolerance, Margins, tolerance_inputs
from minirt.oracles.base import Oracle

DEFAULT_SUBDIVISIONS = 4
MAX_SUBDIVISIONS = 7  # 327,680 faces per ball; beyond that float32 (not the tessellation) dominates
# Faces the default level may give a scene: the mesh, trimesh's caches and Embree's copy take ~350 bytes
# a face (measured: 10,000 balls at level 4, 51 M faces, peaked at 18 GB), so 2^23 faces stay near 3 GB.
# A scene of many balls gets the finest level under it (1,024 balls: still 4; 10,000: 2), a wider radial
# gap and band -- recorded with the result -- rather than running out of memory. An explicit
# ``subdivisions`` option is taken as given.
MAX_DEFAULT_FACES = 2**23
# Far distance in units of the scene's size: see the module docstring (float32 budget vs horizon).
FAR_FACTOR = 32.0
U32 = 2.0**-24  # float32 unit round-off
U64 = 2.0**-53
# Embree's ray-triangle test: a few roundings of coordinates of magnitude E (vertices, origins after
# trimesh's translation, edge and Plücker products). 8 ulps of E is a generous bound on the resulting
# perpendicular displacement of an edge; it is only ever used to widen the silhouette/tie band.
EMBREE_ULPS = 8.0
OPTIONS = ("subdivisions", "far_factor")
# Options the CLI/harness passes to every backend that mean nothing here (Embree is float32, whatever
# the reference's precision): accepted, recorded under meta["options"]["ignored"], otherwise unused.
SHARED_OPTIONS = ("precision", "prune")


# ---------------------------------------------------------------------------------------------
# Tessellation


@dataclass(frozen=True)
class Tessellation:
    """A unit icosphere and its exact deviation from the unit sphere."""

    subdivisions: int
    vertices: np.ndarray  # (V, 3) on the unit sphere
    faces: np.ndarray  # (F, 3) int, outward winding
    radial_gap_rel: float  # g = 1 - min over faces of distance(0, face plane)
    normal_deg: float  # α = max angle between a face normal and its vertices' (sphere) normals

    @property
    def n_faces(self) -> int:
        return len(self.faces)


@functools.cache
def tessellation(subdivisions: int) -> Tessellation:
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    v = np.asarray(m.vertices, dtype=np.float64)
    f = np.asarray(m.faces, dtype=np.int64)
    tri = v[f]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    fn /= np.linalg.norm(fn, axis=1)[:, None]
    dist = np.einsum("ij,ij->i", fn, tri[:, 0])  # distance of each face plane from the centre
    if not (dist > 0).all():
        raise RuntimeError("icosphere faces are not wound outward")
    vn = tri / np.linalg.norm(tri, axis=2)[..., None]  # sphere normals at the face's vertices
    cos = np.clip(np.einsum("ijk,ik->ij", vn, fn), -1.0, 1.0)
    v.setflags(write=False)
    f.setflags(write=False)
    return Tessellation(
        subdivisions=subdivisions,
        vertices=v,
        faces=f,
        radial_gap_rel=float(1.0 - dist.min()),
        normal_deg=float(np.degrees(np.arccos(cos.min()))),
    )


def _ray_origin_region(scene: Scene) -> list[np.ndarray]:
    """Extreme points of every possible primary-ray origin: the camera and the image-plane corners."""
    pts = [np.array([0.0, 0.0, -scene.camera.distance])]
    pts += [np.array([x, y, 0.0]) for x in (-0.5, 0.5) for y in (-0.5, 0.5)]
    return pts


def scene_size(scene: Scene) -> float:
    s = max(1.0, scene.camera.distance)
    for shape in scene.shapes:
        if isinstance(shape, Ball):
            s = max(s, float(np.linalg.norm(shape.center)) + shape.radius)
        else:
            s = max(s, abs(shape.distance))
    return s


def enclosing_far(scene: Scene, gap: float) -> float:
    """Largest t any primary ray can reach inside a ball whose inner ball holds every ray origin (else inf).

    Such a ball (a dome around the camera) stops every ray, analytic or faceted, before
    max |x - C| + r over the origins x, so no plane has to reach farther.
    """
    far = math.inf
    pts = _ray_origin_region(scene)
    for s in scene.shapes:
        if isinstance(s, Ball):
            dist = [float(np.linalg.norm(x - np.asarray(s.center))) for x in pts]
            if max(dist) < s.radius * (1.0 - gap):
                far = min(far, max(dist) + s.radius)
    return far


def far_distance(scene: Scene, far_factor: float = FAR_FACTOR, subdivisions: int = DEFAULT_SUBDIVISIONS) -> float:
    """Planes are modelled out to this distance from every ray origin (module docstring)."""
    return min(far_factor * scene_size(scene), enclosing_far(scene, tessellation(subdivisions).radial_gap_rel))


def _plane_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal e1, e2 with e1 × e2 = n (so a quad wound e1, e2 faces along n)."""
    a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(a, n)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    return e1, e2


def shape_meshes(scene: Scene, subdivisions: int = DEFAULT_SUBDIVISIONS, far_factor: float = FAR_FACTOR) -> list:
    """One trimesh.Trimesh per shape, in scene order (balls: icospheres; planes: quads)."""
    import trimesh

    tess = tessellation(subdivisions)
    rho0 = max(float(np.linalg.norm(p)) for p in _ray_origin_region(scene))
    half = far_distance(scene, far_factor, subdivisions) + rho0
    out = []
    for shape in scene.shapes:
        if isinstance(shape, Ball):
            v = tess.vertices * shape.radius + np.asarray(shape.center)
            f = tess.faces
        else:
            n = np.asarray(shape.normal)
            q0 = np.asarray(shape.point)  # foot of the perpendicular from the origin (image-plane centre)
            e1, e2 = _plane_basis(n)
            v = np.array([q0 + half * (sx * e1 + sy * e2) for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
            f = np.array([[0, 1, 2], [0, 2, 3]])
        out.append(trimesh.Trimesh(vertices=v, faces=f, process=False, validate=False))
    return out


def default_subdivisions(scene: Scene) -> int:
    """DEFAULT_SUBDIVISIONS, or the finest level whose balls stay within MAX_DEFAULT_FACES faces."""
    balls = sum(isinstance(s, Ball) for s in scene.shapes)
    level = DEFAULT_SUBDIVISIONS
    while level > 0 and balls * 20 * 4**level > MAX_DEFAULT_FACES:
        level -= 1
    return level


def _hit_face_normals(mesh, hit_faces: np.ndarray):
    """A lookup face index -> unit normal (``mesh.face_normals``' values: trimesh's triangle normals, row by
    row, zero for a degenerate face) computed for the faces hit only: 1,024 balls at the default subdivision
    are 5.2 M faces, every one's normal 6 s, the hit ones' a few ms."""
    import trimesh

    faces = np.unique(hit_faces)
    normals = np.zeros((len(faces), 3))
    if len(faces):
        # A face's squared cross product overflows float64 only for edges past ~1e77, far past float32's
        # range, which minirt.reference.hazards.scene_warnings reports for Embree (a float32 backend); the
        # face is then degenerate here (normal zero), as trimesh says of it.
        with np.errstate(over="ignore"):
            unit, valid = trimesh.triangles.normals(triangles=mesh.vertices[mesh.faces[faces]])
        normals[valid] = unit
    return lambda wanted: normals[np.searchsorted(faces, wanted)]


def scene_to_mesh(scene: Scene, subdivisions: int = DEFAULT_SUBDIVISIONS, far_factor: float = FAR_FACTOR):
    """All shapes in one trimesh.Trimesh, faces in scene order; ``face_attributes["shape_id"]`` per face."""
    import trimesh

    parts = shape_meshes(scene, subdivisions, far_factor)
    verts, faces, ids, base = [], [], [], 0
    for k, m in enumerate(parts):
        verts.append(np.asarray(m.vertices))
        faces.append(np.asarray(m.faces) + base)
        ids.append(np.full(len(m.faces), k, dtype=np.int32))
        base += len(m.vertices)
    mesh = trimesh.Trimesh(
        vertices=np.concatenate(verts) if verts else np.zeros((0, 3)),
        faces=np.concatenate(faces) if faces else np.zeros((0, 3), dtype=np.int64),
        process=False,
        validate=False,
    )
    mesh.face_attributes["shape_id"] = np.concatenate(ids) if ids else np.zeros(0, dtype=np.int32)
    return mesh


# ---------------------------------------------------------------------------------------------
# Error bounds


def _ball_roots(ball: Ball, radius: float, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Both roots (near, far) of a ball of the given radius (stable forms, minirt.model.roots; nan on a miss)."""
    br = ball_roots(ball.center, radius, o, d, on_miss="nan")
    return np.fmin(br.r0, br.q), np.fmax(br.r0, br.q)


def ball_t_bound(ball: Ball, gap: float, o: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Per ray: the largest |t_P - t_ball| for any P inscribed in `ball` with radial gap `gap` (inf if unknown).

    P lies between the inner ball (radius r(1 - g)) and the ball, so its first hit lies in
    [a0, b0] from outside, [b1, a1] from inside the inner ball, and in (0, a1] from inside the shell
    (a: the ball's roots, b: the inner ball's); the analytic hit is one end of that interval, so its
    width bounds the error. It depends only on the ray, never on what Embree returned.
    """
    a0, a1 = _ball_roots(ball, ball.radius, o, d)
    b0, b1 = _ball_roots(ball, ball.radius * (1.0 - gap), o, d)
    lo = np.full(len(o), np.nan)
    hi = np.full(len(o), np.nan)
    outside = a0 > 0
    inner_hit = np.isfinite(b0)
    m = outside & inner_hit
    lo[m], hi[m] = a0[m], b0[m]
    m = outside & ~inner_hit  # silhouette band: anywhere on the outer chord, or a miss
    lo[m], hi[m] = a0[m], a1[m]
    m = ~outside & inner_hit & (b0 < 0) & (b1 > 0)
    lo[m], hi[m] = b1[m], a1[m]
    m = ~outside & np.isnan(lo) & (a1 > 0)
    lo[m], hi[m] = 0.0, a1[m]
    out = hi - lo
    return np.where(np.isfinite(out), out, np.inf)


def plane_t_bound(plane: Plane, o: np.ndarray, d: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Rounding of the float64 point-normal form (same formula as the reference): a few ulps."""
    nd = np.abs(d @ np.asarray(plane.normal))
    with np.errstate(divide="ignore"):
        return 16 * U64 * (abs(plane.distance) + np.linalg.norm(o, axis=1) + t) / nd


# ---------------------------------------------------------------------------------------------
# The oracle


def _import_embree():
    """trimesh and its Embree intersector, or ImportError with the reason."""
    import trimesh
    import trimesh.ray

    if not getattr(trimesh.ray, "has_embree", False):
        raise ImportError("trimesh.ray.has_embree is false (embreex missing or broken)")
    from trimesh.ray import ray_pyembree

    return trimesh, ray_pyembree


def _versions() -> dict[str, str]:
    from importlib.metadata import PackageNotFoundError, version

    out = {}
    for pkg in ("trimesh", "embreex"):
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:
            out[pkg] = "not installed"
    return out


class EmbreeOracle(Oracle):
    name: ClassVar[str] = "embree"
    shades: ClassVar[bool] = False
    display_name: ClassVar[str] = "Embree"
    packages: ClassVar[tuple[str, ...]] = ("trimesh", "embreex")
    float32: ClassVar[bool] = True
    # a check keeps its buffers and figures (220 bytes a pixel); a render keeps 150 and runs with 50 (the
    # mesh's rays are cast in float32 arrays): measured with the others (minirt.jobs.memory)
    check_kept: ClassVar[int] = 220
    render_kept: ClassVar[int] = 150
    render_running: ClassVar[int] = 50
    export_as: ClassVar[str | None] = "mesh"
    export_what: ClassVar[str] = "glTF"
    supported: ClassVar[dict[str, tuple[Any, ...]]] = {
        "near_root_only": (False,),
        "t_max": (math.inf,),  # its rays' tfar is inf: every hit counts (raw_normals: no shading to follow)
    }

    def available(self) -> tuple[bool, str]:
        try:
            _import_embree()
        except Exception as e:  # ImportError, or embreex failing to load its library
            return False, f"Embree via trimesh unavailable: {str(e).splitlines()[0] if str(e) else type(e).__name__}"
        return True, self.version()

    def version(self) -> str:
        v = _versions()
        return f"trimesh {v['trimesh']}, embreex {v['embreex']}"

    def geometry_tolerance(self, result: RenderResult, ref: RenderResult, measured: Margins) -> GeometryTolerance:
        """This oracle's recorded precision as per-pixel tolerances, each with its derivation."""
        h, w, p, m, _ = tolerance_inputs(result, ref, measured)
        tb = result.aux.get("t_bound", np.full((h, w), p["t_abs"]))
        t_abs = tb + p["eps32_abs"]
        # A depth tie is relative to the ray's nearest candidate hit in the scene (margins "near"), not to
        # the reference's t: where the reference misses, t_ref is 0 and a ratio to it put every ray that
        # meets a ball in the band -- a reference that skipped a ball was never caught there (the defect
        # campaign, far_2027_34: 46 of its pixels).
        near = m["near"]
        with np.errstate(divide="ignore", invalid="ignore"):
            tie_rel = np.where(np.isfinite(near) & (near > 0), t_abs / np.maximum(near, 1e-300), np.inf)
        band = (
            measured.below("silhouette", p["band_abs"], h, w)
            | measured.below("origin", p["origin_band_abs"], h, w)
            | (m["grazing"] < p["grazing_abs"])
            | (m["tie"] < 2 * tie_rel)
        )
        # Rays starting on a plane (t ~ 0): Embree's minimum distance is 0 (trimesh casts t in (0, inf)); its
        # quads are float32 coordinates of the mesh's extent (origins included), 8 ulps: eps32_abs.
        starts = measured.start_band(h, w, t_min=0.0, plane_err=p["eps32_abs"])
        band = band | starts
        nd = result.aux.get("normal_bound_deg", np.full((h, w), p["normal_deg"]))
        why = {
            "band": f"silhouette < {p['band_abs']:.3g} (tessellation gap + float32), grazing < {p['grazing_abs']:.3g} "
            f"(far plane cut), depth ties within the t bound, rays starting within {p['eps32_abs']:.3g} of a plane",
            "t": "per pixel: the tessellated shell's thickness along the ray (aux t_bound) "
            "+ float32 of the mesh extent",
            "normal": "per pixel: face-to-vertex normal angle + the shell's tilt (aux normal_bound_deg)",
        }
        summary = {
            "band_eps": p["band_abs"],
            "t_abs_max": float(np.max(t_abs)),
            "normal_deg_max": float(np.max(nd)),
            "start_band_pixels": int(starts.sum()),
        }
        for key in ("t_abs_max", "normal_deg_max"):  # the reason strict JSON writes beside the null (minirt.io.jsonout)
            if not math.isfinite(summary[key]):
                summary[key + "_reason"] = "infinite: the bound is unlimited on pixels the oracle misses"
        return GeometryTolerance(band=band, t_abs=t_abs, normal_deg=nd, why=why, summary=summary)

    @staticmethod
    def _options(options: dict[str, Any] | None, scene: Scene) -> dict[str, Any]:
        given = dict(options or {})
        ignored = {k: given.pop(k) for k in SHARED_OPTIONS if k in given}
        opts = {"subdivisions": default_subdivisions(scene), "far_factor": FAR_FACTOR, **given}
        unknown = sorted(set(opts) - set(OPTIONS))
        if unknown:
            raise ValueError(f"unknown option(s) {', '.join(unknown)} (known: {', '.join(OPTIONS)})")
        n = opts["subdivisions"]
        if isinstance(n, bool) or not isinstance(n, int) or not 0 <= n <= MAX_SUBDIVISIONS:
            raise ValueError(f"subdivisions must be an integer in 0..{MAX_SUBDIVISIONS}, got {n!r}")
        ff = opts["far_factor"]
        if isinstance(ff, bool) or not isinstance(ff, int | float) or not (math.isfinite(ff) and ff >= 1):
            raise ValueError(f"far_factor must be a finite number >= 1, got {ff!r}")
        opts["far_factor"] = float(ff)
        if ignored:
            opts["ignored"] = ignored
        return opts

    def render(self, scene: Scene, rules: Rules, options: dict[str, Any] | None = None, progress=None) -> RenderResult:
        w, h = scene.camera.width, scene.camera.height
        try:
            opts = self._options(options, scene)
        except ValueError as e:
            return RenderResult.failed(self.name, w, h, "error", str(e))
        ok, why = self.available()
        if not ok:
            return RenderResult.failed(self.name, w, h, "skip", why)
        if self.cannot_follow(rules):
            names = ", ".join(self.cannot_follow(rules))
            return RenderResult.failed(
                self.name, w, h, "skip", f"cannot follow rule(s) {names}: render under adapt(rules)"
            )
        try:
            return self._render(scene, rules, opts)
        except Exception as e:  # a renderer failure is a result, never an exception
            msg = str(e).splitlines()[0] if str(e) else ""
            return RenderResult.failed(self.name, w, h, "error", f"{type(e).__name__}: {msg}")

    def _render(self, scene: Scene, rules: Rules, opts: dict[str, Any]) -> RenderResult:
        _, ray_pyembree = _import_embree()
        w, h = scene.camera.width, scene.camera.height
        level, far_factor = opts["subdivisions"], opts["far_factor"]
        timings: dict[str, float] = {}
        t_start = time.perf_counter()

        tess = tessellation(level)
        mesh = scene_to_mesh(scene, level, far_factor)
        o, d = camera.primary_rays(scene, rules)
        timings["tessellation"] = time.perf_counter() - t_start

        tri, passes, extent = _cast(ray_pyembree, mesh, o, d, timings)
        t0 = time.perf_counter()
        sid, t, normal, bad = _hits(scene, mesh, tri, o, d)
        hit = sid >= 0
        position = o + np.where(hit, t, 0.0)[:, None] * d
        t_bound, normal_bound = _bounds(scene, tess, sid, o, d, t, extent)
        timings["readback"] = time.perf_counter() - t0
        timings["total"] = time.perf_counter() - t_start

        geom = geometry_from_flat(w, h, sid, t, position, normal)
        aux = {
            "t_bound": np.where(geom["hit"], t_bound.reshape(h, w), np.inf),
            "normal_bound_deg": np.where(geom["hit"], normal_bound.reshape(h, w), np.inf),
            "triangle": np.where(hit, tri, -1).reshape(h, w),
        }
        precision = precision_summary(scene, tess, far_factor, extent)
        meta = {
            "backend": self.name,
            "version": _versions(),
            "scene": scene.name,
            "scene_sha256": scene.digest,
            "options": opts,
            "settings": {
                "width": w,
                "height": h,
                "samples_cast": 1,
                "far_distance": far_distance(scene, far_factor, level),
            },
            "rules": rules.as_dict(),
            "tessellation": {
                "subdivisions": level,
                "faces": len(mesh.faces),
                "faces_per_ball": tess.n_faces,
                "radial_gap_rel": tess.radial_gap_rel,
                "face_normal_deg": tess.normal_deg,
            },
            "precision": precision,
            "effects": {"simulated": ["geometry"], "skipped": ["shading"]},
            "passes": passes,
            "dropped_hits": int(bad.sum()),
            "timings": timings,
            "commands": [
                "trimesh.ray.ray_pyembree.RayMeshIntersector(mesh).intersects_id(origins, directions, "
                "multiple_hits=False, return_locations=False)"
            ],
        }
        return RenderResult(backend=self.name, width=w, height=h, color=None, aux=aux, meta=meta, **geom)

    def export(self, scene: Scene, rules: Rules, out_dir: Path, options: dict[str, Any] | None = None) -> list[Path]:
        """The tessellated scene as glTF binary (one node and mesh per shape, "shape0", ...) + JSON notes."""
        import trimesh

        opts = self._options(options, scene)
        out = Path(out_dir)
        tscene = trimesh.Scene()
        for k, m in enumerate(shape_meshes(scene, opts["subdivisions"], opts["far_factor"])):
            tscene.add_geometry(m, node_name=f"shape{k}", geom_name=f"shape{k}")
        glb = out / "embree_scene.glb"
        tess = tessellation(opts["subdivisions"])
        notes = out / "embree_scene.json"
        text = (
            json.dumps(
                {
                    "mesh": glb.name,
                    "shapes": [
                        {"node": f"shape{k}", "type": "ball" if isinstance(s, Ball) else "plane"}
                        for k, s in enumerate(scene.shapes)
                    ],
                    "options": opts,
                    "far_distance": far_distance(scene, opts["far_factor"], opts["subdivisions"]),
                    "tessellation": {"subdivisions": tess.subdivisions, "radial_gap_rel": tess.radial_gap_rel},
                    "rays": "minirt.model.camera.primary_rays (one per pixel); rules " + json.dumps(rules.as_dict()),
                },
                indent=2,
            )
            + "\n"
        )
        return write_all({glb: tscene.export(file_type="glb"), notes: text})  # both whole, or neither

    # ---- the sweep (minirt.sweep): what accuracy costs in time ---------------------------------
    sweep_knobs: ClassVar[dict[str, Any]] = {"subdivisions": tuple(range(MAX_SUBDIVISIONS + 1))}

    def sweep(self, scene: Scene, rules: Rules, knobs: dict[str, Any]) -> list[Series]:
        """One knob, subdivisions: 0 ... 7, against the analytic geometry (reference f64, 1 ray/pixel,
        Embree's rules): t relative error, hit/id mismatches, and the harness's own geometry check
        ("geometry+check": Embree does not shade). Cost: triangles per ball, 20 4^N, so the fit's
        ``factor_per_level`` is 4^slope: theory 1/4, the radial gap of an inscribed icosphere shrinks with
        the square of its edge."""
        k = self.turned(knobs)
        er = self.adapt(rules)
        exact = Truth("reference/f64/embree-rules", "reference", {"precision": "f64"}, samples=1, rules=er,
                      describe={"precision": "f64", "spp": 1})  # fmt: skip
        levels = tuple(
            Setting(n, 20 * 4**n, {"subdivisions": n},
                    f"Embree at subdivision {n} ({20 * 4 ** int(n)} triangles per ball)", f"embree subdivisions {n}")
            for n in k["subdivisions"]
        )  # fmt: skip
        return [
            Series(self.name, "subdivisions", levels, er, exact, "geometry+check", metric="t_rel_mean",
                   cost="triangles per ball (20 4^N)",
                   theory="faces^-1, i.e. 4^-N (radial gap of the inscribed icosphere)",
                   knobs={"embree_subdivisions": k["subdivisions"]}, level_factor=4.0)
        ]  # fmt: skip


def precision_summary(scene: Scene, tess: Tessellation, far_factor: float, extent: float) -> dict[str, Any]:
    """The error bounds a comparison may use, with their derivation (module docstring)."""
    g = tess.radial_gap_rel
    balls = [s for s in scene.shapes if isinstance(s, Ball)]
    planes = [s for s in scene.shapes if isinstance(s, Plane)]
    eps32_abs = EMBREE_ULPS * U32 * extent
    eps32_rel = max((eps32_abs / b.radius for b in balls), default=0.0)
    shell = math.sqrt(1.0 - (1.0 - g) ** 2)  # largest Δt / r for a ray crossing the inner ball
    t_abs = max((b.radius * shell for b in balls), default=0.0)
    worst = max(((b.radius * shell + eps32_abs) / (b.radius * (1.0 - g)) for b in balls), default=0.0)
    normal_deg = tess.normal_deg + math.degrees(math.asin(min(1.0, worst))) if balls else 0.0
    far = far_distance(scene, far_factor, tess.subdivisions)
    origins = _ray_origin_region(scene)
    h_max = max((abs(float(np.dot(p.normal, x)) - p.distance) for p in planes for x in origins), default=0.0)
    if far == enclosing_far(scene, g):
        h_max = 0.0  # a dome stops every ray before the far distance: no plane hit is lost
    return {
        "t_abs": t_abs,
        "t_rel_over_cos": 1.0 - (1.0 - g) ** 2,
        "normal_deg": normal_deg,
        "normal_face_deg": tess.normal_deg,
        "band_abs": g + eps32_rel,
        "origin_band_abs": g + eps32_rel,
        "grazing_abs": h_max / far if planes else 0.0,
        "eps32_abs": eps32_abs,
        "eps32_rel": eps32_rel,
        "why": (
            "Balls are inscribed icospheres with radial gap g: the faceted surface lies between radius r(1-g) and r. "
            "t_abs = max r*sqrt(1-(1-g)^2): largest |Δt| for a ray crossing the inner ball (per pixel: aux t_bound, "
            "<= r*t_rel_over_cos/cos θ). normal_deg = α (face vs vertex normals, normal_face_deg) + "
            "asin((t_abs + eps32_abs)/r(1-g)) (per pixel: aux normal_bound_deg). band_abs = g + eps32_rel: "
            "silhouette margin |h-r|/r below which hit/miss may differ (g from the tessellation, "
            "eps32_rel = 8 float32 ulps of the mesh's extent / r); "
            "origin_band_abs: the same for | |o-C| - r |/r, a ray starting in the shell. "
            "grazing_abs: |n·d| below which a plane hit lies beyond the far distance and is lost. t, position, "
            "normal are recomputed in float64 from the triangle Embree chose; depth ties within t_bound + eps32_abs."
        ),
    }


def _cast(ray_pyembree, mesh, o: np.ndarray, d: np.ndarray, timings: dict[str, float]):
    """(the triangle each ray hits, -1 on a miss; the passes' record; the extent of the coordinates Embree
    sees): one Embree query per ray, its BVH's build and the casting timed apart (``timings``)."""
    n_rays = len(o)
    tri = np.full(n_rays, -1, dtype=np.int64)
    passes = []
    extent = 0.0
    if len(mesh.faces):
        t0 = time.perf_counter()
        intersector = ray_pyembree.RayMeshIntersector(mesh)
        _ = intersector._scene  # build Embree's BVH now, so the timings separate build and casting
        timings["bvh_build"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        # One Embree query per ray, t in (0, inf): the first hit (no offsets, no multiple-hit loop).
        index_tri, index_ray = intersector.intersects_id(o, d, multiple_hits=False, return_locations=False)
        tri[index_ray] = index_tri
        timings["cast"] = time.perf_counter() - t0
        passes.append({"name": "primary", "rays": int(n_rays), "hits": len(index_ray), "query": "INTERSECT"})
        # Coordinates Embree sees: translated to the bounding-box corner (trimesh), then float32.
        corner = mesh.vertices.min(axis=0)
        extent = float(max(np.abs(mesh.vertices - corner).max(), np.abs(o - corner).max()))
    else:
        timings["bvh_build"] = timings["cast"] = 0.0
    return tri, passes, extent


def _hits(scene: Scene, mesh, tri: np.ndarray, o: np.ndarray, d: np.ndarray):
    """(shape id, -1 on a miss; t; normal; the hits dropped) of each ray from the triangle Embree chose:
    t in float64 at the face's plane (a ball's) or the shape's own plane, the face's or the plane's normal."""
    n_rays = len(o)
    face_shape = mesh.face_attributes["shape_id"]
    hit = tri >= 0
    if len(face_shape):
        sid = np.where(hit, face_shape[np.maximum(tri, 0)], -1).astype(np.int32)
    else:  # a scene without shapes: every ray misses
        sid = np.full(n_rays, -1, dtype=np.int32)
    t = np.full(n_rays, np.inf)
    normal = np.zeros((n_rays, 3))
    face_n = _hit_face_normals(mesh, tri[hit])
    for k, shape in enumerate(scene.shapes):
        m = sid == k
        if not m.any():
            continue
        om, dm = o[m], d[m]
        if isinstance(shape, Ball):
            fn = face_n(tri[m])
            v0 = mesh.vertices[mesh.faces[tri[m], 0]]
            # float64 intersection with the face's plane (the triangle Embree chose)
            with np.errstate(divide="ignore", invalid="ignore"):
                tk = np.einsum("ij,ij->i", fn, v0 - om) / np.einsum("ij,ij->i", fn, dm)
            normal[m] = fn
        else:
            n = np.asarray(shape.normal)
            with np.errstate(divide="ignore", invalid="ignore"):
                tk = ((np.asarray(shape.point) - om) @ n) / (dm @ n)
            normal[m] = n
        t[m] = tk
    # float32 can report a hit whose float64 plane intersection is not in front of the origin
    # (a triangle grazed at t ~ 0, or parallel to the ray): count them, and call them misses.
    bad = hit & ~(np.isfinite(t) & (t > 0))
    sid[bad] = -1
    return sid, t, normal, bad


def _bounds(scene: Scene, tess, sid: np.ndarray, o: np.ndarray, d: np.ndarray, t: np.ndarray, extent: float):
    """Per-ray bounds for the shape the oracle hit: (t's, the normal's in degrees); inf on a miss."""
    n_rays = len(o)
    t_bound = np.full(n_rays, np.inf)
    gap = tess.radial_gap_rel
    normal_bound = np.full(n_rays, np.inf)
    # Embree's float32 hit may land on any triangle within eps32 of the true point: far from the origin
    # (a ball 7.9e5 away with radius 0.374, fuzz far_11_15: eps32 0.37) that tilts the chosen face's
    # normal as much as the shell does, so the normal bound takes both.
    eps32_abs = EMBREE_ULPS * U32 * extent
    for k, shape in enumerate(scene.shapes):
        m = sid == k
        if not m.any():
            continue
        if isinstance(shape, Ball):
            tb = ball_t_bound(shape, gap, o[m], d[m])
            t_bound[m] = tb
            ratio = (tb + eps32_abs) / (shape.radius * (1.0 - gap))
            with np.errstate(invalid="ignore"):
                extra = np.where(ratio < 1.0, np.degrees(np.arcsin(np.minimum(ratio, 1.0))), 180.0)
            normal_bound[m] = np.minimum(tess.normal_deg + extra, 180.0)
        else:
            t_bound[m] = plane_t_bound(shape, o[m], d[m], t[m])
            normal_bound[m] = 1e-9
    return t_bound, normal_bound
