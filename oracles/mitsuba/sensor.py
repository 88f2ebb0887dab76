"""The sensor route (``mode = "sensor"``): Mitsuba's own ``perspective`` sensor generates the rays and
``mi.render`` renders them -- the ``aov`` integrator (depth, position, geometric normal, shape index)
around ``direct``; with spp > 1 the ``independent`` sampler and ``moment`` for the per-pixel variance.

Square images only (the sensor has square pixels). The sensor is the exported one (exporter.py's
sensor_params: mirrored, near clip on the image plane, principal point at the pixel corner at 1 spp).
The rectangles cannot grow after tracing here, so they come from planes.sensor_frames, sized up front.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from minirt.model.result import RenderResult, geometry_from_flat
from minirt.oracles.mitsuba.accuracy import RAY_EPSILON
from minirt.oracles.mitsuba.exporter import sensor_params
from minirt.oracles.mitsuba.planes import sensor_frames
from minirt.oracles.mitsuba.render import MitsubaRender
from minirt.oracles.mitsuba.variants import BACKEND


class SensorRender(MitsubaRender):
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
