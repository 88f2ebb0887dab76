"""What both render routes share (MitsubaRender): the scene loaded into Mitsuba from its XML with
``optimize=False`` (so that every plane keeps its own shape), Mitsuba's shape registry ids mapped back
to the scene's shape index (the package docstring's "Registry ids"), and the result's meta: version,
settings, timings, the terms Mitsuba cannot simulate, and ``precision`` (accuracy.py).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from minirt.model import camera
from minirt.model.rules import Rules
from minirt.model.scene import Scene
from minirt.oracles.base import materials_use
from minirt.oracles.mitsuba.accuracy import BAND_K, DIR_ERR, NORMAL_DEG, T_REL, U32, band_scales, shape_eps
from minirt.oracles.mitsuba.exporter import scene_to_xml
from minirt.oracles.mitsuba.planes import PlaneRect
from minirt.oracles.mitsuba.variants import BACKEND


def _unsupported_terms(scene: Scene, mode: str) -> list[str]:
    out = [term for term in ("ambient", "specular") if materials_use(scene, term)]
    if any(v != 0 for v in scene.background):
        out.append("background")
    if mode == "sensor" and scene.max_depth > 0 and materials_use(scene, "reflection"):
        out.append("reflection")  # the `direct` integrator does not follow delta reflections
    return out


class MitsubaRender:
    """One render of a scene in Mitsuba, whichever route (``RayRender``, ``SensorRender``: subclasses with
    a ``run``): the scene, its rules and the options, the variant loaded, and what both routes share."""

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
        """Registry ids -> scene indices where ``hit`` (-1 elsewhere, and for an id the scene has not)."""
        keys = np.fromiter(self.lut.keys(), dtype=np.int64, count=len(self.lut))
        vals = np.fromiter(self.lut.values(), dtype=np.int32, count=len(self.lut))
        order = np.argsort(keys)
        keys, vals = keys[order], vals[order]
        reg = np.asarray(reg, dtype=np.int64)
        at = np.clip(np.searchsorted(keys, reg), 0, max(len(keys) - 1, 0))
        known = hit & (keys[at] == reg) if len(keys) else np.zeros(reg.shape, dtype=bool)
        return np.where(known, vals[at] if len(keys) else -1, -1).astype(np.int32)

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
