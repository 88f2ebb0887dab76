"""Every backend by name: the reference tracer and the oracles, behind one interface (minirt.model.backend).

This is the registry: the one place that knows which name is the reference. Everything else asks a
backend itself (``get(name).shading_model``, ``.float32``, ``.concurrent``, ...), never compares names.

Whatever a backend does -- missing, crashing, unable to reproduce the scene -- ``render`` returns a
RenderResult; a failure is a result with status "skip" or "error" and a one-line reason.
"""

from __future__ import annotations

import functools
import importlib
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from minirt.errors import MinirtError
from minirt.model.backend import Backend
from minirt.model.result import RenderResult
from minirt.model.rules import Rules
from minirt.model.scene import Scene
from minirt.oracles import REGISTRY as ORACLES

REFERENCE = "reference"  # what every oracle is compared with
REGISTRY: dict[str, str] = {REFERENCE: "minirt.reference.backend:Reference", **ORACLES}


@functools.cache
def get(name: str) -> Backend:
    """The backend called ``name`` (KeyError for an unknown one). Its module is imported on first use:
    a renderer that is not installed costs nothing until it is asked for."""
    if is_program(name):  # a student's program, named by itself: program:SPEC (minirt.oracles.program)
        return importlib.import_module("minirt.oracles.program").backend(name)
    module, cls = REGISTRY[name].split(":")
    return getattr(importlib.import_module(module), cls)()


def is_program(name: str) -> bool:
    return name.startswith(("program:", "program("))


def find(name: str) -> Backend | None:
    """The backend called ``name``, or None for a name no backend has (a result a test made by hand)."""
    return get(name) if name in REGISTRY or is_program(name) else None


def oracle_names() -> list[str]:
    return list(ORACLES)


def all_names() -> list[str]:
    return list(REGISTRY)


def oracles_among(names: Sequence[str]) -> list[str]:
    """The oracles in ``names``, in their order, and a student's program (``program:SPEC``): what a
    comparison compares the reference with."""
    return [n for n in names if n in ORACLES or is_program(n)]


def display_name(name: str) -> str:
    b = find(name)
    return b.display_name if b else name


def shading_model(name: str, has_color: bool) -> str | None:
    """How a backend's colour relates to the exercise's model ("exercise", "physical", None: no colour);
    a name no backend has is taken as shading the exercise's model when it has a colour."""
    b = find(name)
    if b is None:
        return "exercise" if has_color else None
    return b.shading_model


def parse_backends(spec: str) -> list[str]:
    """'all', 'reference', or a comma-separated list (where 'all' stands for every registered backend);
    unknown names are bad input. A student's program, ``program:SPEC``, ends the list: its SPEC is the rest,
    commas and all."""
    if spec.strip() == "all":
        return all_names()
    at = next((k for k in range(len(spec)) if is_program(spec[k:]) and (k == 0 or spec[k - 1] == ",")), None)
    program = [] if at is None else [spec[at:].strip()]
    if program:
        get(program[0]).spec  # noqa: B018 -- parsed now: a bad SPEC is bad input before any work
        spec = spec[:at]
    listed = [s.strip() for s in spec.split(",") if s.strip()]
    # "all" in a list (all,program:SPEC): every registered backend in its place
    names = list(dict.fromkeys(n for s in listed for n in (all_names() if s == "all" else [s]))) + program
    known = all_names()
    unknown = [n for n in names if n not in known and not is_program(n)]
    if unknown or not names:
        raise MinirtError(
            f"--backend: unknown backend {', '.join(unknown) or repr(spec)} (known: all, {', '.join(known)})"
        )
    return names


def require_oracle(names: list[str], spelled: str = "--backend", programs_too: bool = False) -> None:
    """A comparison needs something to compare with: the reference alone is bad input. A program gives a
    colour image only: ``programs_too`` where the comparison checks an image alone (a check, whose geometry
    check then says SKIP: minirt.harness.image_only), else it is bad input (a campaign needs every buffer)."""
    programs = [n for n in names if is_program(n)]
    if programs and not programs_too:
        spec = programs[0].partition(":")[2]
        raise MinirtError(
            f"{spelled} {programs[0]}: a program gives a colour image, and a comparison needs its geometry "
            f"buffers too; grade it instead: minirt grade --program {spec!r}"
        )
    if not oracles_among(names):
        raise MinirtError(
            f"{spelled} {','.join(names)}: no oracle to compare with (give one or more of "
            f"{', '.join(oracle_names())}, or all)"
        )


@dataclass
class BackendInfo:
    name: str
    available: bool
    detail: str  # version line, or why it is unavailable
    shades: bool


def info(name: str) -> BackendInfo:
    try:
        b = get(name)
        ok, why = b.available()
        return BackendInfo(name, ok, b.version() if ok else why, b.shades)
    except Exception as e:  # a broken install must not take the others down
        return BackendInfo(name, False, f"cannot load: {type(e).__name__}: {e}", False)


def rules_for(name: str, rules: Rules) -> Rules:
    """The rules a backend actually follows when asked for `rules`."""
    return get(name).adapt(rules)


def render(name: str, scene: Scene, rules: Rules, options: dict[str, Any] | None = None, progress=None) -> RenderResult:
    """Render with one backend under the rules it can follow; never raises for the backend's failure."""
    w, h = scene.camera.width, scene.camera.height
    options = dict(options or {})
    t0 = time.perf_counter()
    try:
        b = get(name)
        ok, why = b.available()
        if not ok:
            return RenderResult.failed(name, w, h, "skip", why)
        if progress is not None and b.reports_progress:
            options["progress"] = progress
        result = b.render(scene, b.adapt(rules), options)
    except Exception as e:  # a crashing backend is an ERROR verdict, not a crash of minirt
        result = _failure(name, w, h, e)
    result.meta.setdefault("timings", {})["wall"] = time.perf_counter() - t0
    return result


def _failure(name: str, w: int, h: int, e: Exception) -> RenderResult:
    """A backend's exception as an ERROR result with a one-line reason (our own errors say it all)."""
    why = str(e) if isinstance(e, MinirtError) else f"{type(e).__name__}: {e}"
    return RenderResult.failed(name, w, h, "error", (why.splitlines() or [""])[0])


def render_to_files(
    name: str,
    scene: Scene,
    rules: Rules,
    options: dict[str, Any] | None,
    out_dir: Any,
    stem: str,
    timings: bool = False,
    progress=None,
    stream: bool = False,
    variant: str = "",
) -> tuple[RenderResult, dict[str, Any] | None]:
    """Render with one backend and write its files (minirt.io.images.write_result); (result, paths), paths
    None when the backend failed. With ``stream``, an image its backend ``streams`` (the reference's,
    larger than one tile, under the default output rules) is written tile by tile as it is traced
    (minirt.io.images.write_tiles): its memory is one tile's, whatever the size; the returned result then
    carries the metadata only (no buffers). ``variant``: what differs from the scene's own model (see
    minirt.io.names), recorded in the metadata and so in the sidecar."""
    from minirt.io.images import write_result, write_tiles

    w, h = scene.camera.width, scene.camera.height
    options = dict(options or {})
    if stream and get(name).streams(scene, rules):
        t0 = time.perf_counter()
        try:
            traced = get(name).tiles(scene, rules, options, progress)

            def tiles():
                for y0, tile in traced:
                    if variant:
                        tile.meta["variant"] = variant
                    yield y0, tile

            paths, last = write_tiles(tiles(), w, h, out_dir, stem, timings=timings)
        except Exception as e:  # as render(): an ERROR result, never a crash of minirt
            return _failure(name, w, h, e), None
        res = RenderResult(backend=name, width=w, height=h, meta=dict(last.meta))
        took = time.perf_counter() - t0
        res.meta["timings"] = {"total": took, "wall": took}
        return res, paths
    res = render(name, scene, rules, options, progress)
    if not res.ok:
        return res, None
    if variant:
        res.meta["variant"] = variant
    return res, write_result(res, out_dir, stem, timings=timings, rules=rules)


def versions(backends_used: Sequence[str]) -> dict[str, str]:
    """What besides a job's inputs its result depends on (a cache key's part): minirt's code, Dr.Jit,
    each backend's version line."""
    import drjit

    from minirt.jobs.cache import code_digest

    v = {"minirt": code_digest(), "drjit": drjit.__version__}
    for name in backends_used:
        v[name] = info(name).detail
    return v


def check_bytes(pixels: list[int], oracles: Sequence[str], local_workers: int = 0) -> int:
    """minirt.jobs.memory.check_bytes with each backend's own figures (``check_kept``)."""
    from minirt.jobs import memory

    kept = [get(n).check_kept for n in oracles]
    return memory.check_bytes(pixels, get(REFERENCE).check_kept, kept, local_workers)


def render_bytes(pixels: int, names: Sequence[str]) -> int:
    """minirt.jobs.memory.render_bytes with each backend's own figures (``render_kept``, ``render_running``)."""
    from minirt.jobs import memory

    bs = [get(n) for n in names]
    return memory.render_bytes(pixels, [b.render_kept for b in bs], [b.render_running for b in bs])


def reference_result(results: Sequence[RenderResult]) -> RenderResult | None:
    """The reference's result among ``results`` (None when it was not asked for)."""
    return next((r for r in results if r.backend == REFERENCE), None)


def export_targets() -> dict[str, Backend]:
    """``minirt export --to NAME``: each backend that exports, by its export name (``export_as``)."""
    return {b.export_as: b for b in map(get, REGISTRY) if b.export_as}


# What every check reads and writes with, whichever backends run: images, statistics, colour differences.
SHARED_PACKAGES = ("OpenImageIO", "numpy", "colour-science", "flip-evaluator")


def packages() -> list[str]:
    """The Python distributions minirt renders and compares with (`minirt doctor`): each backend's own,
    in registry order, then the shared ones. Reading them imports each backend's module, not its renderer."""
    own = [p for name in REGISTRY for p in get(name).packages]
    return list(dict.fromkeys([*own, *SHARED_PACKAGES]))
