"""Scene checks in your own test suite: "my scenes pass against every oracle" as an assertion.

``assert_scene_passes(scene, backends="all", size=(64, 64))`` runs ``minirt check`` on a scene file,
a bundled scene's name, a folder of scenes or a list of them, and raises AssertionError naming every
scene and backend that did not pass, with the reason and the checks that failed. minirt's pytest
plugin (minirt.pytest_plugin) builds its fixture and its scene-file tests on it.
"""

from __future__ import annotations

from collections.abc import Sequence
from os import PathLike
from typing import TYPE_CHECKING

from minirt.errors import MinirtError

if TYPE_CHECKING:
    from minirt.harness.results import CheckResult

# Verdicts that pass: WARN is a pass with a remark (minirt check exits 0); SKIP only when allowed,
# so a missing renderer cannot make "passes against every oracle" true by not running.
PASSING = ("pass", "warn")


def parse_size(size: str | tuple[int, int] | None) -> tuple[int, int] | None:
    """``"64x48"`` (or ``"64"``, square) or ``(64, 48)`` as (width, height); None or ``""``: the scene's own."""
    if not size:
        return None
    if isinstance(size, str):
        w, _, h = size.lower().partition("x")
        try:
            size = (int(w), int(h or w))
        except ValueError:
            raise MinirtError(f"size {size!r}: expected WIDTHxHEIGHT, e.g. 64x64") from None
    w, h = size
    if min(w, h) < 1:
        raise MinirtError(f"size {w}x{h}: width and height must be >= 1")
    return int(w), int(h)


def assert_scene_passes(
    scene: str | PathLike[str] | Sequence[str | PathLike[str]],
    backends: str | Sequence[str] = "all",
    *,
    size: str | tuple[int, int] | None = None,
    allow_skip: bool = False,
) -> CheckResult:
    """Check the scene(s) against the backends (``"all"``: every oracle) and raise AssertionError unless
    every scene passes with every backend (WARN counts as a pass; SKIP, a backend that could not run or
    does not apply, only with ``allow_skip``). ``size``: render at (width, height) or ``"WxH"`` instead
    of each scene's own size; small sizes keep a test suite fast. Returns the CheckResult. Bad input (a
    scene that does not load, an unknown backend) raises MinirtError with its message, from this call:
    no frames inside minirt."""
    __tracebackhide__ = True  # pytest: the failure points at the caller's line
    import minirt

    try:
        result = minirt.check(scene, backends, size=parse_size(size))
    except MinirtError as e:  # bad input (a missing scene, an unknown backend): its one line, raised here --
        raise type(e)(*e.lines) from None  # pytest shows the caller's line, no traceback into minirt
    problems: list[str] = []
    for s in result.scenes:
        for name, b in s.backends.items():
            if b.verdict in PASSING or (b.verdict == "skip" and allow_skip):
                continue
            where = s.scene if s.file == s.scene else f"{s.scene} ({s.file})"  # a bundled scene: its name
            line = f"{where} with {name}: {b.verdict.upper()}"
            if b.reason:
                line += f": {b.reason}"
            failed = [f"{k}: {c.reason}" if c.reason else k for k, c in b.checks.items() if c.verdict == "fail"]
            failed = [f for f in failed if f not in line]  # the backend's reason is often its failed check's
            if failed:
                line += f" [{'; '.join(failed)}]"
            problems.append(line)
    if problems:
        raise AssertionError("minirt check did not pass:\n  " + "\n  ".join(problems))
    return result
