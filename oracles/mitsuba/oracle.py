"""The Mitsuba oracle: MitsubaOracle, the Backend that picks a variant, runs one of the two routes (rays.py,
sensor.py) and exports the scene (exporter.py), and turns its recorded precision into per-pixel
tolerances (geometry_tolerance). The conventions it bridges are the package docstring's
(minirt.oracles.mitsuba).
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from minirt.io.atomic import write_all
from minirt.model.result import RenderResult
from minirt.model.rules import Rules
from minirt.model.scene import Scene
from minirt.model.series import Series, Setting, Truth
from minirt.model.tolerance import GeometryTolerance, Margins, tolerance_inputs
from minirt.oracles.base import Oracle
from minirt.oracles.mitsuba.accuracy import U32
from minirt.oracles.mitsuba.exporter import scene_to_xml, viewing_distance
from minirt.oracles.mitsuba.rays import RayRender
from minirt.oracles.mitsuba.sensor import SensorRender
from minirt.oracles.mitsuba.variants import BACKEND, load_mitsuba, one_line


class MitsubaOracle(Oracle):
    name: ClassVar[str] = "mitsuba"
    shades: ClassVar[bool] = True
    display_name: ClassVar[str] = "Mitsuba"
    packages: ClassVar[tuple[str, ...]] = ("mitsuba",)
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
        # rules from real solutions' bugs: a renderer has neither a finite "infinity" nor unnormalised normals
        "t_max": (math.inf,),
        # ray_origin, pixel_sample and pixel_shift: any (custom rays are minirt.model.camera's, so they honour all
        # three; the sensor via near_clip and the principal point offsets).
        # specular_exponent: any (no specular lobe is simulated; see unsupported_terms).
    }

    def available(self) -> tuple[bool, str]:
        try:
            load_mitsuba()
        except Exception as e:
            return False, one_line(e)
        return True, self.version()

    def version(self) -> str:
        try:
            mi, variant = load_mitsuba()
        except Exception as e:
            return f"mitsuba unavailable ({one_line(e)})"
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
        h, w, p, m, t_ref = tolerance_inputs(result, ref, measured)
        ties = None
        eps = p["band_k"] * p["band_eps"]
        plane_abs = max([pl.get("abs_error", 0.0) for pl in result.meta.get("planes", {}).values()] or [0.0])
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
        else:  # a shadow or hit decision moved by the rectangle's absolute error: relative to the smallest radius
            band = measured.below("margin", eps, h, w)
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
        path = Path(out_dir) / "scene.xml"
        spp = int((options or {}).get("spp", 1))
        d = viewing_distance(scene, rules)  # the light scaled for viewing (package docstring: falloff)
        return write_all({path: scene_to_xml(scene, rules, spp=spp, light_distance=d)})  # atomic

    # ---- render ------------------------------------------------------------------------------
    def render(self, scene: Scene, rules: Rules, options: dict[str, Any] | None = None, progress=None) -> RenderResult:
        opts = dict(options or {})
        w, h = scene.camera.width, scene.camera.height
        mode = opts.get("mode", "rays")
        try:
            t0 = time.perf_counter()
            mi, variant = load_mitsuba()
            t_import = time.perf_counter() - t0
        except Exception as e:
            return RenderResult.failed(BACKEND, w, h, "skip", f"mitsuba unavailable: {one_line(e)}", options=opts)
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
                res = SensorRender(mi, variant, scene, rules, opts).run()
            else:
                res = RayRender(mi, variant, scene, rules, opts).run()
        except Exception as e:  # any Mitsuba exception becomes a result, never an exception
            return RenderResult.failed(BACKEND, w, h, "error", f"mitsuba failed: {one_line(e)}", options=opts)
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
