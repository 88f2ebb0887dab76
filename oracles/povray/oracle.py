"""The POV-Ray oracle: PovrayOracle, the Backend that runs the exported scene and reads it back, and
turns its recorded precision into per-pixel tolerances (geometry_tolerance). The conventions it bridges
are the package docstring's (minirt.oracles.povray); the pieces it puts together are the package's
other modules.
"""

from __future__ import annotations

import math
import os
import shlex
import shutil
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from minirt.errors import MinirtError
from minirt.io.images import read_image, read_image_u8
from minirt.jobs import processes
from minirt.model.backend import (
    GeometryTolerance,
    Margins,
    Series,
    Setting,
    Truth,
    farthest_hit,
    tolerance_inputs,
)
from minirt.model.effects import effects
from minirt.model.result import RenderResult
from minirt.model.rules import Rules
from minirt.model.scene import Ball, Scene
from minirt.oracles.base import Oracle
from minirt.oracles.povray import accuracy
from minirt.oracles.povray.buffers import color_frames, decode_geometry, encoding_ranges, geometry_frames
from minirt.oracles.povray.exporter import export, scene_to_pov
from minirt.oracles.povray.rays import (
    MAX_DISTANCE,
    between_camera_and_image_plane,
    mesh_reach,
    too_many_mesh_rays,
    uses_mesh_camera,
)
from minirt.oracles.povray.runner import (
    INSTALL_HINT,
    MAX_ANTIALIAS,
    NAME,
    PovrayError,
    command,
    default_timeout,
    frame_files,
    povray_version,
    run_povray,
)


class PovrayOracle(Oracle):
    name: ClassVar[str] = NAME
    shades: ClassVar[bool] = True
    display_name: ClassVar[str] = "POV-Ray"
    shading_model: ClassVar[str | None] = "exercise"
    concurrent: ClassVar[bool] = True  # its render is a process of its own: it overlaps the others' in a check
    # a check keeps its render and figures (1,400 bytes a pixel); a render keeps 60 and runs with 40 (its
    # working buffers are in its own process): measured with the others (minirt.jobs.memory)
    check_kept: ClassVar[int] = 1400
    render_kept: ClassVar[int] = 60
    render_running: ClassVar[int] = 40
    export_as: ClassVar[str | None] = "povray"
    export_what: ClassVar[str] = ".pov + command"
    supported: ClassVar[dict[str, tuple[Any, ...]]] = {
        # folded into ambient, or a background statement; "none": neither
        "background": ("on-hit", "on-miss", "none"),
        "near_root_only": (False,),  # it sees the inside of balls
        "shadow_range": ("to-light",),  # only objects before the light block
        "two_sided": (True,),  # normals flipped to face the viewer
        "clamp": (True,),  # light skipped when n·l < 1e-10, phong only when r·l > 0
        "offset": ("error-bound",),  # its own epsilons (1e-3 for shadow rays): the closest rule
        "offset_along": ("normal",),  # (its epsilons are distances along the ray; "ray" needs a number)
        "ray_origin": ("image-plane", "camera"),  # image-plane: skip when something is in between
        "pixel_sample": ("corner", "center"),  # skewed or plain direction vector
        # The skewed direction vector is written for the unshifted grid only (the mesh camera would follow).
        "pixel_shift": ((0.0, 0.0),),
        # rules from real solutions' bugs: a renderer has neither a finite "infinity" nor unnormalised normals
        "t_max": (math.inf,),
        # specular_exponent: any, as phong_size (POV-Ray's phong is (r·l)^phong_size, only where r·l > 0).
    }

    def available(self) -> tuple[bool, str]:
        if shutil.which("povray") is None:
            return False, INSTALL_HINT
        try:
            return True, self.version()
        except Exception as e:  # a broken install: say so, do not raise
            return False, f"povray found but not runnable: {e}"

    def version(self) -> str:
        exe = shutil.which("povray")
        if exe is None:
            raise FileNotFoundError(INSTALL_HINT)
        st = os.stat(exe)
        v = povray_version(exe, st.st_mtime_ns, st.st_size)
        if isinstance(v, Exception):
            raise v
        return v

    # ---- render -------------------------------------------------------------------------
    def options(self, precision: str = "f64", samples: int | None = None, timeout: float | None = None) -> dict:
        """--timeout SECONDS: POV-Ray's process is killed after that long (an ERROR verdict)."""
        opts: dict[str, Any] = {"precision": precision}
        if timeout is not None:
            opts["timeout"] = timeout
        return opts

    def geometry_tolerance(self, result: RenderResult, ref: RenderResult, measured: Margins) -> GeometryTolerance:
        """This oracle's recorded precision as per-pixel tolerances, each with its derivation."""
        h, w, p, m, t_ref = tolerance_inputs(result, ref, measured)
        ties = None
        eps = p["band_threshold"]
        # its minimum distance along the harness's rays and its position error there (oracles.povray.start_decision)
        t_min, start_err = p.get("min_distance", 0.0), p.get("start_err", 0.0)
        starts = measured.start_band(h, w, t_min=t_min, plane_err=start_err, ball_err=start_err)
        if measured.scaled is not None and p.get(
            "band_scale"
        ):  # each shape's own threshold (oracles.povray.band_scales)
            band, ties = measured.per_shape_band(p, h, w)
            band = band | starts
        else:
            band = measured.below("margin", eps, h, w) | starts
        # POV-Ray drops hits beyond MAX_DISTANCE 1e7 from its ray's origin (a pinhole ray's origin is the
        # camera, up to max_distance_lift before the harness's): where the nearest candidate lies that far,
        # POV-Ray misses what the reference hits -- a decision it cannot make, like its minimum distance
        # (fuzz far_2026_6: rays starting just inside a ground of radius 4.5e7 meet its far side 1.04e7 away).
        if "max_distance" in p:
            band |= np.isfinite(m["near"]) & (m["near"] >= farthest_hit(p))
        # plus the conditioning of the hit: a ray whose origin and direction err by dir_err (R + t) -- the mesh
        # camera's single-precision rays, R its origins' reach -- meets a surface dir_err (R + t)/cos away, cos = |n·d|
        # at the hit, ball or plane (fuzz start_2026_83: a ball met at an angle, dt 1.65e-6 > t_abs 1.54e-6)
        # and POV-Ray's own sphere root, 12 2^-53 |f|^2/(r cos) along the ray (oracles.povray.root_errors; fuzz
        # f32_2026_22: a ball 2.4e4 away, its hit 8.6e-7 off along the ray near its silhouette), which turns
        # the normal (P - C)/r by as much over r
        root = np.zeros((h, w))
        root_n = np.zeros((h, w))
        if p.get("root_err"):
            # ids the scene does not have (a defective reference's, fuzz --defects ids-swapped on a one-ball
            # scene) get no root term: those pixels are id mismatches, never compared in t or normal
            n_shapes = len(p["root_err"])
            ids = np.where(ref.hit & (ref.shape_id < n_shapes), ref.shape_id, -1)
            k = np.maximum(ids, 0)
            per_t = np.asarray(p["root_err"], dtype=np.float64)[k]
            per_n = np.asarray(p.get("root_normal_err", np.zeros(len(p["root_err"]))), dtype=np.float64)[k]
            with np.errstate(divide="ignore", invalid="ignore"):
                root = np.where(ids >= 0, per_t / m["hit_cos"], 0.0)
                root_n = np.where(ids >= 0, per_n / m["hit_cos"], 0.0)
        with np.errstate(divide="ignore"):
            t_abs = p["t_abs"] + p.get("dir_err", 0.0) * (p.get("ray_reach", 1.0) + t_ref) / m["hit_cos"] + root
        deg = math.degrees(math.asin(min(1.0, 2 * p["normal_abs"]))) + 1e-9
        nd = np.degrees(np.arcsin(np.minimum(1.0, 2 * (p["normal_abs"] + root_n)))) + 1e-9
        why = {
            "band": f"margin < each shape's own threshold (at most {eps:.3g}): single-precision bounding boxes "
            "and textbook sphere roots in POV-Ray, its mesh camera's single-precision rays; "
            f"or a candidate hit with t cos within {start_err:.3g} of [0, {t_min:.3g}] (POV-Ray drops hits within "
            "its minimum distance 1e-4 of a mesh-camera ray's origin; its rays are off by start_err there)",
            "t": f"|dt| <= {p['t_abs']:.3g} + {p.get('dir_err', 0.0):.3g}*(R + t)/|n·d| (n at the hit, R = ray_reach) "
            "+ 12 2^-53 |f|^2/(r |n·d|) (POV-Ray's textbook sphere root, |f| from its ray's origin to the centre): "
            f"{p.get('derivation', '')}",
            "normal": f"{deg:.3g} deg: normals from decoded positions, |dn| <= {p['normal_abs']:.3g}, plus per pixel "
            "POV-Ray's root error over r: 12 2^-53 |f|^2/(r^2 |n·d|)",
        }
        summary = {
            "band_eps": eps,
            "t_abs": p["t_abs"],
            "normal_deg": deg,
            "min_distance": t_min,
            "start_band_pixels": int(starts.sum()),
        }
        return GeometryTolerance(band=band, t_abs=t_abs, normal_deg=nd, why=why, summary=summary, ties=ties)

    def render(self, scene: Scene, rules: Rules, options: dict[str, Any] | None = None, progress=None) -> RenderResult:
        opts = dict(options or {})
        w, h = scene.camera.width, scene.camera.height
        meta: dict[str, Any] = {"scene": scene.name, "rules": rules.as_dict(), "options": opts}

        def fail(status: str, reason: str) -> RenderResult:
            extra = {k: v for k, v in meta.items() if k != "backend"}
            return RenderResult.failed(NAME, w, h, status, reason, **extra)

        if shutil.which("povray") is None:
            return fail("skip", INSTALL_HINT)
        bad = self.cannot_follow(rules)
        if bad:
            return fail("skip", f"POV-Ray cannot follow rule(s): {', '.join(bad)}")
        samples = opts.get("samples", 1)
        if not (isinstance(samples, int) and not isinstance(samples, bool) and samples >= 1):
            return fail("error", f"samples must be an integer >= 1, got {samples!r}")
        if opts.get("antialias") is not None and samples > 1:
            return fail("error", "antialias and samples exclude each other (POV-Ray's own grid, or the exercise's)")
        too_many = too_many_mesh_rays(scene, samples)
        if too_many:
            return fail("skip", too_many)
        if opts.get("antialias") is not None and uses_mesh_camera(scene, rules):
            between = ", ".join(map(str, between_camera_and_image_plane(scene)))
            return fail("skip", f"object between camera and image plane (shape {between}) needs a mesh camera, "
                                "which cannot antialias")  # fmt: skip
        try:
            return self._render(scene, rules, opts, meta)
        except FileNotFoundError as e:
            return fail("skip", (str(e).splitlines() or [INSTALL_HINT])[0])
        except PovrayError as e:
            return fail("error", str(e))
        except Exception as e:  # never raise out of render()
            msg = (str(e).splitlines() or [""])[0]
            return fail("error", f"{type(e).__name__}: {msg}")

    def _render(self, scene: Scene, rules: Rules, opts: dict[str, Any], meta: dict[str, Any]) -> RenderResult:
        w, h = scene.camera.width, scene.camera.height
        samples, threads, geometry, antialias = _render_options(opts)
        t_start = time.perf_counter()
        fx = effects(scene, rules)
        cframes = color_frames(scene, rules)
        gframes = geometry_frames(scene) if geometry and scene.shapes else []
        frames = cframes + gframes
        timeout = float(opts.get("timeout") or default_timeout(scene, len(frames), samples))
        ranges = encoding_ranges(scene, rules) if gframes else None
        text = scene_to_pov(scene, rules, frames, ranges, samples)
        mesh = uses_mesh_camera(scene, rules, samples)
        meta.update(
            backend=NAME,
            version=self.version(),
            # one ray per pixel (-A): POV-Ray's antialiasing jitters its own grid, not the exercise's pattern
            settings={"width": w, "height": h, "max_depth": scene.max_depth, "timeout": timeout,
                      "samples_requested": scene.samples, "samples_rendered": samples if antialias is None else None,
                      "sampling": ("the exercise's stratified samples, one camera mesh each" if samples > 1 else
                                   "POV-Ray's jittered antialiasing grid" if antialias is not None else "one ray"),
                      "antialias": antialias,
                      "channel_mode": "per-channel" if len(cframes) == 3 else "rgb",
                      "frames": [f.label for f in frames], "max_trace_level": scene.max_depth + 1 if fx.reflection
                      else 1, "camera": "mesh_camera" if mesh else "perspective"},
            effects={"simulated": fx.simulated(), "skipped": fx.skipped(), **fx.as_dict()},
        )  # fmt: skip
        passes: list[dict[str, Any]] = []
        timings: dict[str, Any] = {"export": time.perf_counter() - t_start}
        with processes.temporary_folder("minirt-povray-") as cwd:
            (cwd / "scene.pov").write_text(text)
            n = len(frames)
            # One EXR animation: float colour frames and geometry frames, +UA for the hit mask.
            cmd_exr = command(scene, n, 1, n, "exr", threads=threads, antialias=antialias, mesh_camera=mesh)
            png_pass = antialias is None
            # The 8-bit PNG of the colour frames: POV-Ray's own rounding, exact. The two passes are
            # independent processes (their own output files, the same .pov read): run side by side, so
            # one's single-threaded parse and start-up overlap the other's trace (both cores busy).
            cmd_png = (
                command(scene, n, 1, len(cframes), "png8", threads=threads, mesh_camera=mesh) if png_pass else None
            )
            with ThreadPoolExecutor(max_workers=2) as pool:
                jobs = [pool.submit(run_povray, c, cwd, timeout) for c in (cmd_exr, cmd_png) if c is not None]
                done = [j.result() for j in jobs]  # the first failure raises, in pass order
            passes.append({"name": "exr", "frames": [f.label for f in frames], "command": shlex.join(cmd_exr),
                           "timings": done[0][1]})  # fmt: skip
            if cmd_png is not None:
                passes.append({"name": "png8", "frames": [f.label for f in cframes],
                               "command": shlex.join(cmd_png), "timings": done[1][1]})  # fmt: skip
            t0 = time.perf_counter()
            color, color8, geom = _read_frames(scene, rules, cwd, cframes, gframes, ranges, mesh, png_pass)
            timings["decode"] = time.perf_counter() - t0
        # The passes run side by side: setup, parse and trace are sums over them (each process's own
        # time), total is the wall time of the whole render.
        timings.update(_pass_timings(passes))
        timings["total"] = time.perf_counter() - t_start
        meta.update(passes=passes, commands=[p["command"] for p in passes], timings=timings)
        if gframes or geometry or samples > 1:  # geometry asked for (even with no shapes), or the exercise's samples
            meta["precision"] = _precision(scene, rules, ranges, mesh, samples)
        if gframes:
            meta["encoding_ranges"] = ranges
            # pixels where the three frames' alpha and the id channel disagree on hit/miss (expected 0)
            meta["hit_consistency"] = geom.pop("hit_mismatch")
            meta["surface_residual"] = geom.pop("surface_residual")
        else:
            miss = np.zeros((h, w), dtype=bool)
            geom = {"hit": miss, "shape_id": np.full((h, w), -1, np.int32), "t": np.full((h, w), np.inf),
                    "position": np.zeros((h, w, 3)), "normal": np.zeros((h, w, 3))}  # fmt: skip
        # POV-Ray's own 8-bit image (exact rounding; rounding the half-float colour flips .5 ties); antialiased
        # renders have none (color8() then rounds the half-float colour)
        return RenderResult(backend=NAME, width=w, height=h, color=color, image8=color8, meta=meta, **geom)

    # ---- export ---------------------------------------------------------------------------
    def export(self, scene: Scene, rules: Rules, out_dir: Path, options: dict[str, Any] | None = None) -> list[Path]:
        return export(scene, rules, out_dir)

    # ---- the sweep (minirt.sweep): what accuracy costs in time ---------------------------------
    sweep_knobs: ClassVar[dict[str, Any]] = {
        "antialias": (0, 1, 2, 3, 4),  # 0: antialiasing off (-A); R > 0: +A0.0 +R{R}
        # the exercise's samples through POV-Ray's mesh camera (64 at 256² passes its ray limit)
        "samples": (1, 4, 16),
        "converged_spp": 1024,  # the reference's samples for the converged answer
    }
    SWEEP_STAGES = ("parse", "bounding", "photon", "radiosity", "trace")  # its own statistics (1 ms steps)
    SWEEP_RESOLUTION = 0.001

    def sweep(self, scene: Scene, rules: Rules, knobs: dict[str, Any]) -> list[Series]:
        """Two knobs, both measured against the reference at 1024 spp under POV-Ray's rules:

        - antialias: off, +A0.0 +R1 ... +R4. Method 1 with threshold 0 supersamples every pixel on an
          R x R jittered grid *plus* its centre ray, averaged with weight 1/(R^2 + 1) each
          (``tracetask.cpp`` SupersampleOnePixel), so its cost in rays per pixel is R^2 + 1 and it
          converges to a centre-weighted average, not the box the reference averages: expect a floor.
          Its pixel square is centred on the ray it shoots, so POV-Ray and its converged reference are
          rendered with rule ``pixel_sample = "center"`` (with "corner" the skewed camera shifts the
          supersampled square by half a pixel against the reference's samples).
        - samples: 1, 4, 16 (the exercise's stratified samples), pixel corner: POV-Ray renders the
          reference's own samples through its mesh camera, so it converges as the reference's spp does.

        The rows are colour only (no geometry frames, no 8-bit pass): one POV-Ray invocation per render.
        Time (``_sweep_seconds``): POV-Ray starts a process per render (~0.65 s whatever the size,
        measured from its own statistics): that start-up is its ``seconds_setup`` and is *not* in its
        ``seconds_median`` (the time inside POV-Ray: parse, bounding, trace); ``seconds_total`` has both.
        Its statistics count whole milliseconds: a median below 1 ms is recorded *at* 1 ms, an upper
        bound (``seconds_at_resolution``)."""
        from dataclasses import replace

        k = self.turned(knobs)
        n = k["converged_spp"]
        f64 = {"precision": "f64"}
        centre = replace(self.adapt(rules), pixel_sample="center")
        corner = self.adapt(rules)
        antialias = tuple(
            Setting(r, r * r + 1 if r else 1, {"geometry": False} if r == 0 else {"antialias": r},
                    "POV-Ray -A (antialiasing off)" if r == 0 else f"POV-Ray +A0.0 +R{r}",
                    "povray antialias off" if r == 0 else f"povray +A0.0 +R{r}")
            for r in k["antialias"]
        )  # fmt: skip
        # The exercise's own samples (pixel corner, the rules' own pixel square): its converged answer is
        # the reference under the same rules.
        samples = tuple(
            Setting(m, m, {"geometry": False, "samples": m},
                    f"POV-Ray with the exercise's {m} sample{'s' if m != 1 else ''} (mesh camera)",
                    f"povray {m} exercise samples")
            for m in k["samples"]
        )  # fmt: skip

        def against_reference(knob: str, settings: tuple[Setting, ...], under: Rules, truth: str, cost: str,
                              theory: str) -> Series:  # fmt: skip
            """One knob's series under the rules ``under``, against the converged answer: the reference
            tracer's at n spp under the same rules."""
            return Series(self.name, knob, settings, under,
                          Truth(f"reference/{n}spp/{truth}", "reference", f64, samples=n, rules=under,
                                describe={"precision": "f64", "spp": n}),
                          "color", metric="rmse", cost=cost, theory=theory,
                          knobs={f"povray_{knob}": k[knob], "converged_reference_spp": n},
                          seconds=self._sweep_seconds)  # fmt: skip

        return [
            against_reference("antialias", antialias, centre, "povray-rules", "rays per pixel (R^2 + 1)",
                              "~(R^2+1)^-0.75 (jittered grid, edges) down to a floor (centre-weighted filter)"),
            against_reference("samples", samples, corner, "povray-rules-corner", "rays per pixel",
                              "as reference/spp: the same stratified samples, at POV-Ray's cost per ray"),
        ]  # fmt: skip

    @classmethod
    def _sweep_seconds(cls, res: RenderResult) -> tuple[float, float, float]:
        """(time inside POV-Ray, the process's start-up, its statistics' resolution) of one render."""
        tm = res.meta.get("timings", {})
        if "passes" not in tm:
            return float(tm.get("wall", math.nan)), 0.0, 0.0
        # the EXR pass is the image; the unantialiased render adds an 8-bit PNG pass (exact rounding only)
        passes = [tm["passes"]["exr"]] if "exr" in tm["passes"] else list(tm["passes"].values())
        work = sum(p.get(k, 0.0) for p in passes for k in cls.SWEEP_STAGES)
        return round(work, 6), sum(p["wall"] for p in passes) - work, cls.SWEEP_RESOLUTION


def _render_options(opts: dict[str, Any]) -> tuple[int, Any, bool, int | None]:
    """(samples, threads, geometry, antialias) of a render's options, checked."""
    samples = opts.get("samples", 1)
    threads = opts.get("threads")
    geometry = bool(opts.get("geometry", True))
    antialias = opts.get("antialias")
    if samples > 1:
        # The exercise's samples: colour only (an average of positions is no position), like antialias.
        geometry = False
    if antialias is not None:
        ok = isinstance(antialias, int) and not isinstance(antialias, bool) and 1 <= antialias <= MAX_ANTIALIAS
        if not ok:
            raise ValueError(f"antialias must be an integer in 1..{MAX_ANTIALIAS}, got {antialias!r}")
        # Antialiased renders are colour only: supersampling jitters the geometry passes' encodings
        # (an average of positions is no position), and the 8-bit PNG pass would pay the start-up twice.
        geometry = False
    return samples, threads, geometry, antialias


def _read_frame(path: Path, first: int, h: int, w: int, u8: bool = False) -> np.ndarray:
    """One frame POV-Ray wrote, without the mesh camera's extra first row (``first``), checked whole and
    of the size asked for."""
    try:
        img = (read_image_u8(path) if u8 else read_image(path)[0])[first:]
    except MinirtError as e:  # the file POV-Ray left is cut short or is not an image
        said = str(e).replace(str(path), path.name)
        raise PovrayError(f"POV-Ray wrote a truncated or corrupt {path.name} ({said})") from None
    if img.shape[:2] != (h, w):
        got = f"{img.shape[1]}x{img.shape[0] + first}"
        raise PovrayError(f"POV-Ray wrote {path.name} at {got}, not the {w}x{h + first} asked for")
    return img


def _read_frames(
    scene: Scene, rules: Rules, cwd: Path, cframes: list, gframes: list, ranges, mesh: bool, png_pass: bool
) -> tuple[np.ndarray, np.ndarray | None, dict[str, np.ndarray]]:
    """(colour, POV-Ray's own 8-bit colour or None, the decoded geometry buffers) from the frames the
    passes wrote in ``cwd``."""
    w, h = scene.camera.width, scene.camera.height
    n = len(cframes) + len(gframes)
    exr = frame_files(cwd, "out", "exr")
    png = frame_files(cwd, "out", "png") if png_pass else {}
    missing = [i for i in range(1, n + 1) if i not in exr] + [
        i for i in range(1, len(cframes) + 1) if png_pass and i not in png
    ]
    if missing:
        raise PovrayError(f"POV-Ray wrote no output for frame(s) {sorted(set(missing))}")
    first = 1 if mesh else 0  # the mesh camera's extra first row (see command)
    color = np.zeros((h, w, 3))
    color8: np.ndarray | None = np.zeros((h, w, 3), dtype=np.uint8) if png_pass else None
    for i, f in enumerate(cframes, start=1):
        img = _read_frame(exr[i], first, h, w)
        img8 = _read_frame(png[i], first, h, w, u8=True) if png_pass else None
        if f.index < 0:
            color = img[..., :3].astype(np.float64)
            if img8 is not None:
                color8 = img8[..., :3].copy()
        else:
            color[..., f.index] = img[..., 0]
            if img8 is not None and color8 is not None:
                color8[..., f.index] = img8[..., 0]
    geom: dict[str, np.ndarray] = {}
    if gframes:
        imgs = [_read_frame(exr[len(cframes) + 1 + g], first, h, w) for g in range(len(gframes))]
        geom = decode_geometry(scene, rules, imgs, ranges)
    return color, color8, geom


def _pass_timings(passes: list[dict[str, Any]]) -> dict[str, Any]:
    """The passes run side by side: setup, parse and trace are sums over them (each process's own time)."""
    return {
        "passes": {p["name"]: p["timings"] for p in passes},
        "setup": sum(p["timings"]["setup"] for p in passes),
        "trace": sum(p["timings"].get("trace", 0.0) for p in passes),
        "parse": sum(p["timings"].get("parse", 0.0) for p in passes),
    }


def _precision(scene: Scene, rules: Rules, ranges, mesh: bool, samples: int) -> dict[str, Any]:
    """What the harness's tolerance reads of a render (``meta["precision"]``): minirt.oracles.povray.accuracy's
    bounds for this scene, camera and sampling."""
    precision = accuracy.precision(scene, ranges or [None] * len(scene.shapes), mesh, mesh_reach(scene, rules))
    inside = accuracy.band_inside_scales(scene, rules, samples)
    root = accuracy.root_errors(scene, rules)
    precision.update(
        band_threshold=accuracy.band_threshold(scene, rules, samples, inside),
        band_scale=accuracy.band_scales(scene, rules, samples),
        band_origin_scale=accuracy.band_origin_scales(scene, rules, samples),
        band_inside_scale=inside,
        root_err=root,
        root_normal_err=[e / s.radius if isinstance(s, Ball) else 0.0 for e, s in zip(root, scene.shapes, strict=True)],
        max_distance=MAX_DISTANCE,
        max_distance_lift=0.0 if mesh else accuracy.origin_lift(scene, rules),
        **accuracy.start_decision(scene, rules, mesh),
    )
    return precision
