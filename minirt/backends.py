"""Run any backend by name: "reference" (the tracer) or an oracle. Sits above the core and oracles.

Whatever a backend does -- missing, crashing, unable to reproduce the scene -- this returns a
RenderResult; a failure is a result with status "skip" or "error" and a one-line reason.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

from minirt.errors import MinirtError
from minirt.result import RenderResult
from minirt.rules import Rules
from minirt.scene import Scene

REFERENCE = "reference"


def oracle_names() -> list[str]:
    from minirt import oracles

    return oracles.names()


def all_names() -> list[str]:
    return [REFERENCE, *oracle_names()]


def parse_backends(spec: str) -> list[str]:
    """'all', 'reference', or a comma-separated list; unknown names are bad input."""
    if spec.strip() == "all":
        return all_names()
    names = [s.strip() for s in spec.split(",") if s.strip()]
    known = all_names()
    unknown = [n for n in names if n not in known]
    if unknown or not names:
        raise MinirtError(
            f"--backend: unknown backend {', '.join(unknown) or repr(spec)} (known: all, {', '.join(known)})"
        )
    return names


def require_oracle(names: list[str], spelled: str = "--backend") -> None:
    """A comparison needs something to compare with: the reference alone is bad input."""
    if not [n for n in names if n != REFERENCE]:
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
    if name == REFERENCE:
        from minirt.engine import llvm_status

        ok, why = llvm_status()
        if ok:
            import drjit

            why = f"minirt tracer on Dr.Jit {drjit.__version__} ({why})"
        return BackendInfo(name, ok, why, True)
    from minirt import oracles

    try:
        o = oracles.get(name)
        ok, why = o.available()
        return BackendInfo(name, ok, o.version() if ok else why, o.shades)
    except Exception as e:  # a broken install must not take the others down
        return BackendInfo(name, False, f"cannot load: {type(e).__name__}: {e}", False)


def rules_for(name: str, rules: Rules) -> Rules:
    """The rules a backend actually follows when asked for `rules`."""
    if name == REFERENCE:
        return rules
    from minirt import oracles

    return oracles.get(name).adapt(rules)


def render(name: str, scene: Scene, rules: Rules, options: dict[str, Any] | None = None, progress=None) -> RenderResult:
    """Render with one backend under the rules it can follow; never raises for the backend's failure."""
    w, h = scene.camera.width, scene.camera.height
    options = dict(options or {})
    t0 = time.perf_counter()
    try:
        if name == REFERENCE:
            from minirt import tracer

            result = tracer.render(
                scene,
                rules,
                precision=options.get("precision", "f64"),
                prune=options.get("prune", True),
                progress=progress,
                diagnostics=bool(options.get("diagnostics", False)),
                terms=options.get("terms"),
                runtime=options.get("runtime"),  # None: the tracer's choice by image size
            )
        else:
            from minirt import oracles

            o = oracles.get(name)
            ok, why = o.available()
            if not ok:
                return RenderResult.failed(name, w, h, "skip", why)
            result = o.render(scene, o.adapt(rules), options)
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
    """Render with one backend and write its files (minirt.imageio.write_result); (result, paths), paths
    None when the backend failed. With ``stream``, a reference image larger than one tile
    (tracer.TILE_PIXELS) under the default output rules is written tile by tile as it is traced
    (imageio.write_tiles): its memory is one tile's, whatever the size; the returned result then
    carries the metadata only (no buffers). ``variant``: what differs from the scene's own model (see
    minirt.names), recorded in the metadata and so in the sidecar."""
    from minirt import bitmap, tracer
    from minirt.imageio import write_result, write_tiles

    w, h = scene.camera.width, scene.camera.height
    options = dict(options or {})
    if stream and name == REFERENCE and w * h > tracer.TILE_PIXELS and bitmap.is_default(rules):
        t0 = time.perf_counter()
        try:
            tr = tracer.Tracer(scene, rules, precision=options.get("precision", "f64"))

            def tiles():
                for y0, tile in tr.tiles(progress):
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
