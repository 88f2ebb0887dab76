"""The reference tracer as a backend: the same interface as every oracle (minirt.model.backend).

It follows every rule (``supported`` is empty: any value of any rule), shades the exercise's own model,
traces in float64 by default (``--precision f32`` for float32), and writes an image larger than one tile
tile by tile as it is traced (``streams``). Its memory figures are measured like the oracles' (minirt.jobs.memory).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any, ClassVar

from minirt.model import bitmap
from minirt.model.backend import Backend
from minirt.model.result import RenderResult
from minirt.model.rules import Rules
from minirt.model.scene import Scene


class Reference(Backend):
    name: ClassVar[str] = "reference"
    display_name: ClassVar[str] = "The reference"
    shades: ClassVar[bool] = True
    shading_model: ClassVar[str | None] = "exercise"
    reports_progress: ClassVar[bool] = True  # tile by tile
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
