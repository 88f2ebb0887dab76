"""The check of scene files against the oracles as its two front ends run it: ``minirt check`` (and
``minirt report``) and the Python API's ``minirt.check``.

Both take the same steps -- which files (``scene_files``), every one read before any long work
(``read_all``), the check itself with its progress counted in jobs (``run_checks``) -- and each front end
says bad input in its own words (``--backend`` or ``backends``), in the order it always has. The command
line then prints the hazard warnings of what was checked (``hazard_warnings``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from os import PathLike
from pathlib import Path

from minirt.errors import MinirtError
from minirt.harness import backends
from minirt.harness import run as harness
from minirt.harness.results import CheckResult
from minirt.model.scene import Scene


def scene_files(items: Sequence[str | PathLike[str]] | None) -> list[Path]:
    """The scene files of SCENE...: files, bundled scenes' names and folders (their ``*.toml``, sorted);
    none: every bundled scene. An unknown name raises SceneError."""
    from minirt.model.bundled import BUNDLED, find_scene

    if not items:
        return sorted(BUNDLED.glob("*.toml"))
    out: list[Path] = []
    for item in items:
        p = Path(item)
        out += sorted(p.glob("*.toml")) if p.is_dir() else [find_scene(item)]
    return out


def read_all(paths: Sequence[Path]) -> list[Scene]:
    """Bad input first, before any long work: every scene file read (SceneError names the file and key).
    The scenes, for ``run_checks`` and ``hazard_warnings``: each file parsed once per check."""
    from minirt.model.scene import load_scene

    return [load_scene(p) for p in paths]


def refuse_cached_programs(names: Sequence[str], cache: object, spelled: str = "--cache") -> None:
    """A student's program is never checked through the cache (MinirtError): the cache knows a backend by its
    name and version, and a program's are its SPEC, not its files -- a source or script changed under the
    same SPEC would be answered from the cache."""
    programs = [n for n in names if backends.is_program(n)]
    if cache is not None and programs:
        raise MinirtError(f"{spelled}: a program ({programs[0]}) is checked afresh every time; give no cache with it")


def job_count(paths: Sequence[Path], names: Sequence[str]) -> int:
    """The steps ``run_checks`` reports: one per (scene, oracle) -- one per scene when none is an oracle."""
    return len(paths) * max(1, len(backends.oracles_among(list(names))))


def run_checks(
    paths: list[Path],
    names: list[str],
    size: tuple[int, int] | None = None,
    *,
    workers: int = 1,
    scheduler: str | None = None,
    cache: Path | None = None,
    on_step: Callable[[int, int, str, str], None] | None = None,
    scenes: Sequence[Scene] | None = None,
) -> CheckResult:
    """Render and compare every scene file with the backends (minirt.harness.run.run: ``workers``
    processes, a Dask ``scheduler`` or a ``cache`` folder make each (scene, oracle) one job).
    ``on_step(done, total, scene, backend)``: ``done`` of ``total`` (job_count) steps are behind -- in
    this process a backend of a scene is starting, on workers a job has finished (they finish in any
    order, so each counts one). ``scenes``: the files' scenes as ``read_all`` parsed them (else parsed here)."""
    tick = None
    if on_step is not None:
        total = job_count(paths, names)
        oracle_count = max(1, len(backends.oracles_among(names)))
        jobs_mode = workers > 1 or scheduler is not None or cache is not None
        finished = 0

        def tick(i: int, scene: str, name: str, j: int, n: int) -> None:
            nonlocal finished
            finished += 1
            on_step(finished if jobs_mode else i * oracle_count + j, total, scene, name)

    return harness.run(paths, names, size, tick, workers=workers, scheduler=scheduler, cache=cache, scenes=scenes)


def hazard_warnings(
    result: CheckResult,
    names: Sequence[str],
    size: tuple[int, int] | None,
    scenes: Sequence[Scene] | None = None,
) -> list[tuple[str, str]]:
    """The hazard warnings of every checked scene (minirt.reference.hazards.scene_warnings), on its
    reference render under the scene's own rules, for the float32 backends among ``names``: (scene name,
    line) pairs, scene by scene. ``scenes``: the checked files' scenes as ``read_all`` parsed them, in
    order (else parsed again)."""
    from minirt.reference import hazards

    out: list[tuple[str, str]] = []
    for i, sc in enumerate(result.scenes):
        given = None if scenes is None else scenes[i]
        scene, rules = harness.file_scene_and_rules(sc.path or sc.file, size, given)
        f32 = [n for n in sc.backends if n in names and backends.get(n).is_float32({})]
        out += [(scene.name, line) for line in hazards.scene_warnings(scene, rules, sc.reference, "f64", f32)]
    return out
