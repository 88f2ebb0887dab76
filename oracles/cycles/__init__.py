"""Blender's Cycles as an oracle: its own camera rays, intersectors and path tracer, compared pixel by pixel
in geometry and statistically (as a physically based renderer) in colour.

Blender 5.0.1 as a Python module (``bpy`` from the package registry, ~1 GB), run in a child process with a
Python of its own (minirt.oracles.cycles.run says why: bpy requires NumPy < 2, minirt's OpenImageIO NumPy
>= 2). The child (inside_blender.py) builds the scene this package describes (scene.py), renders it with
Cycles on the CPU and writes its passes to a multilayer EXR, which this process reads. The tolerances
and their derivations are in precision.py. ``minirt export SCENE --to blender`` writes the same scene as
SCENE.blend, for a student to open in Blender.

Conventions bridged (each one is a place where Cycles and the exercise differ):

- Handedness: the exercise's frame is left-handed (x right, y up, the camera looking along +z from
  (0, 0, -d)); Blender's is right-handed and its camera looks along its own -z. Every point and direction
  goes to Blender as (x, y, -z) and comes back the same way: exact, and the camera needs no rotation
  (a rotation by 90 degrees would put cos(pi/2) ~ 4e-8 into its matrix).
- Balls: one vertex at the centre, made a point of the ball's radius by a geometry-nodes "Mesh to Points"
  modifier. Cycles draws points as exact spheres (a ray-sphere root in float32), not as meshes.
- Planes: Cycles has no infinite plane. Each is a quad (two triangles) sized as Mitsuba's rectangles are:
  the smallest box covering every point a ray Cycles casts can meet on the plane -- primary rays through
  the pixels' corners, shadow segments (through the projections of every hit and of the light), and
  reflections within REFLECTION_REACH scene sizes (scene.quads says why each is covered). The quad's
  float32 corners give its hit points an absolute error recorded per plane in meta["planes"].
- Camera: a perspective camera with tan(fov/2) = 0.5 / d (sensor width S, focal length S d), pixel
  aspect H : W for non-square images (the exercise's image plane is square whatever W and H are), and a
  shift moving Cycles' first sample of each pixel onto the rules' ray: Cycles shoots sample 0 through
  its pixel filter's centre -- the pixel centre plus 1/2044 pixel, a quirk of its filter table (scene.
  FILTER_CENTRE_BIAS) -- and the shift takes it to the pixel's corner (rule pixel_sample "corner"), its
  centre ("center"), plus the rule pixel_shift. Near clip: Cycles starts a camera ray on the plane
  z_cam = clip_start, so clip_start = d puts the origins on the image plane (rule ray_origin
  "image-plane"); for "camera" it is Blender's smallest, 1e-6. One sample per pixel, the box filter, no
  denoising, no adaptive sampling, seed 0: the same scene gives the same bytes (checked by the tests).
- Geometry buffers: the Position pass (world space, float32) gives the hit point and t = |P - o| along
  the reference's own ray from its own origin (Cycles' Depth pass is the distance along the view axis,
  not along the ray: measured); the Object Index pass gives the shape (pass_index = index + 1, 0 on a
  miss). The Normal pass is the shading normal, which Cycles turns toward the viewer on a back face; the
  reference's normal is the shape's own (outward for a ball, the plane's given normal), so a Cycles
  normal pointing against the shape's own is turned back.
- Light and units: Cycles' point light of power P radiates P / (4 pi) W/sr and its Diffuse BSDF is
  dc / pi. The light's power is 4 pi with colour lc -- radiant intensity lc, Mitsuba's point light --
  radius 0 and no soft falloff: a lit point's radiance is dc lc cos / (pi r^2). ``color`` and
  terms["diffuse"] (Diffuse Direct x Diffuse Color) are Cycles' numbers; aux["diffuse_exercise"] =
  terms["diffuse"] x pi r^2 (r from Cycles' own hit point to the light: aux["light_distance"]) is the
  exercise's n.s dc lc, compared per pixel by the harness. The export scales the light by pi d^2 (d the
  median distance from the light to the points the camera sees) so that a student's render is as bright
  as the exercise's image at that distance, as Mitsuba's export does.
- Mirrors: a Glossy BSDF of roughness 0 (a perfect mirror) of the reflection colour kr, added to the
  Diffuse BSDF; glossy bounces and all bounces = max_depth, no diffuse bounce (the exercise has no
  indirect diffuse light). Cycles picks one closure per bounce to continue a path, so with both lobes on a
  shape a one-sample reflection is noisy: its colour is compared statistically, never per pixel.
- Background: the world is the background colour, seen by camera and mirror rays that leave the scene
  (rule background "on-miss"; "none": black); it lights nothing (world importance sampling off, no
  diffuse bounce). It is never added at a hit ("on-hit" is not reproducible).
- Ambient and the Phong specular lobe: Cycles has neither; not simulated (meta["unsupported_terms"]).
- Shadows, offsets, sidedness: a shadow ray stops at the light ("to-light"); Cycles offsets no ray, it
  skips the primitive the ray leaves (the closest rule: "error-bound", along the normal); every surface
  shades on both faces with the normal toward the viewer ("two_sided" true) and max(0, n.s) ("clamp"
  true). Cycles culls the back faces of points (its Embree filter rejects a point's hit whose normal
  faces along the ray): a ball is invisible from inside, the exercise's near_root_only true -- measured
  on the bundled scene rules, whose ball crossing the image plane Cycles does not see from inside.
- Samples: ``spp`` > 1 renders Cycles' own sequence (sample 0 the pixel's filter centre, then its
  Sobol samples over the box filter's pixel square, the square the reference's stratified samples cover:
  no corner shift then). The harness's statistical comparison asks for ``mode = "sensor"`` (direct light
  only, the colour compared being the diffuse term) with the per-sample variance: each sample is then
  rendered on its own (``sample_offset``) and the mean and variance taken here.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from minirt.errors import MinirtError
from minirt.io.atomic import atomic_path
from minirt.io.names import scene_stem
from minirt.jobs import processes
from minirt.model import camera
from minirt.model.backend import GeometryTolerance, Margins, Series, Setting, Truth
from minirt.model.result import RenderResult, geometry_from_flat, to8
from minirt.model.rules import Rules
from minirt.model.scene import Ball, Plane, Scene
from minirt.oracles.base import Oracle, materials_use
from minirt.oracles.cycles import precision as pr
from minirt.oracles.cycles import run
from minirt.oracles.cycles import scene as cs

NAME = "cycles"
SPP = (1, 4, 16, 64, 256)  # the sweep's settings (samples per pixel)
CONVERGED_SPP = 4096  # the sweep's truth: Cycles' own render at this many samples ...
CONVERGED_SEED = 1  # ... with another seed than the rows' (0): it must not share their samples
VARIANCE_MAX_SPP = 256  # per-sample variance renders each sample on its own: at most this many
OPTIONS = ("spp", "seed", "mode", "timeout", "threads", "variance")
SHARED_OPTIONS = ("precision", "prune")  # options every backend is given that mean nothing here (float32)


def default_timeout(scene: Scene, samples: int) -> float:
    """Seconds one Blender run may take before it counts as hung: 60 s for starting Blender and building
    the scene, plus 20 us per pixel and sample. Measured: 64 x 64 at one sample renders in ~0.05 s inside
    Blender (~12 us a pixel, on a loaded 2-core machine), so this allows a machine or scene ~100x slower
    per sample; 256 x 256 at 4,096 samples gets ~1.5 hours. The option "timeout" overrides it."""
    return 60.0 + 2e-5 * scene.camera.width * scene.camera.height * max(1, samples)


def unsupported_terms(scene: Scene, rules: Rules, direct_only: bool) -> list[str]:
    out = [term for term in ("ambient", "specular") if materials_use(scene, term)]
    if any(v != 0 for v in scene.background) and rules.background != "on-miss":
        out.append("background")
    if direct_only and scene.max_depth > 0 and materials_use(scene, "reflection"):
        out.append("reflection")  # the statistical route renders direct light only
    return out


class CyclesOracle(Oracle):
    name: ClassVar[str] = NAME
    display_name: ClassVar[str] = "Cycles"
    shades: ClassVar[bool] = True
    shading_model: ClassVar[str | None] = "physical"
    float32: ClassVar[bool] = True
    concurrent: ClassVar[bool] = True  # Blender renders in a process of its own: beside the others in a check
    # Bytes a pixel (minirt.jobs.memory): a check keeps its render and figures, 1,400 as Mitsuba's -- measured
    # with /usr/bin/time -v, `minirt check exercise --size 1024x1024 -q` peaks at 2.26 GB with -b cycles and
    # 2.20 GB with -b mitsuba, the same run; a render keeps 220 and runs with 300 (the EXR's float32
    # channels, ~17 x 4, and their float64 buffers): `minirt render` of the same peaks at 0.78 GB against
    # Mitsuba's 0.92 GB. Blender's own memory is in its own process, not counted (as POV-Ray's).
    check_kept: ClassVar[int] = 1400
    render_kept: ClassVar[int] = 220
    render_running: ClassVar[int] = 300
    export_as: ClassVar[str | None] = "blender"
    export_what: ClassVar[str] = ".blend"
    supported: ClassVar[dict[str, tuple[Any, ...]]] = {
        # the world colour on a miss (camera and mirror rays), or black; never added at a hit
        "background": ("on-miss", "none"),
        # Cycles culls a point's back face (its Embree filter rejects hits whose normal faces along the ray):
        # from inside, a ball is invisible, and a ray crossing the image plane inside one sees what is beyond
        "near_root_only": (True,),
        "shadow_range": ("to-light",),  # a shadow ray stops at the light
        "two_sided": (True,),  # back faces shade with the normal toward the viewer
        "clamp": (True,),  # BSDFs are 0 below the surface: max(0, n.s)
        "offset": ("error-bound",),  # no offset: the primitive a ray leaves is skipped (the closest rule)
        "offset_along": ("normal",),  # ("ray" needs a numeric offset)
        # rules from real solutions' bugs: a renderer has neither a finite "infinity" nor unnormalised normals
        "t_max": (math.inf,),
        # ray_origin, pixel_sample, pixel_shift: any (the near clip and the camera's shift)
        # specular_exponent: any (no specular lobe: unsupported_terms)
    }

    def available(self) -> tuple[bool, str]:
        if run.blender_python() is None:
            return False, run.INSTALL_HINT
        try:
            return True, self.version()
        except Exception as e:  # a broken install: say so, do not raise
            return False, " ".join(str(e).split())[:300]

    def version(self) -> str:
        return f"Blender {run.version()} (Cycles, CPU)"

    def options(self, precision: str = "f64", samples: int | None = None, timeout: float | None = None) -> dict:
        """--samples N: Cycles' own N samples per pixel (its stochastic image, colour only); --timeout
        SECONDS: Blender is killed after that long (an ERROR verdict)."""
        opts: dict[str, Any] = {"precision": precision}
        if samples:
            opts["spp"] = samples
        if timeout is not None:
            opts["timeout"] = timeout
        return opts

    @staticmethod
    def _options(options: dict[str, Any] | None) -> dict[str, Any]:
        given = dict(options or {})
        ignored = {k: given.pop(k) for k in SHARED_OPTIONS if k in given}
        opts = {"spp": 1, "seed": 0, **given}
        unknown = sorted(set(opts) - set(OPTIONS))
        if unknown:
            raise ValueError(f"unknown option(s) {', '.join(unknown)} (known: {', '.join(OPTIONS)})")
        for key, lo in (("spp", 1), ("seed", 0)):
            v = opts[key]
            if isinstance(v, bool) or not isinstance(v, int) or v < lo:
                raise ValueError(f"{key} must be an integer >= {lo}, got {v!r}")
        if opts.get("mode", "sensor") != "sensor":
            raise ValueError(f"mode must be 'sensor' (direct light, per-sample variance), got {opts['mode']!r}")
        if ignored:
            opts["ignored"] = ignored
        return opts

    # ---- render ------------------------------------------------------------------------------
    def render(self, scene: Scene, rules: Rules, options: dict[str, Any] | None = None, progress=None) -> RenderResult:
        w, h = scene.camera.width, scene.camera.height
        try:
            opts = self._options(options)
        except ValueError as e:
            return RenderResult.failed(NAME, w, h, "error", str(e))

        def fail(status: str, reason: str) -> RenderResult:
            return RenderResult.failed(NAME, w, h, status, reason, scene=scene.name, options=opts)

        ok, why = self.available()
        if not ok:
            return fail("skip", why)
        bad = self.cannot_follow(rules)
        if bad:
            return fail("skip", f"Cycles cannot follow rule(s) {', '.join(bad)}: render under adapt(rules)")
        if max(w, h) / min(w, h) > 200:
            return fail("skip", f"{w}x{h}: Blender's pixel aspect ratio is at most 200")
        try:
            with processes.temporary_folder("minirt-cycles-") as folder:
                if opts["spp"] == 1 and "mode" not in opts:
                    return self._one_sample(scene, rules, opts, folder)
                return self._samples(scene, rules, opts, folder)
        except FileNotFoundError as e:
            return fail("skip", (str(e).splitlines() or [run.INSTALL_HINT])[0])
        except run.CyclesError as e:
            return fail("error", str(e))
        except Exception as e:  # never raise out of render()
            return fail("error", f"{type(e).__name__}: {(str(e).splitlines() or [''])[0]}")

    def _meta(self, scene: Scene, rules: Rules, opts: dict, said: dict, quads: dict, extra: dict) -> dict[str, Any]:
        size = cs.scene_size(scene)
        return {
            "backend": NAME,
            "version": f"Blender {said['blender']} (Cycles, CPU)",
            "scene": scene.name,
            "scene_sha256": scene.digest,
            "settings": {"width": scene.camera.width, "height": scene.camera.height, "max_depth": scene.max_depth,
                         "filter": "box", "denoising": False, "adaptive_sampling": False},
            "options": opts,
            "rules": rules.as_dict(),
            "emitter": {"type": "point", "power": cs.LIGHT_POWER, "color": list(scene.light.color),
                        "radiant_intensity": list(scene.light.color), "position": list(scene.light.position)},
            "planes": {f"shape{k}": q.describe(size) for k, q in quads.items()},
            "camera": cs.camera_job(scene, rules, int(opts["spp"])),
            "timings": {"blender_setup": said["timings"]["setup"], "render": said["timings"]["render"],
                        "process": said["wall"]},
            **extra,
        }  # fmt: skip

    # one piece: two Blender jobs (a black world for the buffers and the diffuse term, the scene's world for
    # the colour) whose outputs are read back and combined into one result, in that order
    def _one_sample(self, scene: Scene, rules: Rules, opts: dict, folder: Path) -> RenderResult:
        """One sample per pixel on the rules' rays: geometry, Cycles' colour and its diffuse term."""
        w, h = scene.camera.width, scene.camera.height
        t0 = time.perf_counter()
        quads = cs.quads(scene, rules)
        world = scene.background if rules.background == "on-miss" else (0.0, 0.0, 0.0)
        job = cs.job(scene, rules, quads, spp=1, world=world)
        job["seed"] = opts["seed"]
        job["threads"] = opts.get("threads")
        job["passes"] = ["position", "normal", "object_index", "diffuse_direct", "diffuse_color"]
        # The buffers and the diffuse term from a render whose world is black; the colour from one whose world
        # is the background (when it shows). Cycles splits the light a mirror ray brings back from the world
        # between the diffuse and glossy passes by the two lobes' values in its direction over their pdfs
        # (a perfect mirror's is a large finite number): ~1e-6 of lc dc leaked into Diffuse Direct on shadowed
        # mirror-floor pixels of three_balls, where the exercise's diffuse term is exactly 0.
        job["renders"] = [{"sample_offset": 0, "exr": str(folder / "render.exr"), "world": [0.0, 0.0, 0.0]}]
        if any(v != 0 for v in world):
            job["renders"].append({"sample_offset": 0, "exr": str(folder / "color.exr")})
        t_job = time.perf_counter() - t0
        said = run.run_job(job, folder, float(opts.get("timeout") or default_timeout(scene, 1)))
        t0 = time.perf_counter()
        ch = run.read_exr(folder / "render.exr", w, h, cs.canvas(scene))
        o, d = camera.primary_rays(scene, rules)

        def vec(name: str, keys: str = "XYZ") -> np.ndarray:
            return np.stack([ch[f"{name}.{k}"] for k in keys], axis=-1).astype(np.float64).reshape(-1, len(keys))

        sid = np.rint(ch["Object Index.X"].astype(np.float64)).astype(np.int64).reshape(-1) - 1
        sid = np.where((sid >= 0) & (sid < len(scene.shapes)), sid, -1)
        p = vec("Position") * cs.MIRROR
        n = vec("Normal") * cs.MIRROR
        n = _unflip(scene, sid, p, n)
        t = np.linalg.norm(p - o, axis=1)  # along the reference's ray, from its origin
        geom = geometry_from_flat(w, h, sid, t, p, n)
        if len(job["renders"]) > 1:
            ch_color = run.read_exr(folder / "color.exr", w, h, cs.canvas(scene))
            color = np.stack([ch_color[f"Combined.{k}"] for k in "RGB"], axis=-1).astype(np.float64)
        else:
            color = vec("Combined", "RGB").reshape(h, w, 3)
        diffuse = (vec("Diffuse Direct", "RGB") * vec("Diffuse Color", "RGB")).reshape(h, w, 3)
        light = np.asarray(scene.light.position, dtype=np.float64)
        r = np.where(geom["hit"], np.linalg.norm(geom["position"] - light, axis=-1), 0.0)
        to_ex = math.pi * r * r
        diffuse_x = diffuse * to_ex[..., None]
        hitm = geom["hit"][..., None]
        terms = {"diffuse": diffuse, "reflection": np.where(hitm, color - diffuse, 0.0)}
        if rules.background == "on-miss":
            terms["background"] = np.where(hitm, 0.0, color)
        e_o = pr.origin_error(scene.camera.distance, o)
        aux = {
            "t_silhouette_bound": pr.silhouette_t_bound(scene, o, d, sid).reshape(h, w),
            "hit_cos": pr.hit_cos(scene, o, d, sid).reshape(h, w),
            "light_distance": r,
            "diffuse_to_exercise": to_ex,
            "diffuse_exercise": diffuse_x,
        }
        scales = pr.band_scales(scene, o, e_o)
        disc, ray = pr.shape_eps(scene, o, e_o)
        cam = cs.camera_job(scene, rules)
        corner_cos = scene.camera.distance / math.sqrt(scene.camera.distance**2 + 0.5)
        extra = {
            "passes": job["passes"],
            "spp": 1,
            "unsupported_terms": unsupported_terms(scene, rules, direct_only=False),
            "image8_shows": "diffuse x pi r^2 and background only",
            "precision": {
                "t_rel": pr.T_REL,
                "dir_err": pr.DIR_ERR,
                "origin_err": e_o,
                "normal_floor_deg": pr.NORMAL_FLOOR_DEG,
                "band_eps": max([a + b for a, b in zip(disc, ray, strict=True)], default=pr.U32),
                "band_k": pr.BAND_K,
                "band_scale": scales["scale"],
                "band_inside_scale": scales["inside"],
                "band_origin_scale": scales["origin"],
                "band_tie_scale": scales["tie"],
                "radius": [s.radius if isinstance(s, Ball) else 0.0 for s in scene.shapes],  # the normal bound's 1/r
                # Cycles starts a camera ray on the plane z_cam = clip_start: along the ray, at most this far
                "min_distance": 0.0 if rules.ray_origin == "image-plane" else cam["clip_start"] / corner_cos,
                "why": (
                    "float32 camera rays (direction within dir_err of the reference's, origin within origin_err), "
                    "Embree's float32 sphere points in their stable form (t_rel; near a silhouette the error of "
                    "r^2 - |perp|^2, u32 (4|f| + |C| + r) r: aux t_silhouette_bound), quads interpolating float32 "
                    "corners (meta planes abs_error); each shape's band from its intersector's error and the "
                    "ray's displacement (oracles/cycles/precision.py)"
                ),
            },
            "aux": {
                "t_silhouette_bound": "the margin-dependent part of the t error bound on balls",
                "hit_cos": "|cos| of the incidence on the shape hit, on the exact ray (1 on a miss)",
                "light_distance": "r: from Cycles' hit point to the light (0 on a miss)",
                "diffuse_to_exercise": "pi r^2: terms.diffuse * pi r^2 = n.s dc lc (radiant intensity lc)",
                "diffuse_exercise": "terms.diffuse * pi r^2: the exercise's diffuse term",
            },
        }
        meta = self._meta(scene, rules, opts, said, quads, extra)
        meta["timings"].update(job=t_job, read=time.perf_counter() - t0)
        shown = np.where(hitm, diffuse_x, terms.get("background", 0.0))
        return RenderResult(backend=NAME, width=w, height=h, color=color, terms=terms, aux=aux,
                            image8=to8(shown), meta=meta, **geom)  # fmt: skip

    def _samples(self, scene: Scene, rules: Rules, opts: dict, folder: Path) -> RenderResult:
        """Cycles' own samples: colour only. With ``mode = "sensor"`` (the harness's statistical route) or
        ``variance``, direct light only and each sample rendered on its own, for the per-sample variance."""
        w, h = scene.camera.width, scene.camera.height
        spp = int(opts["spp"])
        direct = opts.get("mode") == "sensor"
        variance = direct or bool(opts.get("variance"))
        if variance and spp > VARIANCE_MAX_SPP:
            raise ValueError(f"per-sample variance renders each sample on its own: spp at most {VARIANCE_MAX_SPP}")
        quads = cs.quads(scene, rules)
        # Direct light only: no bounce, and a black world -- even without a bounce Cycles follows the ray a
        # mirror lobe samples, to meet what emits there, and a world the background colour would shine in
        # every mirror as direct light (fuzz start_27_0: 100 times the diffuse term on its mirror plane).
        world = scene.background if rules.background == "on-miss" and not direct else (0.0, 0.0, 0.0)
        job = cs.job(scene, rules, quads, spp=spp, bounces=0 if direct else None, world=world)
        job["seed"] = opts["seed"]
        job["threads"] = opts.get("threads")
        # Cycles writes its data passes (the object index) for sample 0 alone: coverage is the alpha of a
        # transparent film instead (1 where the camera ray hit, 0 where it missed; misses are never compared)
        job["transparent"] = variance
        if variance:
            job["renders"] = [{"sample_offset": i, "samples": 1, "exr": str(folder / f"s{i}.exr")} for i in range(spp)]
        else:
            job["renders"] = [{"sample_offset": 0, "samples": spp, "exr": str(folder / "render.exr")}]
        said = run.run_job(job, folder, float(opts.get("timeout") or default_timeout(scene, spp)))
        t0 = time.perf_counter()
        aux: dict[str, np.ndarray] = {}
        if variance:
            total = np.zeros((h, w, 3))
            square = np.zeros((h, w, 3))
            covered = np.zeros((h, w))
            for r in job["renders"]:
                ch = run.read_exr(Path(r["exr"]), w, h, cs.canvas(scene))
                c = np.stack([ch[f"Combined.{k}"] for k in "RGB"], axis=-1).astype(np.float64)
                total += c
                square += c * c
                covered += ch["Combined.A"]
            color = total / spp
            aux["variance"] = np.maximum(square / spp - color * color, 0.0)
            aux["coverage"] = covered / spp
        else:
            ch = run.read_exr(folder / "render.exr", w, h, cs.canvas(scene))
            color = np.stack([ch[f"Combined.{k}"] for k in "RGB"], axis=-1).astype(np.float64)
        extra = {
            "spp": spp,
            "seed": opts["seed"],
            "unsupported_terms": unsupported_terms(scene, rules, direct_only=direct),
            "sampling": "Cycles' own samples over the box filter's pixel square"
            + (", one render each (per-sample variance)" if variance else ""),
        }
        if variance:
            extra["variance"] = "per-sample variance of the colour (divide by spp for the mean's variance)"
        meta = self._meta(scene, rules, opts, said, quads, extra)
        meta["timings"]["read"] = time.perf_counter() - t0
        terms = {"diffuse": color.copy()} if direct else {}
        return RenderResult(backend=NAME, width=w, height=h, color=color, terms=terms, aux=aux, meta=meta)

    # ---- geometry tolerance -------------------------------------------------------------------
    def geometry_tolerance(self, result: RenderResult, ref: RenderResult, measured: Margins) -> GeometryTolerance:
        """This oracle's recorded precision as per-pixel tolerances, each with its derivation."""
        h, w = ref.height, ref.width
        p = result.meta.get("precision") or {}
        m = measured.image(h, w)
        t_ref = np.where(ref.hit, ref.t, 0.0)
        e_o, dir_err = p["origin_err"], p["dir_err"]
        planes = result.meta.get("planes") or {}
        plane_abs = np.zeros((h, w))
        plane_normal = max([pl.get("normal_error", 0.0) for pl in planes.values()] or [0.0])
        for key, pl in planes.items():
            plane_abs[ref.shape_id == int(key.removeprefix("shape"))] = pl["abs_error"]
        ties = None
        eps = p["band_k"] * p["band_eps"]
        if measured.scaled is not None and p.get("band_scale"):
            band, ties = measured.per_shape_band(p, h, w)
        else:
            band = measured.below("margin", eps, h, w)
        # Whether a candidate counts (t > 0, or beyond the near clip): a plane's quad lies within its
        # normal_error of the plane, and Cycles' ray starts within origin_err of the reference's, plus the
        # reference origin's own rounding to float32 (4 u32 |o|); a ball's origin band covers its own.
        start_err = plane_normal + e_o + 4 * pr.U32 * m["origin_norm"]
        starts = measured.start_band(h, w, t_min=p.get("min_distance", 0.0), plane_err=start_err.reshape(-1),
                                     ball_err=e_o)  # fmt: skip
        band = band | starts
        # t: the float32 root (t_rel t), the quad's interpolation (its abs_error, and along a plane's ray by
        # 1/|n·d|), the ray's displacement e_o + dir_err t met at the incidence's cosine, the hit point's
        # float32 rounding (8 u32 (|o| + t)) and, near a ball's silhouette, the intersector's error. The
        # cosine is that of the shape hit (aux hit_cos), not of the nearest candidate (margins' hit_cos).
        cos = np.maximum(result.aux.get("hit_cos", m["hit_cos"]), 1e-300)
        with np.errstate(divide="ignore", invalid="ignore"):
            t_abs = (
                p["t_rel"] * t_ref
                + plane_abs
                + (plane_abs + e_o + dir_err * t_ref) / cos
                + 8 * pr.U32 * (m["origin_norm"] + t_ref)
                + result.aux.get("t_silhouette_bound", 0.0)
            )
        nb = pr.ball_normal_bound(p["radius"], t_ref, ref.shape_id, e_o, cos, m["origin_norm"])
        nd = np.degrees(np.minimum(nb, math.pi)) + p["normal_floor_deg"]
        why = {
            "band": f"margin < each shape's own band (at most band_k*band_eps = {eps:.3g}): the float32 "
            "intersector's error (exact in the margin) and the camera ray's displacement (origin_err + "
            f"dir_err |f|)/r; or a candidate within {plane_normal:.3g} + origin_err + 4 u32 |o| of the near "
            "clip (a quad's float32 plane, Cycles' ray origin)",
            "t": f"t_rel*t + abs + (abs + origin_err + dir_err*t)/cos + 8 u32 (|o| + t) = {p['t_rel']:.3g}*t "
            f"+ quad abs_error (<= {float(plane_abs.max()):.3g}) + (abs + {e_o:.3g} + {dir_err:.3g}*t)/cos, cos the "
            "incidence on the shape hit (aux hit_cos: |n·d| on a plane); + per pixel "
            "4 u32 (4|f| + |C| + r)/sqrt(2m) near a ball's silhouette (aux t_silhouette_bound)",
            "normal": f"{p['normal_floor_deg']} deg (float32 normals) + on balls the hit point's displacement "
            "over r: ((origin_err + dir_err*t)/cos + 8 u32 (|o| + t))/r",
        }
        summary = {
            "band_eps": eps,
            "t_rel": p["t_rel"],
            "dir_err": dir_err,
            "origin_err": e_o,
            "plane_abs": float(plane_abs.max()),
            "plane_normal_error": plane_normal,
            "normal_deg_max": float(nd.max()),
            "start_band_pixels": int(starts.sum()),
        }
        return GeometryTolerance(band=band, t_abs=t_abs, normal_deg=nd, why=why, summary=summary, ties=ties)

    # ---- export -------------------------------------------------------------------------------
    def export(self, scene: Scene, rules: Rules, out_dir: Path, options: dict[str, Any] | None = None) -> list[Path]:
        """SCENE.blend: the scene as a Blender user opens it -- camera, light, materials named as in the
        scene file, the world the background colour -- rendering with Cycles as the oracle does (one
        sample per pixel unless the scene asks for more), the light scaled by pi d^2 for viewing (the
        package's docstring: Light and units)."""
        path = Path(out_dir) / f"{scene_stem(scene)}.blend"
        quads = cs.quads(scene, rules)
        d = cs.viewing_distance(scene, rules)
        world = scene.background if rules.background == "on-miss" else (0.0, 0.0, 0.0)
        job = cs.job(scene, rules, quads, spp=scene.samples, world=world,
                     intensity_scale=math.pi * d * d if d else 1.0)  # fmt: skip
        job["passes"] = ["position", "normal", "object_index", "diffuse_direct", "diffuse_color"]
        # Blender saves straight into the destination's folder, under atomic_path's temporary name (never
        # moved there from $TMPDIR: across file systems a move copies into a symlink's target).
        with processes.temporary_folder("minirt-cycles-") as folder, atomic_path(path) as tmp:
            tmp.unlink()  # Blender keeps a file it saves over as NAME.blend1 (its save versions): none here
            job["blend"] = str(tmp)
            try:
                run.run_job(job, folder, default_timeout(scene, 1))
                if not run.whole_blend(tmp):
                    raise run.CyclesError("Blender saved it cut short (a full disk?)")
            except run.CyclesError as e:  # one line naming the .blend (atomic_path: never the temporary name)
                raise MinirtError(f"{tmp}: cannot write the Blender file: {e}") from None
            finally:  # what Blender leaves of a failed save: its own temporary file NAME@, a version NAME1
                for left in (f"{tmp}@", f"{tmp}1"):
                    Path(left).unlink(missing_ok=True)
        return [path]

    # ---- the sweep (minirt.sweep): what accuracy costs in time ---------------------------------
    sweep_knobs: ClassVar[dict[str, Any]] = {"spp": SPP, "converged_spp": CONVERGED_SPP}

    def sweep(self, scene: Scene, rules: Rules, knobs: dict[str, Any]) -> list[Series]:
        """One knob, spp: samples per pixel against Cycles' own render at ``converged_spp`` (another seed):
        its shading is a physical model, not the exercise's, so only Cycles can be its own limit; errors
        after matching exposure ("color_exposure"), as Mitsuba's."""
        k = self.turned(knobs)
        n = k["converged_spp"]
        followed = self.adapt(rules)
        truth = Truth(f"cycles/{n}spp", self.name, {"spp": n, "seed": CONVERGED_SEED},
                      describe={"spp": n, "seed": CONVERGED_SEED})  # fmt: skip
        settings = tuple(
            Setting(s, s, {"spp": s, "seed": 0}, f"Cycles at {s} spp", f"cycles {s} spp") for s in k["spp"]
        )
        return [
            Series(self.name, "spp", settings, followed, truth, "color_exposure", metric="rmse",
                   cost="samples per pixel",
                   theory="spp^-0.5, or faster where Cycles' stratified (Sobol-Burley) samples help",
                   knobs={"cycles_spp": k["spp"], "converged_cycles_spp": n})
        ]  # fmt: skip


def _unflip(scene: Scene, sid: np.ndarray, p: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Cycles' normals with its turn toward the viewer undone: against the shape's own outward normal at
    Cycles' hit point (a ball's P - C, a plane's given normal), a normal pointing the other way is negated."""
    own = np.zeros_like(n)
    for k, s in enumerate(scene.shapes):
        on = sid == k
        if isinstance(s, Ball):
            own[on] = p[on] - np.asarray(s.center)
        elif isinstance(s, Plane):
            own[on] = np.asarray(s.normal)
    back = np.einsum("ij,ij->i", n, own) < 0
    return np.where(back[:, None], -n, n)
