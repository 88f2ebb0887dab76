"""Running the sweep: each backend's series as one job, its rows, and sweep.json's document.

For every backend asked for, the sweep renders the same scene (square, ``size`` x ``size``, one sample)
at each setting of each of its series (minirt.sweep.series), times it (minirt.sweep.timing) and measures
the error against the series' converged answer, rendered once by the first row that needs it. A backend
that is missing (or fails at a setting) gives rows with status "skip" or "error" and the reason; nothing
raises.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, TypedDict

import numpy as np

from minirt.harness import backends as bk
from minirt.jobs.data import JSON, Schema
from minirt.model.result import RenderResult
from minirt.model.rules import Rules
from minirt.model.scene import Scene
from minirt.model.series import Series, Setting
from minirt.sweep.document import answers, fit_slopes, mark_pareto, write_outputs
from minirt.sweep.series import ERRORS, Catalogue, Knobs, catalogue
from minirt.sweep.timing import REPEATS, SLOW_SECONDS, timed, wall_seconds

SIZE = 256  # realistic: the exercise renders 256x256; tests pass small sizes

Progress = Callable[[int, int, str], None]


class Row(TypedDict):
    """One row of a series (``_row``, with ``timing``'s keys filled in): what a series job gives back."""

    backend: str
    knob: str | None
    value: JSON
    cost: float | None
    status: Literal["ok", "skip", "error"]
    reason: str
    seconds_median: float | None
    seconds_setup: float | None
    seconds_first: float | None
    seconds_total: float | None
    seconds_at_resolution: bool
    timer_resolution: float | None
    runs: list[float]
    metric: str | None
    error: dict[str, JSON]
    pareto: bool


def _row(
    backend: str, knob: str | None, value: Any, status: str, reason: str = "", cost: float | None = None,
    metric: str | None = None,
) -> dict:  # fmt: skip
    return {
        "backend": backend,
        "knob": knob,
        "value": value,
        "cost": cost,
        "status": status,
        "reason": reason,
        "seconds_median": None,
        "seconds_setup": None,
        "seconds_first": None,
        "seconds_total": None,
        "seconds_at_resolution": False,
        "timer_resolution": None,
        "runs": [],
        "metric": metric,
        "error": {},
        "pareto": False,
    }


class _Sweep:
    """One backend's series on one scene: its settings' rows and the converged answers they need."""

    def __init__(self, scene: Scene, repeats: int, slow_seconds: float):
        self.scene, self.repeats, self.slow_seconds = scene, repeats, slow_seconds
        self.converged: dict[str, dict[str, Any]] = {}
        self._cache: dict[str, RenderResult] = {}
        self.notify: Callable[[str], None] = lambda label: None

    def _scene(self, samples: int | None) -> Scene:
        return self.scene if samples is None else self.scene.with_overrides(samples=samples)

    # Converged answers, rendered lazily (once) by the first row that needs them.
    def truth(self, s: Series) -> RenderResult:
        t = s.truth
        if t.key not in self._cache:
            self.notify(f"converged answer: {t.key}")
            rules = t.rules or s.rules
            t0 = time.perf_counter()
            res = bk.render(t.backend, self._scene(t.samples), rules, t.options)
            self._cache[t.key] = res
            self.converged[t.key] = {"backend": t.backend, **t.describe, "rules": rules.as_dict(),
                                     "status": res.status, "reason": res.reason,
                                     "seconds": round(time.perf_counter() - t0, 6)}  # fmt: skip
        res = self._cache[t.key]
        if not res.ok:
            raise _ConvergedFailed(f"converged answer {t.key} failed: {res.reason}")
        return res

    def run(self, s: Series, setting: Setting) -> dict[str, Any]:
        def render() -> RenderResult:
            return bk.render(s.backend, self._scene(setting.samples), s.rules, setting.options)

        res, timing = timed(render, self.repeats, self.slow_seconds, s.seconds or wall_seconds)
        row = _row(s.backend, s.knob, setting.value, res.status, res.reason, setting.cost, s.metric)
        if not res.ok:
            return row
        row.update(timing)
        try:
            row["error"] = ERRORS[s.error](self.scene, s.rules, res, self.truth(s))
        except _ConvergedFailed as e:
            row["status"], row["reason"] = "error", str(e)
        if "exposure" in row["error"]:  # the scale both images were measured at: the converged answer's
            self.converged[s.truth.key]["exposure"] = row["error"]["exposure"]
        return row


class _ConvergedFailed(Exception):
    pass


def _availability(name: str) -> tuple[bool, str]:
    if name not in bk.all_names():
        return False, f"unknown backend {name!r} (known: {', '.join(bk.all_names())})"
    try:
        i = bk.info(name)
    except Exception as e:  # a broken install must not take the sweep down
        return False, f"{type(e).__name__}: {e}".splitlines()[0]
    return i.available, i.detail


# ---------------------------------------------------------------------------------------------
# Jobs: one backend's series each


@dataclass(frozen=True)
class SeriesJob:
    """One backend's series: every setting of its knobs and the converged answers they are measured
    against (rendered once, by the first row that needs them), so the series is one job."""

    scene: Scene  # at the sweep's size, one sample
    rules: Rules
    backend: str
    knobs: dict[str, Any]  # the backend's knobs as asked for (its defaults for the rest)
    repeats: int
    slow_seconds: float = SLOW_SECONDS


# Set by run_sweep when the series run in this process: each task's label, as it starts.
_notify: Callable[[str], None] | None = None


def task_count(backend: str, cat: Catalogue) -> int:
    """The rows a backend's series gives (one, a skip row, when the backend is unknown or will not load)."""
    return sum(len(s.settings) for s in cat.of(backend)) if cat.swept(backend) else 1


def run_series(job: SeriesJob) -> tuple[list[dict[str, Any]], dict[str, dict[str, Any]]]:
    """A series' rows and the converged answers it rendered; a backend missing where the job runs is one
    skip row (on a cluster: missing on that worker)."""
    name = job.backend
    ok, why = _availability(name)
    if not ok:
        return [_row(name, None, None, "skip", why)], {}
    notify = _notify or (lambda label: None)
    sweep = _Sweep(job.scene, job.repeats, job.slow_seconds)
    sweep.notify = notify
    rows = []
    for s in bk.get(name).sweep(job.scene, job.rules, job.knobs):
        for setting in s.settings:
            notify(setting.progress)
            rows.append(sweep.run(s, setting))
    return rows, sweep.converged


# What a series job gives back: its rows, and the converged answers it rendered (sweep.json's "converged").
SERIES = Schema(tuple[list[Row], dict[str, dict[str, JSON]]])


def series_fits(job: SeriesJob, got: tuple[list[Row], dict[str, dict[str, JSON]]]) -> None:
    """Raise ValueError unless ``got`` -- from a worker or the cache -- is a series of ``job``'s backend."""
    SERIES.check(got)
    rows, _ = got
    if not rows or any(r["backend"] != job.backend for r in rows):
        raise ValueError(f"not a series of {job.backend!r}")


def sweep_cache(folder: Path, backends_used: list[str], where: str, cat: Catalogue):
    """The cache of run_sweep's series in ``folder`` (minirt.jobs.cache, as data): keyed by the scene's text,
    the rules, the series' knobs, size and repeats, the versions -- and the machine the times were taken on
    (``where``: this host and its cores, or the cluster's address), since a series' times are only that
    machine's."""
    from minirt.harness.backends import versions
    from minirt.jobs.cache import Cache, data_codec, digest

    v = versions(bk.oracles_among(backends_used))

    def own(job: SeriesJob) -> dict[str, Any]:
        # only the job's own knobs: changing one backend's knobs keeps the other backends' series
        return {**cat.recorded(job.backend), "slow_seconds": job.slow_seconds}

    def key(job: SeriesJob) -> str:
        sc = job.scene
        return digest({"kind": "sweep", "source": sc.source, "digest": sc.digest, "name": sc.name,
                       "size": [sc.camera.width, sc.camera.height], "rules": job.rules.as_dict(),
                       "backend": job.backend, "knobs": own(job), "repeats": job.repeats,
                       "minirt": v["minirt"], "drjit": v["drjit"], "oracle": v.get(job.backend, ""),
                       "where": where})  # fmt: skip

    def accept(job: SeriesJob, got) -> bool:
        series_fits(job, got)
        return True

    # a series with a skip or error row may be the machine's (a renderer missing, a crash): redone next time
    return Cache(folder, key, data_codec(SERIES), keep=lambda got: all(r["status"] == "ok" for r in got[0]),
                 accept=accept)  # fmt: skip


def here() -> str:
    """The machine a local sweep's times are taken on: its name and the cores this process may use."""
    import platform

    from minirt.jobs import batch as jobs

    return f"{platform.node()}/{jobs.cores()} cores"


def run_sweep(
    scene: Scene,
    rules: Rules,
    backends: list[str],
    out_dir: Path,
    size: int = SIZE,
    repeats: int = REPEATS,
    progress: Progress | None = None,
    knobs: Knobs | None = None,
    workers: int = 1,
    scheduler: str | None = None,
    cache: Path | None = None,
    slow_seconds: float = SLOW_SECONDS,
) -> dict[str, Any]:
    """Sweep each backend's accuracy knobs on `scene` at size x size; write the files; return sweep.json's dict.

    ``knobs``: the settings to sweep, per backend by knob name ({"mitsuba": {"spp": (1, 4)}}); the rest
    are each backend's defaults. ``progress(done, total, label)`` is called before each render task
    (label: what runs now) and once at the end with done == total. ``repeats`` (>= 1) counts the timed
    runs after the untimed warm-up; ``slow_seconds``: a setting whose warm-up takes longer is timed once.

    Each backend's series is one job (minirt.jobs.batch): here, one after the other (``workers = 1``, the
    default: a timing study wants the machine to itself), in ``workers`` local processes at once, or on
    a Dask ``scheduler``'s workers -- concurrent series share cores, so their times are those of a
    loaded machine (sweep.json's ``jobs`` says how they ran; a worker runs Dr.Jit on one thread). Progress
    is then per series. ``cache``: a folder of series results by content hash (``sweep_cache``): a
    rerun renders only the series whose inputs changed.
    """
    global _notify
    from minirt.jobs import batch as jobs

    knobs = knobs or {}
    repeats = max(int(repeats), 1)
    out_dir = Path(out_dir)
    sc = scene.with_overrides(width=size, height=size, samples=1)
    cat = catalogue(sc, rules, knobs)
    todo = [SeriesJob(sc, rules, name, dict(knobs.get(name, {})), repeats, slow_seconds) for name in backends]
    total = sum(task_count(name, cat) for name in backends)
    done = 0
    here_ = scheduler is None and workers <= 1

    def started(label: str) -> None:
        if progress:
            progress(done, total, label)

    def finished(job: SeriesJob, got) -> None:
        nonlocal done
        done += len(got[0]) if here_ else task_count(job.backend, cat)
        if progress and not here_:
            progress(min(done, total), total, f"{job.backend}: done")

    def failed(job: SeriesJob, message: str):
        return [_row(job.backend, None, None, "error", message)], {}

    where = scheduler if scheduler is not None else here()
    store = None if cache is None else sweep_cache(Path(cache), backends, where, cat)
    if progress and not here_:
        progress(0, total, f"sweeping {len(todo)} series")
    _notify = started if here_ else None
    try:
        got = jobs.run(run_series, todo, workers=workers, scheduler=scheduler, on_done=finished, on_error=failed,
                       cache=store, check=series_fits)  # fmt: skip
    finally:
        _notify = None
    rows = [r for series_rows, _ in got for r in series_rows]
    converged = {k: v for _, conv in got for k, v in conv.items()}
    if progress:
        progress(total, total, "writing results")
    hits = store.hits if store else 0
    ran = {"workers": 1 if here_ else workers, "scheduler": scheduler, "where": where, "cached": hits}
    result = _document(scene, rules, size, repeats, cat, slow_seconds, ran, rows, converged)
    write_outputs(result, out_dir)
    return result


def _document(
    scene: Scene,
    rules: Rules,
    size: int,
    repeats: int,
    cat,
    slow_seconds: float,
    ran: dict[str, Any],
    rows: list[dict[str, Any]],
    converged: dict[str, Any],
) -> dict[str, Any]:
    """sweep.json's dict: the sweep's settings, its rows, and what they say (slopes, Pareto fronts, answers)."""
    slopes = fit_slopes(rows, cat)
    pareto = mark_pareto(rows, cat)
    answer = answers(rows, cat)
    return {
        "scene": scene.name,
        "source": scene.source,
        "size": [size, size],
        "repeats": repeats,
        "rules": rules.as_dict(),
        "knobs": {**cat.recorded(), "slow_seconds": slow_seconds},
        "series": cat.document(),
        "jobs": ran,
        "converged": converged,
        "rows": [_clean(r) for r in rows],
        "slopes": slopes,
        "pareto": pareto,
        "answer": _clean(answer),
        "answer_lines": [f"{scene.name} {size}x{size}: {a['line']}" for a in answer],
    }


def _clean(o: Any) -> Any:
    """JSON-safe: non-finite floats become None."""
    if isinstance(o, dict):
        return {k: _clean(v) for k, v in o.items()}
    if isinstance(o, list | tuple):
        return [_clean(v) for v in o]
    if isinstance(o, np.generic):
        o = o.item()
    if isinstance(o, float) and not math.isfinite(o):
        return None
    return o
