"""The reference renders a check compares with (``ReferenceCache``): one scene's, keyed by the rules
(an oracle's adapted rules, many oracles sharing them) and the samples, each rendered once, with only the
terms and diagnostics the checks read.
"""

from __future__ import annotations

import hashlib

from minirt.errors import MinirtError
from minirt.harness import backends
from minirt.model import camera
from minirt.model.result import RenderResult
from minirt.model.rules import Rules
from minirt.model.scene import Scene
from minirt.reference import band

# The reference terms the checks read (the lit mask, the shading comparison, the report's diffuse
# preview): a reference render for a check writes only these (each term is 24 bytes a pixel of kernel
# writes; tracer.Tracer.render).
CHECKED_TERMS = ("diffuse", "specular")


class ReferenceCache:
    """Reference renders of one scene, keyed by rules (many oracles share the same adapted rules), and the
    primary rays' margins (``rays``), which every oracle's geometry check reads."""

    def __init__(self, scene: Scene):
        self.scene, self.cache = scene, {}
        self._rays: dict[bytes, band.Rays] = {}

    def rays(self, rules: Rules) -> band.Rays:
        """The primary rays under ``rules`` (minirt.reference.band.Rays: their ball tree, candidates and
        margins computed once), shared by every oracle whose rules give the same rays, bit for bit."""
        o, d = camera.primary_rays(self.scene, rules)
        key = hashlib.blake2b(o.tobytes() + d.tobytes(), digest_size=16).digest()
        if key not in self._rays:
            self._rays[key] = band.Rays(self.scene, o, d, next(iter(self._rays.values())).balls if self._rays else None)
        return self._rays[key]

    def get(self, rules: Rules, samples: int | None = None) -> RenderResult:
        key = (rules, samples)
        if key not in self.cache:
            sc = self.scene if samples is None else self.scene.with_overrides(samples=samples)
            # diagnostics: the ray-tree labels and shadow margins the edge classes and shading checks use.
            # runtime: the rules an oracle's variants differ in are values the kernel reads, so the scene's
            # renders under its oracles' rules share one compiled kernel (the same bits: Tracer, tested).
            opts = {"diagnostics": True, "terms": CHECKED_TERMS, "runtime": True}
            r = backends.render(backends.REFERENCE, sc, rules, opts)
            if not r.ok:
                raise MinirtError(f"{self.scene.source}: the reference tracer failed: {r.reason}")
            r.meta["shapes"] = len(self.scene.shapes)
            self.cache[key] = r
        return self.cache[key]
