"""The reference tracer as a backend: the same interface as every oracle (minirt.model.backend).

It follows every rule (``supported`` is empty and ``follows_bugs`` true: any value of any rule), shades the
exercise's own model, traces in float64 by default (``--precision f32`` for float32), and writes an image
larger than one tile tile by tile as it is traced (``streams``). Its memory figures are measured like the
oracles' (minirt.jobs.memory).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any, ClassVar

from minirt.model import bitmap
from minirt.model.backend import Backend
from minirt.model.result import RenderResult
from minirt.model.rules import Rules
from minirt.model.scene import Scene
from minirt.model.series import Series, Setting, Truth


class Reference(Backend):
    name: ClassVar[str] = "reference"
    display_name: ClassVar[str] = "The reference"
    shades: ClassVar[bool] = True
    shading_model: ClassVar[str | None] = "exercise"
    reports_progress: ClassVar[bool] = True  # tile by tile
    packages: ClassVar[tuple[str, ...]] = ("drjit",)
    follows_bugs: ClassVar[bool] = True
    # ``minirt check`` keeps the reference render for the report: 450 bytes a pixel; a render keeps 220 and
    # runs with 430 (Dr.Jit's working buffers); measured as the oracles' figures (minirt.jobs.memory)
    check_kept: ClassVar[int] = 450
    render_kept: ClassVar[int] = 220
    render_running: ClassVar[int] = 430

    def available(self) -> tuple[bool, str]:
        from minirt.jit.engine import llvm_status

        return llvm_status()

    def version(self) -> str:
        import drjit

        _, why = self.available()
        return f"minirt tracer on Dr.Jit {drjit.__version__} ({why})"

    def is_float32(self, options: dict[str, Any]) -> bool:
        return options.get("precision", "f64") == "f32"

    def render(self, scene: Scene, rules: Rules, options: dict[str, Any] | None = None) -> RenderResult:
        from minirt.reference import tracer

        options = options or {}
        return tracer.render(
            scene,
            rules,
            precision=options.get("precision", "f64"),
            prune=options.get("prune", True),
            progress=options.get("progress"),
            diagnostics=bool(options.get("diagnostics", False)),
            terms=options.get("terms"),
            runtime=options.get("runtime"),  # None: the tracer's choice by image size
        )

    def streams(self, scene: Scene, rules: Rules) -> bool:
        """An image larger than one tile (tracer.TILE_PIXELS) under the default output rules is traced and
        written tile by tile: its memory is one tile's, whatever the size."""
        from minirt.reference import tracer

        return scene.camera.width * scene.camera.height > tracer.TILE_PIXELS and bitmap.is_default(rules)

    def tiles(
        self, scene: Scene, rules: Rules, options: dict[str, Any] | None = None, progress=None
    ) -> Iterator[tuple[int, RenderResult]]:
        from minirt.reference import tracer

        tr = tracer.Tracer(scene, rules, precision=(options or {}).get("precision", "f64"))
        return tr.tiles(progress)

    # ---- the sweep (minirt.sweep): what accuracy costs in time ----------------------------------------
    sweep_knobs: ClassVar[dict[str, Any]] = {
        "precision": ("f32", "f64"),  # one sample each
        "spp": (1, 4, 16, 64, 256),
        "converged_spp": 1024,  # the converged answer the spp rows are measured against
    }

    def sweep(self, scene: Scene, rules: Rules, knobs: dict[str, Any]) -> list[Series]:
        """Two knobs:

        - precision: f32, f64 (1 sample), against the f64 render: t relative error, hit/id mismatches,
          colour RMSE and FLIP (f64's own row is 0 by design, so it is no candidate for the answer and
          gets no fit: two points, one of them the truth itself);
        - spp: 1, 4, 16, 64, 256, against the reference f64 at 1024 spp under the same rules: RMSE, FLIP.
          ``spp = 1`` is the rules' single ray per pixel (the exercise's pixel corner), not a random one;
          ``spp > 1`` averages stratified jittered samples over the pixel square [x, x+1) x [y, y+1)
          (``minirt.model.camera``). The converged render uses the same estimator, so its own error is
          about that of the 256-spp row divided by two: read errors far below it as "at the floor"."""
        k = self.turned(knobs)
        f64 = {"precision": "f64"}
        exact = Truth("reference/f64", self.name, f64, samples=1, describe={"precision": "f64", "spp": 1})
        n = k["converged_spp"]
        converged = Truth(f"reference/{n}spp", self.name, f64, samples=n, describe={"precision": "f64", "spp": n})
        bits = {"f32": 32, "f64": 64}
        precision = tuple(
            Setting(p, bits.get(p, math.nan), {"precision": p}, f"the reference in {p}", f"reference {p}", samples=1)
            for p in k["precision"]
        )
        spp = tuple(Setting(s, s, f64, f"the reference at {s} spp", f"reference {s} spp", samples=s) for s in k["spp"])
        return [
            Series(self.name, "precision", precision, rules, exact, "geometry+color", metric="rmse", cost="bits",
                   theory="f32 vs f64: rounding only", knobs={"reference_precisions": k["precision"]},
                   candidate=False, fit=False),
            Series(self.name, "spp", spp, rules, converged, "color", metric="rmse", cost="samples per pixel",
                   theory="spp^-0.5 (random) to spp^-0.75 (stratified, edges)",
                   knobs={"reference_spp": k["spp"], "converged_reference_spp": n}),
        ]  # fmt: skip
