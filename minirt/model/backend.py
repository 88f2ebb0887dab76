"""What every backend is: the reference tracer and each oracle behind one interface.

A backend takes a parsed Scene and the model Rules and returns a RenderResult (minirt.model.result),
the one result type, with timings and the exact commands or parameters it used in ``meta``. It never
raises for a renderer's failure: it returns a result with status "error" (the renderer broke) or
"skip" (not installed, or the scene cannot be reproduced), and a one-line reason.

Everything minirt knows about a backend is said here, by the backend itself: its display name, its
precision, the model its colour follows, whether it runs beside the others, the memory it holds per
pixel, the command-line options it takes, the rules it can follow, its geometry tolerance with the
derivation, its sweep knob and its export. Nothing outside a backend's own module asks which backend it
is. The reference tracer (minirt.reference.backend) implements this interface as every oracle
(minirt.oracles) does; minirt.harness.backends finds each by name.

Rules: a backend declares, per model rule, the values it can reproduce (``supported``). The harness
renders the reference under ``adapt(rules)`` -- the requested rules with every unsupported value
replaced by one the backend can do -- and compares like with like; the rules changed are the ones the
attribution step reports.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any, ClassVar

from minirt.model import rules as rules_mod
from minirt.model.result import RenderResult
from minirt.model.rules import Rules
from minirt.model.scene import Scene

# The value types the interface names live beside it (minirt.model.tolerance: the harness's geometry
# check; minirt.model.series: the sweep's knobs); imported here too, so ``from minirt.model.backend import``
# of them keeps working.
from minirt.model.series import Seconds, Series, Setting, Truth  # noqa: F401
from minirt.model.tolerance import (  # noqa: F401
    U32,
    U64,
    GeometryTolerance,
    Margins,
    farthest_hit,
    generic_tolerance,
    tolerance_inputs,
)


class Backend:
    """The interface of every backend (see the module's docstring). Class attributes are facts about the
    backend, read without rendering (and without importing its renderer)."""

    name: ClassVar[str] = ""
    display_name: ClassVar[str] = ""  # as pages name it ("POV-Ray")
    shades: ClassVar[bool] = False  # does it produce a colour image?
    # How its colour relates to the exercise's model: "exercise" (the same model, compared level by level),
    # "physical" (a physically based renderer's, compared statistically), None (no colour)
    shading_model: ClassVar[str | None] = None
    float32: ClassVar[bool] = False  # traces in float32 (a render warns about the scene's float32 hazards)
    concurrent: ClassVar[bool] = False  # runs beside the others in a check (its work is in its own process)
    reports_progress: ClassVar[bool] = False  # takes options["progress"], a callable(done, total)
    # Memory, bytes per pixel (minirt.jobs.memory, fitted to measured peaks): a check keeps its render and
    # figures (check_kept); a render keeps its result (render_kept) while one render runs (render_running).
    check_kept: ClassVar[int] = 1400
    render_kept: ClassVar[int] = 220
    render_running: ClassVar[int] = 430
    packages: ClassVar[tuple[str, ...]] = ()  # the Python distributions it renders with (`minirt doctor`)
    export_as: ClassVar[str | None] = None  # `minirt export --to NAME`; None: no export
    export_what: ClassVar[str] = ""  # what that export writes, for --help
    # rule name -> values this backend reproduces, preferred first. A rule not listed: any value -- except
    # the rules from real solutions' bugs (rules.BUG_RULES), which a backend follows only at their
    # defaults unless it lists them or ``follows_bugs`` says it follows every one (the reference does).
    supported: ClassVar[dict[str, tuple[Any, ...]]] = {}
    follows_bugs: ClassVar[bool] = False

    def available(self) -> tuple[bool, str]:
        """(usable, reason or version line)."""
        raise NotImplementedError

    def version(self) -> str:
        raise NotImplementedError

    def adapt(self, rules: Rules) -> Rules:
        """The closest rules this backend can follow."""
        changes = {}
        for name, values in self.supported.items():
            if getattr(rules, name) not in values:
                changes[name] = values[0]
        if not self.follows_bugs:
            for name in rules_mod.BUG_RULES:
                if name not in self.supported and getattr(rules, name) != rules_mod.default(name):
                    changes[name] = rules_mod.default(name)
        return replace(rules, **changes)

    def cannot_follow(self, rules: Rules) -> list[str]:
        return rules.differs(self.adapt(rules))

    def options(self, precision: str = "f64", samples: int | None = None, timeout: float | None = None) -> dict:
        """The render options for the command line's (and the API's) --precision, --samples and --timeout:
        each backend takes those it has a meaning for."""
        return {"precision": precision}

    def is_float32(self, options: dict[str, Any]) -> bool:
        """Does a render with these options trace in float32?"""
        return self.float32

    # Does a check ask ``check_options`` before rendering (it then renders after the reference)?
    chooses_pixels: ClassVar[bool] = False

    def check_options(self, scene: Scene, reference: RenderResult) -> dict[str, Any]:
        """Options for the render a check compares with ``reference`` (the reference's own render of the
        scene under the rules this backend follows, one ray a pixel, with its diagnostics): a backend too
        slow to render every pixel of a large image names the pixels worth its time (``chooses_pixels``)."""
        return {}

    def runs_apart(self, options: dict[str, Any]) -> bool:
        """Whether its render with these options works in processes of its own, so that a check starts it
        beside the others' work (minirt.harness.compare.start_ahead): ``concurrent``, by default."""
        return self.concurrent

    def scene_as_rendered(self, scene: Scene) -> Scene:
        """The scene as this backend renders it, where its input cannot say all of it (a 2014 program's
        interface has no specular colour: minirt.oracles.program.edition_scene): what its image is compared
        with. The scene itself, by default."""
        return scene

    def render(self, scene: Scene, rules: Rules, options: dict[str, Any] | None = None) -> RenderResult:
        """Render under `rules` (already adapted by the caller); options are backend-specific, and a
        backend that ``reports_progress`` is given ``options["progress"]``, called as ``progress(done, total)``."""
        raise NotImplementedError

    def streams(self, scene: Scene, rules: Rules) -> bool:
        """Would this render be written tile by tile as it is traced (``tiles``), in bounded memory?"""
        return False

    def tiles(
        self, scene: Scene, rules: Rules, options: dict[str, Any] | None = None, progress=None
    ) -> Iterator[tuple[int, RenderResult]]:
        """The image as (first row, tile) pairs, top to bottom (where ``streams`` says so)."""
        raise NotImplementedError

    def export(self, scene: Scene, rules: Rules, out_dir: Path, options: dict[str, Any] | None = None) -> list[Path]:
        """Write the scene as a user would open it in this renderer; return the files written."""
        raise NotImplementedError

    def geometry_tolerance(self, result: RenderResult, ref: RenderResult, measured: Margins) -> GeometryTolerance:
        """Translate this backend's recorded precision (``result.meta["precision"]``) into per-pixel
        tolerances, each with its derivation (``why``)."""
        return generic_tolerance(result, ref, measured)

    # The sweep's knobs (minirt.sweep): their defaults, by name (none: nothing to sweep).
    sweep_knobs: ClassVar[dict[str, Any]] = {}

    def sweep(self, scene: Scene, rules: Rules, knobs: dict[str, Any]) -> list[Series]:
        """What accuracy costs in time: this backend's knobs, each a series of settings (minirt.sweep).
        ``knobs``: the settings the caller asked for, by knob name (absent: ``sweep_knobs``'s defaults; see
        ``turned``). Building the series renders nothing: the sweep renders them."""
        return []

    def turned(self, knobs: dict[str, Any]) -> dict[str, Any]:
        """``sweep_knobs`` with the caller's settings in place of the defaults; a knob this backend does not
        have is a ValueError (a misspelt knob would sweep the defaults unnoticed)."""
        unknown = sorted(set(knobs) - set(self.sweep_knobs))
        if unknown:
            known = ", ".join(self.sweep_knobs) or "none"
            raise ValueError(f"{self.name}: no sweep knob {', '.join(unknown)} (its knobs: {known})")
        return {**self.sweep_knobs, **knobs}
