"""minirt: a reference ray tracer for ETH Informatik I problem 13.1, and the harness that checks it.

The Python API is the command line's work as functions (the README's "Python API" has an example):

- ``load_scene(path_or_name)``: a scene file, or a bundled scene by name (``"exercise"``).
- ``render(scene, backend="reference", ...)``: one backend's ``RenderResult``, NumPy arrays throughout.
- ``check(scenes, backends="all", ...)``: the harness's ``CheckResult`` (what ``minirt check`` prints).
- ``grade(scene, image, ...)``: a ``Grade`` of another tracer's image (what ``minirt grade`` prints).

Bad input raises ``MinirtError`` (``SceneError`` for a scene), with a message for a person. Everything
is imported on first use, so ``import minirt`` costs no Dr.Jit, Mitsuba or NumPy.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from os import PathLike
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from minirt.errors import MinirtError, SceneError
    from minirt.grading.grade import Grade
    from minirt.harness.results import CheckResult
    from minirt.model.result import RenderResult
    from minirt.model.scene import Scene

from minirt.version import __version__

__all__ = [
    "CheckResult",
    "Grade",
    "MinirtError",
    "RenderResult",
    "Scene",
    "SceneError",
    "__version__",
    "check",
    "grade",
    "load_scene",
    "render",
]

# The types named in __all__, imported when first asked for (PEP 562).
_LAZY = {
    "CheckResult": "minirt.harness.results",
    "Grade": "minirt.grading.grade",
    "MinirtError": "minirt.errors",
    "RenderResult": "minirt.model.result",
    "Scene": "minirt.model.scene",
    "SceneError": "minirt.errors",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'minirt' has no attribute {name!r}")


def load_scene(scene: str | PathLike[str]) -> Scene:
    """Read a scene: a TOML file, or a bundled scene's name (``minirt scenes`` lists them). A path that
    exists wins over a name. Raises SceneError for a missing file, an unknown name or an invalid scene,
    one line per problem naming file and key."""
    from minirt.model.bundled import find_scene
    from minirt.model.scene import load_scene as _load_file

    return _load_file(find_scene(scene))


def render(
    scene: Scene | str | PathLike[str],
    backend: str = "reference",
    *,
    width: int | None = None,
    height: int | None = None,
    samples: int | None = None,
    profile: str | None = None,
    rules: Mapping[str, Any] | None = None,
    precision: str = "f64",
    **options: Any,
) -> RenderResult:
    """Render a scene with one backend: ``"reference"`` (the tracer), ``"mitsuba"``, ``"povray"`` or
    ``"embree"``, as ``minirt render`` does (without writing files).

    ``scene``: a Scene, a scene file or a bundled scene's name. ``width``, ``height``, ``samples`` and
    ``profile`` override the scene's; ``rules`` overrides model rules (``{"clamp": True}``, as
    ``--rule clamp=true``); ``precision``: the reference's ``"f64"`` or ``"f32"``. Further ``options``
    go to the backend (e.g. Mitsuba's ``mode="sensor"``, ``spp=64``); with ``samples``, Mitsuba renders
    with its stochastic sensor at that many samples per pixel, as the CLI does.

    The result's NumPy arrays, images of shape (H, W) or (H, W, 3) with row 0 at the top: ``color``
    (linear, before clamping; None for a backend that does not shade, Embree), ``terms`` (the shading
    terms that add up to it), ``hit``, ``shape_id`` (-1 on a miss), ``t`` (+inf on a miss),
    ``position``, ``normal``; ``color8()`` is the exercise's 8-bit bitmap; ``meta`` the backend,
    version, settings, rules, effects and timings. Raises MinirtError for bad input and for a
    backend that could not render (missing, or broken), with its reason.
    """
    from minirt.errors import MinirtError
    from minirt.harness import backends
    from minirt.model.bundled import scene_and_rules

    names = backends.parse_backends(backend)
    if len(names) != 1:
        raise MinirtError(f"render: one backend at a time, got {backend!r}")
    name = names[0]
    s, r = scene_and_rules(scene, width, height, samples, profile, rules)
    opts: dict[str, Any] = backends.get(name).options(precision, samples)
    opts.update(options)
    result = backends.render(name, s, r, opts)
    if not result.ok:
        raise MinirtError(f"{name}: {result.status}: {result.reason}")
    return result


def check(
    scenes: str | PathLike[str] | Sequence[str | PathLike[str]] | None = None,
    backends: str | Sequence[str] = "all",
    *,
    size: tuple[int, int] | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    cache: str | PathLike[str] | None = None,
) -> CheckResult:
    """Compare the reference tracer with the oracles on scene files, as ``minirt check`` does:
    geometry pixel by pixel, shading, rules, one verdict per scene and backend.

    ``scenes``: a scene file, a bundled scene's name, a folder of scene files, or a list of them;
    None checks every bundled scene. ``backends``: ``"all"``, a comma list or a list of names; a student's
    program, ``"program:SPEC"`` (last), gives only an image: its geometry check is SKIP, its image compared.
    ``size``: (width, height) to render at instead of each scene's own. ``workers`` / ``scheduler``:
    each (scene, oracle) check as a Dask job on that many local processes or on a running cluster (give
    one; neither: every check in this process);
    ``cache``: a folder keeping each check's result by content hash (``minirt check --cache``).

    Returns the harness's CheckResult: ``verdict`` (the worst: pass, warn, fail, error or skip),
    ``scenes`` (per scene its ``backends``, each a BackendCheck with verdict, reason and figures),
    ``as_dict()`` (check.json's content) and ``exit_code()`` (the CLI's: 0 pass, warn or skip; 1 fail;
    2 error). Raises MinirtError for bad input (an unknown backend, a missing or invalid scene).
    """
    from minirt.errors import MinirtError
    from minirt.harness import backends as backends_mod
    from minirt.harness import checks
    from minirt.jobs import batch as jobs

    spec = backends if isinstance(backends, str) else ",".join(backends)
    names = backends_mod.parse_backends(spec)
    backends_mod.require_oracle(names, "backends", programs_too=True)
    checks.refuse_cached_programs(names, cache, "cache")
    if size is not None and (len(size) != 2 or min(size) < 1):
        raise MinirtError(f"size {size!r}: expected (width, height), each >= 1")
    if scenes is None:
        paths = checks.scene_files(None)
    else:
        items = [scenes] if isinstance(scenes, str | PathLike) else list(scenes)
        paths = checks.scene_files(items) if items else []
        if not paths:
            raise MinirtError(f"check: no scene files in {scenes!s}")
    checks.read_all(paths)  # bad input first, before any long work
    workers = jobs.pool(workers, scheduler, default=1)
    folder = None if cache is None else Path(cache)
    return checks.run_checks(
        paths, names, tuple(size) if size else None, workers=workers, scheduler=scheduler, cache=folder
    )


def grade(
    scene: Scene | str | PathLike[str],
    image: str | PathLike[str],
    *,
    size: tuple[int, int] | None = None,
    profile: str | None = None,
    rules: Mapping[str, Any] | None = None,
) -> Grade:
    """Grade another tracer's image of a scene, as ``minirt grade SCENE IMAGE`` does: is it the
    exercise's model, and if not, which rule settings explain it.

    ``scene``: a Scene, a scene file or a bundled scene's name; ``image``: PNG, BMP, PPM/PGM, TGA,
    TIFF or EXR. ``size``: (width, height) the scene is rendered at (the image's, when it differs from
    the scene's own); ``profile`` and ``rules``: the model the image is graded against, as for render.

    Returns a Grade: ``verdict`` ("match" or "differs"), ``summary()``, ``diagnosis`` (``changed``: the
    rule settings that explain the image; ``mismatch_pixels``: what nothing explains), ``reproduce()``
    (the ``minirt render`` command whose PNG is the image) and ``as_dict()`` (grade.json's content).
    Raises MinirtError for bad input (an unreadable image, a size that does not fit the scene).
    """
    from minirt.grading import grade as grading
    from minirt.model.bundled import find_scene, scene_and_rules
    from minirt.model.scene import Scene

    if isinstance(scene, Scene):
        given, scene_file = scene, scene.source or scene.name
    else:  # the file's path, for the reproduce command and grade.json
        scene_file = str(find_scene(scene))
        given = scene_file
    w, h = size if size else (None, None)
    s, r = scene_and_rules(given, w, h, None, profile, rules)
    return grading.grade_image(s, scene_file, Path(image), r, size_override=tuple(size) if size else None)
