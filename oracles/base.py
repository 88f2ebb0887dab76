"""The interface every oracle implements.

An oracle takes a parsed Scene and the model Rules and returns a RenderResult (minirt.result), the
same type the reference tracer returns, with timings and the exact commands or parameters it used
in ``meta``. It never raises for a renderer's failure: it returns a result with status "error"
(the renderer broke) or "skip" (not installed, or the scene cannot be reproduced), and a one-line
reason. Oracles import only the core (minirt.scene, rules, camera, result, imageio).

Rules: an oracle declares, per model rule, the values it can reproduce (``supported``). The harness
renders the reference under ``adapt(rules)`` -- the requested rules with every unsupported value
replaced by one the oracle can do -- and compares like with like; the rules changed are the ones
the attribution step reports.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any, ClassVar

from minirt.result import RenderResult
from minirt.rules import Rules
from minirt.scene import Scene


class Oracle:
    name: ClassVar[str] = ""
    shades: ClassVar[bool] = False  # does it produce a colour image?
    # rule name -> values this oracle reproduces, preferred first. A rule not listed: any value.
    supported: ClassVar[dict[str, tuple[Any, ...]]] = {}

    def available(self) -> tuple[bool, str]:
        """(usable, reason or version line)."""
        raise NotImplementedError

    def version(self) -> str:
        raise NotImplementedError

    def adapt(self, rules: Rules) -> Rules:
        """The closest rules this oracle can follow."""
        changes = {}
        for name, values in self.supported.items():
            if getattr(rules, name) not in values:
                changes[name] = values[0]
        return replace(rules, **changes)

    def cannot_follow(self, rules: Rules) -> list[str]:
        return rules.differs(self.adapt(rules))

    def render(self, scene: Scene, rules: Rules, options: dict[str, Any] | None = None) -> RenderResult:
        """Render under `rules` (already adapted by the caller); options are oracle-specific."""
        raise NotImplementedError

    def export(self, scene: Scene, rules: Rules, out_dir: Path, options: dict[str, Any] | None = None) -> list[Path]:
        """Write the scene as a user would open it in this renderer; return the files written."""
        raise NotImplementedError
