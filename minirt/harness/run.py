"""Scene files checked against backends: one (``check_scene``), or many (``run``) -- in this process, with
the renders of backends that run as a child process (POV-Ray) started ahead, or as (scene, oracle) jobs on
worker processes or a Dask cluster (minirt.jobs.batch), with a cache of their results (minirt.jobs.cache);
either after a memory pre-check (minirt.jobs.memory).
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from minirt.harness import backends
from minirt.harness.attribution import check_variants
from minirt.harness.compare import check_backend, check_text, small_kernels, start_ahead, start_chosen, start_samples
from minirt.harness.references import ReferenceCache
from minirt.harness.results import BackendCheck, CheckResult, SceneCheck, worst
from minirt.model.bundled import scene_and_rules
from minirt.model.result import RenderResult
from minirt.model.rules import Rules
from minirt.model.scene import Scene, load_scene

if TYPE_CHECKING:
    from minirt.jobs.cache import Cache


LANES = 4  # threads that wait for a scene's renders started ahead (each render's work is in its own processes)
# Threads that run ``run``'s renders started ahead (POV-Ray's, Cycles'), in the scenes' order. Two: a POV-Ray
# render mostly waits (its front end polls its renderer every 200 ms: ~0.7 s to start and ~0.2 s a frame, at
# ~0.4 CPU-s a bundled scene), and one after another its renders of the bundled scenes took 16 s of wall
# time, longer than the rest of the check, which waited for them.
AHEAD = 2
# Scenes whose checks ``run`` begins (``_Started``: their references rendered, the certified oracle's renders
# started) before it checks this one's oracles. One: two ahead measured no faster (20.8-21.2 s against
# 20.0-21.3 for the bundled scenes), and each holds its references in memory meanwhile.
BEGUN_AHEAD = 1


def scene_label(path: str | Path) -> str:
    """How a check's results name its scene file: as given, except a bundled scene (found by its name, or
    one of every bundled scene by default), named by its name, ``exercise`` -- not by where minirt happens
    to be installed, so the same check writes the same document on every machine."""
    from minirt.model.bundled import BUNDLED

    p = Path(path)
    return p.stem if p.is_absolute() and p.suffix == ".toml" and p.parent == BUNDLED else str(path)


def file_scene_and_rules(
    path: str | Path, size: tuple[int, int] | None, scene: Scene | None = None
) -> tuple[Scene, Rules]:
    """The file's scene (``scene``: already parsed from it) at ``size`` and its rules
    (minirt.model.bundled.scene_and_rules)."""
    w, h = size if size else (None, None)
    return scene_and_rules(load_scene(path) if scene is None else scene, w, h)


def check_scene(
    path: str | Path,
    names: list[str],
    size: tuple[int, int] | None = None,
    progress=None,
    variants=None,
    rendered: dict | None = None,
    loaded: tuple[Scene, Rules] | None = None,
) -> SceneCheck:
    """Check one scene file against the given backends (the reference itself is always rendered).
    ``variants``: the run's minirt.diagnose.VariantCache (default: the process's, ``shared_variants``);
    ``rendered``: backend name -> its render started earlier, ``loaded``: the file's scene and rules
    already parsed (both from ``run``)."""
    scene, rules = loaded or file_scene_and_rules(path, size)
    if rendered is None:
        # POV-Ray's render, a child process that mostly waits, starts now on a thread of its own and
        # overlaps the reference's and the other oracles' work here (as ``run`` does): the same results
        with ThreadPoolExecutor(max_workers=1) as pool:
            started = start_ahead(pool, names, scene, rules)
            if started:
                return check_scene(path, names, size, progress, variants, started, (scene, rules))
    return _Started(path, names, scene, rules, rendered).check(progress, variants)


class _Started:
    """A scene's check begun: its reference rendered, and the renders that need it -- those of an oracle
    that picks its pixels from the reference (the certified one, on a large image), and the several-sample
    renders of a scene of samples > 1 -- started beside the others' work on threads of their own (``lane``),
    which ``check`` waits for, its oracles checked last. ``run`` begins the next scene's check before it
    checks this one's oracles: the certified oracle's worker processes then trace the next scene while this
    process checks this one (they sat idle through a scene's rule diagnosis before)."""

    def __init__(self, path, names: list[str], scene: Scene, rules: Rules, rendered: dict | None):
        self.scene, self.rules, self.rendered = scene, rules, rendered or {}
        self.sc = SceneCheck(scene.name, scene_label(path), "skip", description=scene.description, path=str(path))
        self.refs = ReferenceCache(scene)
        self.sc.reference = self.refs.get(rules)
        self.oracle_names = backends.oracles_among(names)
        self.lane = ThreadPoolExecutor(max_workers=LANES)
        try:
            waiting = [n for n in self.oracle_names if n not in self.rendered]
            self.chosen = start_chosen(self.lane, waiting, scene, rules, self.refs)
            self.several = start_samples(self.lane, self.oracle_names, scene, rules, self.refs)
        except BaseException:
            self.cancel()
            raise

    def running(self) -> bool:
        """Whether a render this scene's check started is still running."""
        return any(not f.done() for f in (*self.chosen.values(), *self.several.values()))

    def check(self, progress=None, variants=None, busy=None) -> SceneCheck:
        scene, rules, sc = self.scene, self.rules, self.sc
        with self.lane:
            got = {**self.rendered, **self.chosen}
            checked = {}
            names = sorted(self.oracle_names, key=lambda n: n in self.chosen or n in self.several)
            for i, name in enumerate(names):
                if progress:
                    progress(scene.name, name, i, len(self.oracle_names))
                checked[name] = check_backend(scene, rules, name, self.refs, variants=variants, rendered=got.get(name),
                                              samples_rendered=self.several.get(name), busy=busy)  # fmt: skip
        sc.backends = {name: checked[name] for name in self.oracle_names}  # in the order asked, however they ran
        sc.verdict = worst([b.verdict for b in sc.backends.values()])  # no oracle: skip, nothing was compared
        return sc

    def cancel(self) -> None:
        self.lane.shutdown(wait=True, cancel_futures=True)


def run(
    paths: list[Path],
    names: list[str],
    size: tuple[int, int] | None = None,
    progress=None,
    workers: int = 1,
    scheduler: str | None = None,
    cache: Path | None = None,
    scenes: list[Scene] | None = None,
) -> CheckResult:
    """Check every scene file against the backends (``scenes``: the files already parsed, in order).
    ``progress(i, scene, backend, j, n)``: scene i's backend j of n is starting (in this process) or has
    finished (on workers).

    ``workers`` > 1 or a Dask ``scheduler``: each (scene, oracle) is one job of minirt.jobs.batch, run on that
    many local worker processes or on the cluster's workers; the job carries the scene file's text, so
    workers need minirt and the renderers, not the files. The verdicts and figures are the same.
    ``cache``: a folder of job results (minirt.jobs.cache, data only) keyed by the scene's text and name, the
    size, the oracle and the versions; a job it holds is not run again (jobs run one by one here then, without
    POV-Ray's renders started ahead)."""
    # each file parsed once, for every use below
    loaded = [file_scene_and_rules(p, size, None if scenes is None else scenes[i]) for i, p in enumerate(paths)]
    _fits_in_memory([s for s, _ in loaded], names, 0 if scheduler else workers if workers > 1 else 0)
    if workers > 1 or scheduler is not None or cache is not None:
        return _run_jobs(paths, loaded, names, size, progress, workers, scheduler, cache)
    variants = check_variants()
    # POV-Ray and Cycles run as separate processes: their renders of every scene start now, in the scenes'
    # order on AHEAD threads of their own, and overlap the reference's, Mitsuba's and Embree's work in this
    # process (the cores are otherwise idle while Python waits for POV-Ray). The same results, in less time.
    with ThreadPoolExecutor(max_workers=AHEAD) as pool:
        rendered = [start_ahead(pool, names, *sr) for sr in loaded]
        scenes: list[SceneCheck] = []
        begun: dict[int, _Started] = {}
        try:
            shared = any(rendered)  # renders of other processes (POV-Ray's, Blender's) share the cores
            for i in range(len(paths)):
                with _jit_pool(loaded[i][0], shared):
                    for k in range(i, i + 1 + BEGUN_AHEAD):  # this scene's check begun, and the next ones' (_Started)
                        if k < len(paths) and k not in begun:
                            begun[k] = _Started(paths[k], names, *loaded[k], rendered[k])
                    tick = None if progress is None else (lambda *a, i=i: progress(i, *a))
                    this = begun.pop(i)
                    busy = lambda this=this: this.running() or _running(rendered, begun.values())  # noqa: E731
                    scenes.append(this.check(tick, variants, busy))
        finally:
            for started in begun.values():  # an error or an interrupt: the next scene's renders are not waited for
                started.cancel()
    return CheckResult(verdict=worst([s.verdict for s in scenes]), scenes=scenes)


def _jit_pool(scene: Scene, shared: bool):
    """Dr.Jit's thread pool while ``scene`` is checked: one thread when other processes of the run share the
    cores (``shared``) and the scene's kernels in this process are short (compare.small_kernels), else as it
    is. The references, Mitsuba's renders and the rule diagnosis then run hundreds of kernels of a few
    milliseconds, and a second thread mostly waits for a core at each one's end: with one, a five-oracle
    check of the bundled scenes used 0.975x the CPU (0.89-0.995, every one of 8 pairs lower; 24.1 against
    25.0 CPU-s) in 0.98x the wall time, the same documents. A scene of many balls keeps both threads: its
    kernels pay for them (a 1,024-ball diagnosis on one thread made its check 1.9 s longer)."""
    import contextlib

    from minirt.jit import engine

    return engine.threads(1) if shared and small_kernels(scene) else contextlib.nullcontext()


def _running(rendered: list[dict], begun) -> bool:
    """Whether any render started ahead, or of a scene begun ahead, is still running."""
    return any(not f.done() for r in rendered for f in r.values()) or any(b.running() for b in begun)


def _fits_in_memory(scenes: list[Scene], names, local_workers: int) -> None:
    """Bad input before any work: a check this machine cannot hold (minirt.jobs.memory), as one line."""
    from minirt.jobs import memory

    pixels = [s.camera.width * s.camera.height for s in scenes]
    oracles = backends.oracles_among(names)
    big = max(scenes, key=lambda s: s.camera.width * s.camera.height)
    what = f"{len(scenes)} scenes, the largest" if len(scenes) > 1 else "the scene"
    memory.require(
        backends.check_bytes(pixels, oracles, local_workers),
        f"checking {what} at {big.camera.width}x{big.camera.height} against {len(oracles)} oracle(s)",
        "check at a smaller --size, or fewer scenes at a time",
    )


@dataclass(frozen=True)
class CheckJob:
    """One (scene, oracle) check of ``run`` on a worker: the scene file's text and name, the size override."""

    source: str
    text: str
    size: tuple[int, int] | None
    backend: str


def check_job(job: CheckJob) -> tuple[BackendCheck, RenderResult]:
    """A job of ``_run_jobs``: the oracle's check and the reference at the scene's samples."""
    _, rules, refs, bc = check_text(job.text, job.source, job.backend, job.size)
    return bc, refs.get(rules)


def _schema():
    """What a check job gives back (minirt.jobs.data.Schema): the oracle's check and the reference."""
    from minirt.harness.results import Check, RuleDiagnosis
    from minirt.jobs.data import Schema

    return Schema(tuple[BackendCheck, RenderResult | None], (BackendCheck, Check, RuleDiagnosis, RenderResult))


def _arrays(bc: BackendCheck, ref: RenderResult | None):
    """(where, array) for every image-shaped array of a check job's result."""
    for who, r in (("result", bc.result), ("reference", bc.reference), ("scene reference", ref)):
        if r is None:
            continue
        for name in ("hit", "shape_id", "t", "position", "normal", "color", "image8"):
            if getattr(r, name) is not None:
                yield f"{who}.{name}", getattr(r, name)
        yield from ((f"{who}.terms[{k}]", a) for k, a in r.terms.items())
        yield from ((f"{who}.aux[{k}]", a) for k, a in r.aux.items())
    for name, c in bc.checks.items():
        yield from ((f"checks[{name}].images[{k}]", a) for k, a in c.images.items())
    yield from ((f"rule_masks[{k}]", a) for k, a in bc.rule_masks.items())
    d = bc.rule_diagnosis
    if d.unexplained_mask is not None:
        yield "rule_diagnosis.unexplained_mask", d.unexplained_mask
    yield from ((f"rule_diagnosis.explained_masks[{k}]", a) for k, a in d.explained_masks.items())


def fits(job: CheckJob, got: tuple[BackendCheck, RenderResult | None], size: tuple[int, int]) -> None:
    """Raise ValueError unless ``got`` -- from a worker or a cache -- is a check job's result for ``job``:
    of the schema's types, for the job's oracle, every picture ``size`` (width, height) as the job's scene."""
    from minirt.jobs.data import JSON, check

    _schema().check(got)
    bc, ref = got
    if bc.backend != job.backend:
        raise ValueError(f"a check of {bc.backend!r}, not of {job.backend!r}")
    # what check.json and the report print of the fields typed Any: JSON data
    check(bc.rules_followed, dict[str, JSON], "rules_followed")
    for name, c in bc.checks.items():
        check(c.figures, dict[str, JSON], f"checks[{name}].figures")
    for who, r in (("result", bc.result), ("reference", bc.reference), ("scene reference", ref)):
        if r is not None:
            check(r.meta, dict[str, JSON], f"{who}.meta")
    w, h = size
    for r in (bc.result, bc.reference, ref):
        if r is not None and (r.width, r.height) != (w, h):
            raise ValueError(f"a {r.width}x{r.height} render of a {w}x{h} scene")
    for where, a in _arrays(bc, ref):
        if a.shape[:2] != (h, w):
            raise ValueError(f"{where} has shape {a.shape}, not the scene's {h}x{w}")


def check_cache(folder: Path, oracles: list[str], sizes: dict[CheckJob, tuple[int, int]]) -> Cache:
    """The cache of ``run``'s jobs in ``folder``: results with arrays, as data (minirt.jobs.cache);
    ``sizes``: each job's image size, which an entry must have."""
    from minirt.harness.backends import versions
    from minirt.jobs.cache import Cache, data_codec, digest

    v = versions(oracles)

    def key(job: CheckJob) -> str:
        return digest({"kind": "check", "source": job.source, "text": job.text, "size": job.size,
                       "backend": job.backend, "minirt": v["minirt"], "drjit": v["drjit"],
                       "oracle": v.get(job.backend, "")})  # fmt: skip

    def accept(job: CheckJob, got) -> bool:
        fits(job, got, sizes[job])
        return True

    # an error may be passing (a dead worker, a crashed renderer): never stored, redone next time
    return Cache(folder, key, data_codec(_schema()), keep=lambda got: got[0].verdict != "error", accept=accept)


def _run_jobs(paths, loaded, names, size, progress, workers, scheduler, cache: Path | None = None) -> CheckResult:
    """``run``'s scene files as jobs; ``loaded``: their (scene, rules), parsed before any job starts."""
    from minirt.jobs import batch as jobs

    oracles = backends.oracles_among(names)
    todo = [
        CheckJob(str(p), Path(p).read_text(encoding="utf-8"), size, n) for p in paths for n in oracles
    ]  # fmt: skip
    index = {id(j): (k // max(len(oracles), 1), k % max(len(oracles), 1)) for k, j in enumerate(todo)}

    def done(job: CheckJob, _result) -> None:
        if progress:
            i, j = index[id(job)]
            progress(i, loaded[i][0].name, job.backend, j + 1, len(oracles))

    def failed(job: CheckJob, message: str):
        return BackendCheck(backend=job.backend, verdict="error", reason=message), None

    cameras = {j: loaded[index[id(j)][0]][0].camera for j in todo}
    sizes = {j: (c.width, c.height) for j, c in cameras.items()}  # what a result from a worker or the cache must be
    store = None if cache is None else check_cache(cache, oracles, sizes)
    got = jobs.run(check_job, todo, workers=workers, scheduler=scheduler, on_done=done, on_error=failed, cache=store,
                   check=lambda job, result: fits(job, result, sizes[job]))  # fmt: skip
    scenes = []
    for i, (p, (scene, rules)) in enumerate(zip(paths, loaded, strict=True)):
        sc = SceneCheck(scene.name, scene_label(p), "skip", description=scene.description, path=str(p))
        for j, name in enumerate(oracles):
            bc, ref = got[i * len(oracles) + j]
            sc.backends[name] = bc
            sc.reference = sc.reference or ref
        if sc.reference is None:  # no oracle (or every job died): the reference itself, here
            sc.reference = ReferenceCache(scene).get(rules)
        sc.verdict = worst([b.verdict for b in sc.backends.values()])  # no oracle: skip, nothing was compared
        scenes.append(sc)
    return CheckResult(verdict=worst([s.verdict for s in scenes]), scenes=scenes)
