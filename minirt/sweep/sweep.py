"""What accuracy costs in time: turn each backend's accuracy knob, measure time and error on one scene.

For every backend the sweep renders the same scene (square, ``size`` x ``size``) at each setting of
its knob, times it, and measures the error against that backend's *converged* answer:

| backend   | knob          | settings (defaults)        | error against (converged answer)                     |
|-----------|---------------|----------------------------|------------------------------------------------------|
| reference | precision     | f32, f64 (1 sample)        | the f64 render: t relative error, hit/id mismatches, |
|           |               |                            | colour RMSE and FLIP (f64's own row is 0 by design)  |
| reference | spp           | 1, 4, 16, 64, 256          | reference f64 at 1024 spp, same rules: RMSE, FLIP    |
| mitsuba   | spp           | 1, 4, ..., 1024            | Mitsuba's own 4096 spp (another seed): its shading    |
|           |               |                            | differs from the exercise by design (no ambient,     |
|           |               |                            | 1/(pi r^2) falloff), so only it can be its own limit |
| povray    | antialias     | off, +A0.0 +R1 ... +R4      | reference at 1024 spp under POV-Ray's rules          |
| povray    | samples       | 1, 4, 16 (the exercise's     | the same, pixel corner: POV-Ray renders the          |
|           |               | stratified samples)        | reference's own samples through its mesh camera      |
| embree    | subdivisions  | 0 ... 7                    | the analytic geometry (reference f64, 1 ray/pixel,   |
|           |               |                            | Embree's rules): t relative error, hit/id mismatches |

Conventions and choices (each is a place where the numbers could mislead):

- Samples: ``spp = 1`` is the rules' single ray per pixel (the exercise's pixel corner), not a random
  one; ``spp > 1`` averages stratified jittered samples over the pixel square [x, x+1) x [y, y+1)
  (reference, ``minirt.model.camera``) or Mitsuba's ``independent`` sampler (box filter). The converged
  render uses the same estimator, so its own error is about that of the 256/1024-spp rows divided by
  two: read errors far below it as "at the floor".
- POV-Ray: method 1 with threshold 0 supersamples every pixel on an R x R jittered grid *plus* its
  centre ray, averaged with weight 1/(R^2 + 1) each (``tracetask.cpp`` SupersampleOnePixel), so its
  cost in rays per pixel is R^2 + 1 and it converges to a centre-weighted average, not the box the
  reference averages: expect a floor. Its pixel square is centred on the ray it shoots, so POV-Ray and
  its converged reference are rendered with rule ``pixel_sample = "center"`` (with "corner" the
  skewed camera shifts the supersampled square by half a pixel against the reference's samples).
  The rows are colour only (no geometry frames, no 8-bit pass): one POV-Ray invocation per render.
- Time: each setting is rendered once untimed (the warm-up: JIT compilation, kernel and mesh caches,
  module imports), then ``repeats`` times (only once when the warm-up took longer than
  ``slow_seconds``): even ``repeats = 1`` keeps compilation out of the time. ``seconds_median`` is
  the median of the timed runs and ``seconds_setup`` the warm-up's excess over it. POV-Ray starts a
  process per render (~0.65 s whatever the size, measured from its own statistics): that start-up is
  its ``seconds_setup`` and is *not* in its ``seconds_median`` (the time inside POV-Ray: parse,
  bounding, trace), ``seconds_total`` has both. POV-Ray's statistics count whole milliseconds: a
  median below 1 ms is recorded *at* 1 ms with ``seconds_at_resolution`` true (an upper bound, drawn
  hollow with a left arrow, "≤" in the tables), never as 0 (which would vanish from a log plot). Times
  are wall clock of ``minirt.harness.backends.render`` (POV-Ray: of its process), on however many cores the
  machine has.
- Errors: colours are clipped to [0, 1] first (what the 8-bit image shows). RMSE is over pixels and
  channels; FLIP is the mean LDR ꟻLIP (``flip_evaluator``, 67 pixels per degree) with the clipped
  linear values taken as display values, as the exercise writes them without a gamma curve. Geometry:
  ``mask_mismatch`` is the fraction of pixels whose hit/miss differs, ``id_mismatch`` whose shape id
  differs, ``t_rel_mean``/``t_rel_max`` the relative t error over pixels that hit the same shape.
- Fits: least squares of log(error) against log(cost), cost = samples per pixel (R^2 + 1 for POV-Ray)
  or triangles per ball (20 4^N for Embree, so ``factor_per_level`` = 4^slope: theory 1/4, the
  radial gap of an inscribed icosphere shrinks with the square of its edge), and against log(time).
  Points with error 0 (below measurement) are left out of fits and plots. Pareto front: the settings
  no other setting of the same series beats in both time and error. Plots: colour error and t error
  have different units and go on separate axes (side by side in ``sweep.png``).
- The answer (``answer`` and ``answer_lines`` in sweep.json, printed by ``minirt sweep``, the top of
  sweep.md and of the report's sweep section): per backend, the cheapest setting (shortest median
  time) whose colour RMSE against the converged image is below one 8-bit level (1/255), e.g. "error
  < 1/255 costs 0.055 s with the reference at 16 spp". RMSE, not the largest pixel difference: an
  edge pixel of a finite-sample render stays off by more than a level long after the image as a
  whole has converged. Embree does not shade: its criterion is the harness's geometry check passing
  with a mean relative t error below GEOMETRY_T_REL (why at the constant). When no setting reaches
  it the line says so and names the most accurate one tried. ``reference/precision`` is no
  candidate (measured against f64 itself).

API: :func:`run_sweep` writes ``sweep.csv``, ``sweep.md``, ``sweep.json``, one ``sweep-<backend>.png``
per backend and ``sweep.png`` (all series) into ``out_dir`` and returns the JSON dict. The knob
lists are module constants, overridable per call through :class:`Knobs`. A backend that is missing
(or fails at a setting) gives rows with status "skip" or "error" and the reason; nothing raises.
"""

from __future__ import annotations

import csv
import io
import math
import statistics
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from minirt.harness import backends as bk
from minirt.io.atomic import atomic_path
from minirt.io.images import write_json
from minirt.model.result import RenderResult
from minirt.model.rules import Rules
from minirt.model.scene import Scene

REFERENCE_PRECISIONS = ("f32", "f64")
REFERENCE_SPP = (1, 4, 16, 64, 256)
MITSUBA_SPP = (1, 4, 16, 64, 256, 1024)
POVRAY_ANTIALIAS = (0, 1, 2, 3, 4)  # 0: antialiasing off (-A); R > 0: +A0.0 +R{R}
POVRAY_SAMPLES = (1, 4, 16)  # the exercise's samples through POV-Ray's mesh camera (64 at 256² passes its ray limit)
EMBREE_SUBDIVISIONS = (0, 1, 2, 3, 4, 5, 6, 7)
CONVERGED_REFERENCE_SPP = 1024
CONVERGED_MITSUBA_SPP = 4096
MITSUBA_SEED = 0
MITSUBA_CONVERGED_SEED = 1  # a different seed: the converged render must not share the rows' samples
SLOW_SECONDS = 5.0  # a setting whose first run takes longer is timed once more only
SIZE = 256  # realistic: the exercise renders 256x256; tests pass small sizes
REPEATS = 3

Progress = Callable[[int, int, str], None]


@dataclass(frozen=True)
class Knobs:
    """The settings swept per backend (defaults: the module constants)."""

    reference_precisions: tuple[str, ...] = REFERENCE_PRECISIONS
    reference_spp: tuple[int, ...] = REFERENCE_SPP
    mitsuba_spp: tuple[int, ...] = MITSUBA_SPP
    povray_antialias: tuple[int, ...] = POVRAY_ANTIALIAS
    povray_samples: tuple[int, ...] = POVRAY_SAMPLES
    embree_subdivisions: tuple[int, ...] = EMBREE_SUBDIVISIONS
    converged_reference_spp: int = CONVERGED_REFERENCE_SPP
    converged_mitsuba_spp: int = CONVERGED_MITSUBA_SPP
    slow_seconds: float = SLOW_SECONDS


# What each series is measured by, what its cost axis is, and what theory expects.
SERIES: dict[str, dict[str, str]] = {
    "reference/precision": {"metric": "rmse", "cost": "bits", "theory": "f32 vs f64: rounding only"},
    "reference/spp": {"metric": "rmse", "cost": "samples per pixel",
                      "theory": "spp^-0.5 (random) to spp^-0.75 (stratified, edges)"},
    "mitsuba/spp": {"metric": "rmse", "cost": "samples per pixel", "theory": "spp^-0.5 (independent sampler)"},
    "povray/antialias": {"metric": "rmse", "cost": "rays per pixel (R^2 + 1)",
                         "theory": "~(R^2+1)^-0.75 (jittered grid, edges) down to a floor (centre-weighted filter)"},
    "povray/samples": {"metric": "rmse", "cost": "rays per pixel",
                       "theory": "as reference/spp: the same stratified samples, at POV-Ray's cost per ray"},
    "embree/subdivisions": {"metric": "t_rel_mean", "cost": "triangles per ball (20 4^N)",
                            "theory": "faces^-1, i.e. 4^-N (radial gap of the inscribed icosphere)"},
}  # fmt: skip

# Okabe & Ito's colour-blind-safe palette, one colour per series
PALETTE = {
    "reference/spp": "#0072B2",
    "reference/precision": "#56B4E9",
    "mitsuba/spp": "#E69F00",
    "povray/antialias": "#009E73",
    "povray/samples": "#CC79A7",
    "embree/subdivisions": "#D55E00",
}
MARKERS = {"reference/spp": "o", "reference/precision": "D", "mitsuba/spp": "s", "povray/antialias": "^",
           "povray/samples": "P", "embree/subdivisions": "v"}  # fmt: skip


# ---------------------------------------------------------------------------------------------
# Errors


def color_errors(test: np.ndarray, ref: np.ndarray, exposure: float = 1.0) -> dict[str, float]:
    """RMSE, largest absolute difference and mean ꟻLIP of two linear colour images, each multiplied by
    `exposure` and clipped to [0, 1]."""
    a = np.clip(np.nan_to_num(np.asarray(test, dtype=np.float64) * exposure, nan=0.0), 0.0, 1.0)
    b = np.clip(np.nan_to_num(np.asarray(ref, dtype=np.float64) * exposure, nan=0.0), 0.0, 1.0)
    out = {"rmse": float(np.sqrt(np.mean((a - b) ** 2))), "max_abs": float(np.max(np.abs(a - b)))}
    out["flip"] = flip(a, b)
    return out


def exposure(color: np.ndarray) -> float:
    """1 / the 99.9th percentile of the brightest channel per pixel (1 for a black image): Mitsuba's
    colours are radiance (I / (pi r^2) falloff, ~1e-3 here), so errors are measured after scaling."""
    hi = float(np.percentile(np.max(np.nan_to_num(color), axis=-1), 99.9))
    return 1.0 / hi if hi > 0 and math.isfinite(hi) else 1.0


def flip(test: np.ndarray, ref: np.ndarray) -> float | None:
    """Mean LDR ꟻLIP of `test` against `ref` (values in [0, 1] taken as display values); None if unavailable."""
    try:
        import flip_evaluator
    except ImportError:
        return None
    if np.array_equal(test, ref):
        return 0.0
    _, mean, _ = flip_evaluator.evaluate(
        np.ascontiguousarray(ref, dtype=np.float32), np.ascontiguousarray(test, dtype=np.float32), "LDR",
        inputsRGB=True, applyMagma=False, computeMeanError=True,
    )  # fmt: skip
    return float(mean)


def geometry_errors(test: RenderResult, ref: RenderResult) -> dict[str, float]:
    """Hit/id mismatch fractions and relative t error (over pixels hitting the same shape)."""
    n = ref.hit.size
    same = ref.hit & test.hit & (ref.shape_id == test.shape_id)
    out = {
        "mask_mismatch": float(np.count_nonzero(ref.hit != test.hit) / n),
        "id_mismatch": float(np.count_nonzero(ref.shape_id != test.shape_id) / n),
        "t_rel_mean": 0.0,
        "t_rel_max": 0.0,
        "compared": int(np.count_nonzero(same)),
    }
    if out["compared"]:
        rel = np.abs(test.t[same] - ref.t[same]) / np.abs(ref.t[same])
        out["t_rel_mean"] = float(np.mean(rel))
        out["t_rel_max"] = float(np.max(rel))
    return out


def harness_geometry(scene: Scene, rules: Rules, ref: RenderResult, res: RenderResult) -> dict[str, Any]:
    """The harness's own geometry check (``minirt check``'s tolerances: silhouette band, t and normal
    bounds from the oracle's declared precision): its verdict and the pixels beyond tolerance."""
    from minirt.harness.geometry import check_geometry

    g = check_geometry(scene, rules, ref, res)
    f = g.figures
    beyond = sum(int(f.get(k, 0)) for k in ("mask_mismatch_outside_band", "id_mismatch", "depth_violations",
                                             "normal_violations"))  # fmt: skip
    return {"geometry_check": g.verdict, "geometry_beyond_tolerance": beyond}


# ---------------------------------------------------------------------------------------------
# Timing


POVRAY_STAGES = ("parse", "bounding", "photon", "radiosity", "trace")  # POV-Ray's own statistics (1 ms steps)
POVRAY_RESOLUTION = 0.001


def _seconds(res: RenderResult) -> tuple[float, float, float]:
    """(time of the render itself, per-run start-up, the timer's resolution; 0: fine-grained) of one result."""
    tm = res.meta.get("timings", {})
    if res.backend == "povray" and "passes" in tm:
        # the EXR pass is the image; the unantialiased render adds an 8-bit PNG pass (exact rounding only)
        passes = [tm["passes"]["exr"]] if "exr" in tm["passes"] else list(tm["passes"].values())
        work = sum(p.get(k, 0.0) for p in passes for k in POVRAY_STAGES)
        return round(work, 6), sum(p["wall"] for p in passes) - work, POVRAY_RESOLUTION
    return float(tm.get("wall", math.nan)), 0.0, 0.0


def _timed(render: Callable[[], RenderResult], repeats: int, slow_seconds: float) -> tuple[RenderResult, dict]:
    """One untimed warm-up render, then `repeats` timed ones (one when the warm-up took longer than
    `slow_seconds`); the last result and the timing summary."""
    res = render()  # warm-up: JIT compilation, kernel and mesh caches, imports -- never in the median
    if not res.ok:
        return res, {}
    first, first_startup, _ = _seconds(res)
    runs, startups = [], []
    resolution = 0.0
    for _ in range(1 if first + first_startup > slow_seconds else max(repeats, 1)):
        r = render()
        if not r.ok:
            return r, {}
        s, st, resolution = _seconds(r)
        runs.append(s)
        startups.append(st)
        res = r
    median = statistics.median(runs)
    startup = statistics.median(startups)
    # A time below the timer's resolution (POV-Ray's statistics count whole milliseconds) is not 0: it is
    # plotted and fitted at the resolution and marked as an upper bound.
    floored = resolution > 0 and median < resolution
    if floored:
        median = resolution
    if startup > 0:  # a per-run start-up (POV-Ray's process): that is the setup
        setup: float = startup
    else:
        setup = max(first - median, 0.0)
    timing = {
        "seconds_median": median,
        "seconds_setup": setup,
        "seconds_first": first + first_startup,
        "seconds_total": median + startup,
        "seconds_at_resolution": floored,
        "timer_resolution": resolution or None,
        "runs": [round(r + s, 6) for r, s in zip(runs, startups, strict=True)],
    }
    return res, timing


# ---------------------------------------------------------------------------------------------
# The sweep


@dataclass
class _Task:
    backend: str
    knob: str
    value: Any
    cost: float
    label: str
    render: Callable[[], RenderResult]
    errors: Callable[[RenderResult], dict[str, Any]]


def _row(task: _Task | None, backend: str, knob: str | None, value: Any, status: str, reason: str = "") -> dict:
    return {
        "backend": backend,
        "knob": knob,
        "value": value,
        "cost": task.cost if task else None,
        "status": status,
        "reason": reason,
        "seconds_median": None,
        "seconds_setup": None,
        "seconds_first": None,
        "seconds_total": None,
        "seconds_at_resolution": False,
        "timer_resolution": None,
        "runs": [],
        "metric": SERIES.get(f"{backend}/{knob}", {}).get("metric"),
        "error": {},
        "pareto": False,
    }


class _Sweep:
    def __init__(self, scene: Scene, rules: Rules, knobs: Knobs, repeats: int):
        self.scene, self.rules, self.knobs, self.repeats = scene, rules, knobs, repeats
        self.converged: dict[str, dict[str, Any]] = {}
        self._cache: dict[str, RenderResult] = {}
        self.notify: Callable[[str], None] = lambda label: None

    # Converged answers, rendered lazily (once) by the first row that needs them.
    def _conv(self, key: str, render: Callable[[], RenderResult], describe: dict[str, Any]) -> RenderResult:
        if key not in self._cache:
            self.notify(f"converged answer: {key}")
            t0 = time.perf_counter()
            res = render()
            self._cache[key] = res
            self.converged[key] = {**describe, "status": res.status, "reason": res.reason,
                                   "seconds": round(time.perf_counter() - t0, 6)}  # fmt: skip
        res = self._cache[key]
        if not res.ok:
            raise _ConvergedFailed(f"converged answer {key} failed: {res.reason}")
        return res

    def reference_at(self, rules: Rules, spp: int, precision: str = "f64") -> RenderResult:
        return bk.render("reference", self.scene.with_overrides(samples=spp), rules, {"precision": precision})

    def tasks(self, name: str) -> list[_Task]:
        k, sc, rules = self.knobs, self.scene, self.rules
        out: list[_Task] = []
        if name == "reference":
            f64 = lambda: self._conv("reference/f64", lambda: self.reference_at(rules, 1), {  # noqa: E731
                "backend": "reference", "precision": "f64", "spp": 1, "rules": rules.as_dict()})  # fmt: skip

            def prec_err(res: RenderResult) -> dict[str, Any]:
                ref = f64()
                return {**geometry_errors(res, ref), **color_errors(res.color, ref.color)}

            for p in k.reference_precisions:
                bits = {"f32": 32, "f64": 64}.get(p, math.nan)
                out.append(_Task("reference", "precision", p, bits, f"reference {p}",
                                 lambda p=p: self.reference_at(rules, 1, p), prec_err))  # fmt: skip
            n = k.converged_reference_spp
            conv = lambda: self._conv(f"reference/{n}spp", lambda: self.reference_at(rules, n), {  # noqa: E731
                "backend": "reference", "precision": "f64", "spp": n, "rules": rules.as_dict()})  # fmt: skip
            for s in k.reference_spp:
                out.append(_Task("reference", "spp", s, s, f"reference {s} spp",
                                 lambda s=s: self.reference_at(rules, s),
                                 lambda res: color_errors(res.color, conv().color)))  # fmt: skip
        elif name == "mitsuba":
            mr = bk.rules_for("mitsuba", rules)
            n = k.converged_mitsuba_spp

            def mitsuba(spp: int, seed: int) -> RenderResult:
                return bk.render("mitsuba", sc, mr, {"mode": "sensor", "spp": spp, "seed": seed})

            key = f"mitsuba/{n}spp"
            conv = lambda: self._conv(key, lambda: mitsuba(n, MITSUBA_CONVERGED_SEED), {  # noqa: E731
                "backend": "mitsuba", "mode": "sensor", "spp": n, "seed": MITSUBA_CONVERGED_SEED,
                "rules": mr.as_dict()})  # fmt: skip

            def mitsuba_err(res: RenderResult) -> dict[str, Any]:
                ref = conv()
                e = exposure(ref.color)
                self.converged[key]["exposure"] = e
                return {**color_errors(res.color, ref.color, e), "exposure": e}

            for s in k.mitsuba_spp:
                out.append(_Task("mitsuba", "spp", s, s, f"mitsuba {s} spp", lambda s=s: mitsuba(s, MITSUBA_SEED),
                                 mitsuba_err))  # fmt: skip
        elif name == "povray":
            pr = replace(bk.rules_for("povray", rules), pixel_sample="center")
            n = k.converged_reference_spp
            conv = lambda: self._conv(f"reference/{n}spp/povray-rules", lambda: self.reference_at(pr, n), {  # noqa: E731
                "backend": "reference", "precision": "f64", "spp": n, "rules": pr.as_dict()})  # fmt: skip
            for r in k.povray_antialias:
                opts = {"geometry": False} if r == 0 else {"antialias": r}
                label = "povray antialias off" if r == 0 else f"povray +A0.0 +R{r}"
                out.append(_Task("povray", "antialias", r, r * r + 1 if r else 1, label,
                                 lambda opts=opts: bk.render("povray", sc, pr, opts),
                                 lambda res: color_errors(res.color, conv().color)))  # fmt: skip
            # The exercise's own samples (pixel corner, the rules' own pixel square): its converged answer is
            # the reference under the same rules.
            pc = bk.rules_for("povray", rules)
            conv_c = lambda: self._conv(f"reference/{n}spp/povray-rules-corner", lambda: self.reference_at(pc, n), {  # noqa: E731
                "backend": "reference", "precision": "f64", "spp": n, "rules": pc.as_dict()})  # fmt: skip
            for m in k.povray_samples:
                opts = {"geometry": False, "samples": m}
                out.append(_Task("povray", "samples", m, m, f"povray {m} exercise samples",
                                 lambda opts=opts: bk.render("povray", sc, pc, opts),
                                 lambda res: color_errors(res.color, conv_c().color)))  # fmt: skip
        elif name == "embree":
            er = bk.rules_for("embree", rules)
            exact = lambda: self._conv("reference/f64/embree-rules", lambda: self.reference_at(er, 1), {  # noqa: E731
                "backend": "reference", "precision": "f64", "spp": 1, "rules": er.as_dict()})  # fmt: skip

            def embree_err(res: RenderResult) -> dict[str, Any]:
                ref = exact()
                return {**geometry_errors(res, ref), **harness_geometry(sc, er, ref, res)}

            for lvl in k.embree_subdivisions:
                out.append(_Task("embree", "subdivisions", lvl, 20 * 4**lvl, f"embree subdivisions {lvl}",
                                 lambda lvl=lvl: bk.render("embree", sc, er, {"subdivisions": lvl}),
                                 embree_err))  # fmt: skip
        return out

    def run_task(self, t: _Task) -> dict[str, Any]:
        res, timing = _timed(t.render, self.repeats, self.knobs.slow_seconds)
        row = _row(t, t.backend, t.knob, t.value, res.status, res.reason)
        if not res.ok:
            return row
        row.update(timing)
        try:
            row["error"] = t.errors(res)
        except _ConvergedFailed as e:
            row["status"], row["reason"] = "error", str(e)
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
    """One backend's series: every setting of its knob and the converged answers they are measured
    against (rendered once, by the first row that needs them), so the series is one job."""

    scene: Scene  # at the sweep's size, one sample
    rules: Rules
    backend: str
    knobs: Knobs
    repeats: int


# Set by run_sweep when the series run in this process: each task's label, as it starts.
_notify: Callable[[str], None] | None = None


def task_count(backend: str, knobs: Knobs) -> int:
    """The rows a backend's series gives (one, a skip row, when the backend is unknown)."""
    return {
        "reference": len(knobs.reference_precisions) + len(knobs.reference_spp),
        "mitsuba": len(knobs.mitsuba_spp),
        "povray": len(knobs.povray_antialias) + len(knobs.povray_samples),
        "embree": len(knobs.embree_subdivisions),
    }.get(backend, 1)


# The knobs each series depends on (a cache key holds only its own: changing Embree's levels keeps the
# reference's series).
SERIES_KNOBS = {
    "reference": ("reference_precisions", "reference_spp", "converged_reference_spp"),
    "mitsuba": ("mitsuba_spp", "converged_mitsuba_spp"),
    "povray": ("povray_antialias", "povray_samples", "converged_reference_spp"),
    "embree": ("embree_subdivisions",),
}


def run_series(job: SeriesJob) -> tuple[list[dict[str, Any]], dict[str, dict[str, Any]]]:
    """A series' rows and the converged answers it rendered; a backend missing where the job runs is one
    skip row (on a cluster: missing on that worker)."""
    name = job.backend
    ok, why = _availability(name)
    if not ok:
        return [_row(None, name, None, None, "skip", why)], {}
    notify = _notify or (lambda label: None)
    sweep = _Sweep(job.scene, job.rules, job.knobs, job.repeats)
    sweep.notify = notify
    rows = []
    for t in sweep.tasks(name):
        notify(t.label)
        rows.append(sweep.run_task(t))
    return rows, sweep.converged


def sweep_cache(folder: Path, backends_used: list[str], where: str):
    """The cache of run_sweep's series in ``folder`` (minirt.jobs.cache): keyed by the scene's text, the rules,
    knobs, size and repeats, the versions -- and the machine the times were taken on (``where``: this
    host and its cores, or the cluster's address), since a series' times are only that machine's."""
    from minirt.harness.backends import versions
    from minirt.jobs.cache import Cache, digest, pickle_codec

    v = versions([n for n in backends_used if n in bk.all_names() and n != bk.REFERENCE])

    def own(job: SeriesJob) -> dict[str, Any]:
        names = (*SERIES_KNOBS.get(job.backend, ()), "slow_seconds")
        return {k: getattr(job.knobs, k) for k in names}

    def key(job: SeriesJob) -> str:
        sc = job.scene
        return digest({"kind": "sweep", "source": sc.source, "digest": sc.digest, "name": sc.name,
                       "size": [sc.camera.width, sc.camera.height], "rules": job.rules.as_dict(),
                       "backend": job.backend, "knobs": own(job), "repeats": job.repeats,
                       "minirt": v["minirt"], "drjit": v["drjit"], "oracle": v.get(job.backend, ""),
                       "where": where})  # fmt: skip

    # a series with a skip or error row may be the machine's (a renderer missing, a crash): redone next time
    return Cache(folder, key, pickle_codec, keep=lambda got: all(r["status"] == "ok" for r in got[0]))


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
) -> dict[str, Any]:
    """Sweep each backend's accuracy knob on `scene` at size x size; write the files; return sweep.json's dict.

    ``progress(done, total, label)`` is called before each render task (label: what runs now) and
    once at the end with done == total. ``repeats`` (>= 1) counts the timed runs after the untimed warm-up.

    Each backend's series is one job (minirt.jobs.batch): here, one after the other (``workers = 1``, the
    default: a timing study wants the machine to itself), in ``workers`` local processes at once, or on
    a Dask ``scheduler``'s workers -- concurrent series share cores, so their times are those of a
    loaded machine (sweep.json's ``jobs`` says how they ran; a worker runs Dr.Jit on one thread). Progress
    is then per series. ``cache``: a folder of series results by content hash (``sweep_cache``): a
    rerun renders only the series whose inputs changed.
    """
    global _notify
    from minirt.jobs import batch as jobs

    knobs = knobs or Knobs()
    repeats = max(int(repeats), 1)
    out_dir = Path(out_dir)
    sc = scene.with_overrides(width=size, height=size, samples=1)
    todo = [SeriesJob(sc, rules, name, knobs, repeats) for name in backends]
    total = sum(task_count(name, knobs) for name in backends)
    done = 0
    here_ = scheduler is None and workers <= 1

    def started(label: str) -> None:
        if progress:
            progress(done, total, label)

    def finished(job: SeriesJob, got) -> None:
        nonlocal done
        done += len(got[0]) if here_ else task_count(job.backend, knobs)
        if progress and not here_:
            progress(min(done, total), total, f"{job.backend}: done")

    def failed(job: SeriesJob, message: str):
        return [_row(None, job.backend, None, None, "error", message)], {}

    where = scheduler if scheduler is not None else here()
    store = None if cache is None else sweep_cache(Path(cache), backends, where)
    if progress and not here_:
        progress(0, total, f"sweeping {len(todo)} series")
    _notify = started if here_ else None
    try:
        got = jobs.run(run_series, todo, workers=workers, scheduler=scheduler, on_done=finished, on_error=failed,
                       cache=store)  # fmt: skip
    finally:
        _notify = None
    rows = [r for series_rows, _ in got for r in series_rows]
    converged = {k: v for _, conv in got for k, v in conv.items()}
    if progress:
        progress(total, total, "writing results")
    hits = store.hits if store else 0
    ran = {"workers": 1 if here_ else workers, "scheduler": scheduler, "where": where, "cached": hits}
    slopes = fit_slopes(rows)
    pareto = mark_pareto(rows)
    answer = answers(rows)
    result = {
        "scene": scene.name,
        "source": scene.source,
        "size": [size, size],
        "repeats": repeats,
        "rules": rules.as_dict(),
        "knobs": {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(knobs).items()},
        "series": SERIES,
        "jobs": ran,
        "converged": converged,
        "rows": [_clean(r) for r in rows],
        "slopes": slopes,
        "pareto": pareto,
        "answer": _clean(answer),
        "answer_lines": [f"{scene.name} {size}x{size}: {a['line']}" for a in answer],
    }
    write_outputs(result, out_dir)
    return result


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


# ---------------------------------------------------------------------------------------------
# Fits and the Pareto front


def _series(rows: list[dict[str, Any]]) -> dict[str, list[dict[str, Any]]]:
    out: dict[str, list[dict[str, Any]]] = {}
    for r in rows:
        if r["status"] == "ok" and r["knob"]:
            out.setdefault(f"{r['backend']}/{r['knob']}", []).append(r)
    return out


def _usable(r: dict[str, Any], metric: str) -> bool:
    e, s = r["error"].get(metric), r.get("seconds_median")
    return e is not None and math.isfinite(e) and e > 0 and s is not None and s > 0


def _lsq(x: list[float], y: list[float]) -> tuple[float, float] | None:
    """Least squares y = a + b x; (b, a)."""
    if len(x) < 2 or np.ptp(np.asarray(x, float)) < 1e-9:
        return None
    b, a = np.polyfit(np.asarray(x, float), np.asarray(y, float), 1)
    return float(b), float(a)


def fit_slopes(rows: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Per series: slope of log(error) against log(cost) and against log(seconds), for every metric."""
    out: dict[str, dict[str, Any]] = {}
    for key, rs in _series(rows).items():
        spec = SERIES.get(key, {})
        if key == "reference/precision":
            continue  # two points, one of them the reference itself: no trend to fit
        metrics = sorted({m for r in rs for m, v in r["error"].items() if isinstance(v, float) and m != "exposure"})
        fits: dict[str, Any] = {}
        for m in metrics:
            pts = [r for r in rs if _usable(r, m) and r["cost"]]
            f_cost = _lsq([math.log(r["cost"]) for r in pts], [math.log(r["error"][m]) for r in pts])
            f_time = _lsq([math.log(r["seconds_median"]) for r in pts], [math.log(r["error"][m]) for r in pts])
            if f_cost is None:
                continue
            fit = {"slope_cost": f_cost[0], "slope_time": f_time[0] if f_time else None, "points": len(pts),
                   "values": [r["value"] for r in pts]}  # fmt: skip
            if key == "embree/subdivisions":
                fit["factor_per_level"] = 4.0 ** f_cost[0]
            fits[m] = fit
        primary = spec.get("metric")
        out[key] = {"metric": primary, "cost": spec.get("cost"), "theory": spec.get("theory"),
                    **(fits.get(primary) or {}), "by_metric": fits}  # fmt: skip
    return out


def mark_pareto(rows: list[dict[str, Any]]) -> dict[str, list[Any]]:
    """Mark rows on their series' Pareto front (time, error); return the front's values per series."""
    out: dict[str, list[Any]] = {}
    for key, rs in _series(rows).items():
        m = SERIES.get(key, {}).get("metric", "rmse")
        pts = [r for r in rs if _usable(r, m)]
        front = []
        for r in pts:
            t, e = r["seconds_median"], r["error"][m]
            beaten = any(
                (q["seconds_median"] <= t and q["error"][m] <= e) and (q["seconds_median"] < t or q["error"][m] < e)
                for q in pts
                if q is not r
            )
            r["pareto"] = not beaten
            if not beaten:
                front.append(r["value"])
        out[key] = front
    return out


# ---------------------------------------------------------------------------------------------
# The answer: what an image error below one 8-bit level costs, per backend

COLOR_LEVEL = 1 / 255  # one 8-bit level: a colour RMSE below it is an image error below one level
# Embree does not shade, so no 8-bit level applies. The harness's own geometry check grants it the faceting
# bound it declares for its level (oracles/embree.py precision_summary), so it passes at every level and
# cannot say which level is enough; the criterion is that check passing *and* the mean relative t error
# below the relative t tolerance the check holds an exact float32 intersector to (64 u32, Mitsuba's T_REL).
GEOMETRY_T_REL = 64 * 2.0**-24
ANSWER_SERIES = ("reference/spp", "mitsuba/spp", "povray/antialias", "povray/samples", "embree/subdivisions")
# reference/precision is not a candidate: its rows are measured against the f64 render itself, not against
# the converged image, so f64's error is 0 by construction.


def setting_label(backend: str, knob: str | None, value: Any) -> str:
    """A setting as a reader names it: "the reference at 16 spp", "POV-Ray +A0.0 +R3"."""
    if backend == "reference":
        return f"the reference at {value} spp" if knob == "spp" else f"the reference in {value}"
    if backend == "mitsuba":
        return f"Mitsuba at {value} spp"
    if backend == "povray" and knob == "antialias":
        return "POV-Ray -A (antialiasing off)" if value == 0 else f"POV-Ray +A0.0 +R{value}"
    if backend == "povray" and knob == "samples":
        return f"POV-Ray with the exercise's {value} sample{'s' if value != 1 else ''} (mesh camera)"
    if backend == "embree":
        return f"Embree at subdivision {value} ({20 * 4 ** int(value)} triangles per ball)"
    return f"{backend} {knob}={value}"


def _seconds_text(r: dict[str, Any]) -> str:
    t = f"{'≤ ' if r.get('seconds_at_resolution') else ''}{r['seconds_median']:.3g} s"
    if r["backend"] == "povray" and r.get("seconds_setup"):
        t += f" (+{r['seconds_setup']:.2f} s process start-up)"
    return t


def _meets(r: dict[str, Any]) -> bool:
    if r["backend"] == "embree":
        t = r["error"].get("t_rel_mean")
        return r["error"].get("geometry_check") == "pass" and t is not None and t < GEOMETRY_T_REL
    e = r["error"].get("rmse")
    return e is not None and e < COLOR_LEVEL


def answers(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per backend (in row order): the cheapest setting (shortest median time; then lowest cost) whose
    colour RMSE against the converged image is below one 8-bit level -- for Embree, which does not
    shade, whose geometry passes the harness's own check with a mean relative t error below
    GEOMETRY_T_REL -- with its time and a one-line sentence."""
    out = []
    by_backend: dict[str, list[dict[str, Any]]] = {}
    for r in rows:
        by_backend.setdefault(r["backend"], []).append(r)
    for backend, rs in by_backend.items():
        geometry = backend == "embree"
        criterion = f"t error < {GEOMETRY_T_REL:.2g} (the check's float32 tolerance)" if geometry else "error < 1/255"
        measure = "t_rel_mean" if geometry else "rmse"
        cands = [r for r in rs if r["status"] == "ok" and f"{backend}/{r['knob']}" in ANSWER_SERIES
                 and r.get("seconds_median") is not None and r["error"].get(measure) is not None]  # fmt: skip
        a: dict[str, Any] = {"backend": backend, "criterion": criterion, "metric": measure,
                             "threshold": GEOMETRY_T_REL if geometry else COLOR_LEVEL, "met": False, "knob": None,
                             "value": None, "setting": None, "seconds": None, "seconds_setup": None,
                             "error": None}  # fmt: skip
        if not cands:
            why = next((r["reason"] for r in rs if r.get("reason")), "no setting was measured")
            a["line"] = f"{criterion}: not measured with {DISPLAY.get(backend, backend)} ({why})"
            out.append(a)
            continue
        good = [r for r in cands if _meets(r)]
        if good:  # the cheapest that reaches it
            best = min(good, key=lambda r: (r["seconds_median"], r["cost"] or 0))
        else:  # none does: the most accurate tried
            best = min(cands, key=lambda r, m=measure: (r["error"][m], r["seconds_median"]))
        label = setting_label(backend, best["knob"], best["value"])
        a.update(met=bool(good), knob=best["knob"], value=best["value"], setting=label, seconds=best["seconds_median"],
                 seconds_setup=best["seconds_setup"], error=best["error"][measure])  # fmt: skip
        err = f"{'mean relative t error' if geometry else 'RMSE'} {best['error'][measure]:.2g}"
        if good:
            a["line"] = f"{criterion} costs {_seconds_text(best)} with {label} ({err})"
        else:
            extra = ""
            if geometry:
                extra = f", {best['error'].get('geometry_beyond_tolerance', '?')} pixel(s) beyond tolerance"
            a["line"] = (f"no setting tried reaches {criterion} with {DISPLAY.get(backend, backend)}; "
                         f"best: {label}, {err}{extra}, {_seconds_text(best)}")  # fmt: skip
        out.append(a)
    return out


DISPLAY = {"reference": "the reference", "mitsuba": "Mitsuba", "povray": "POV-Ray", "embree": "Embree"}


# ---------------------------------------------------------------------------------------------
# Output files

CSV_ERRORS = ("rmse", "flip", "max_abs", "t_rel_mean", "t_rel_max", "mask_mismatch", "id_mismatch")
CSV_FIELDS = ("backend", "knob", "value", "cost", "status", "seconds_median", "seconds_setup", "seconds_total",
              "repeats", "metric", "error", *CSV_ERRORS, "pareto", "slope_cost", "slope_time", "reason",
              "at_resolution")  # fmt: skip


def _fmt(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "yes" if v else ""
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def _table_rows(result: dict[str, Any]) -> list[dict[str, Any]]:
    out = []
    for r in result["rows"]:
        key = f"{r['backend']}/{r['knob']}"
        fit = result["slopes"].get(key, {})
        e = r["error"]
        out.append({
            "backend": r["backend"], "knob": r["knob"], "value": r["value"], "cost": r["cost"],
            "status": r["status"], "seconds_median": r["seconds_median"], "seconds_setup": r["seconds_setup"],
            "seconds_total": r["seconds_total"], "repeats": len(r["runs"]), "metric": r["metric"],
            "error": e.get(r["metric"]) if r["metric"] else None, **{k: e.get(k) for k in CSV_ERRORS},
            "pareto": r["pareto"], "slope_cost": fit.get("slope_cost"), "slope_time": fit.get("slope_time"),
            "reason": r["reason"], "at_resolution": bool(r.get("seconds_at_resolution")),
        })  # fmt: skip
    return out


def write_csv(result: dict[str, Any], path: Path) -> None:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=CSV_FIELDS, lineterminator="\n")
    w.writeheader()
    for r in _table_rows(result):
        w.writerow({k: ("" if v is None else repr(v) if isinstance(v, float) else v) for k, v in r.items()})
    with atomic_path(path) as tmp:
        tmp.write_text(buf.getvalue())


def _md_table(rows: list[list[Any]], headers: list[str]) -> str:
    """A GitHub-flavoured Markdown table (tabulate's "github" format: pipes, a header rule, aligned
    columns); cells are formatted by _fmt first, so numbers read as in the CSV's short form."""
    from tabulate import tabulate

    cells = [[_fmt(v).replace("|", "/") for v in row] for row in rows]  # a pipe would split a cell
    return tabulate(cells, headers=headers, tablefmt="github", disable_numparse=True)


def markdown(result: dict[str, Any]) -> str:
    w, h = result["size"]
    lines = [f"# Sweep: {result['scene']} at {w}x{h}, {result['repeats']} timed run(s) per setting", ""]
    lines += [f"- {line}" for line in result.get("answer_lines", [])] + [""]
    cols = ["backend", "knob", "value", "cost", "status", "seconds_median", "seconds_setup", "metric", "error",
            "flip", "t_rel_max", "mask_mismatch", "pareto", "reason"]  # fmt: skip
    table = []
    for r in _table_rows(result):
        if r["status"] != "ok":
            r["status"] = r["status"].upper()
        if r["at_resolution"]:
            r["seconds_median"] = f"≤ {_fmt(r['seconds_median'])}"
        table.append([r[c] for c in cols])
    lines += [_md_table(table, cols)]
    lines += ["", "## Fitted slopes (log error against log cost, and against log time)", ""]
    slope_cols = ["series", "metric", "cost", "slope (cost)", "slope (time)", "factor per level", "points", "theory"]
    slope_rows = [[key, f.get("metric"), f.get("cost"), f.get("slope_cost"), f.get("slope_time"),
                   f.get("factor_per_level"), f.get("points"), f.get("theory")]
                  for key, f in result["slopes"].items()]  # fmt: skip
    lines += [_md_table(slope_rows, slope_cols)]
    lines += ["", "## Converged answers", ""]
    for key, c in result["converged"].items():
        desc = ", ".join(f"{k}={v}" for k, v in c.items() if k not in ("rules", "reason"))
        lines.append(f"- {key}: {desc}" + (f" ({c['reason']})" if c.get("reason") else ""))
    lines += ["", "Times in seconds: median of the timed runs after an untimed warm-up; setup = the warm-up's excess",
              "(JIT, caches) or POV-Ray's per-process start-up (not in its median); ≤: below POV-Ray's 1 ms",
              "timer, shown at 1 ms. Errors: colours clipped to [0, 1]; see minirt/sweep.py for what each",
              "backend's converged answer is.", ""]  # fmt: skip
    return "\n".join(lines)


METRIC_LABELS = {"rmse": "colour RMSE (values in [0, 1])", "t_rel_mean": "mean relative t error"}
AXES = {"rmse": "colour", "t_rel_mean": "geometry"}  # each metric on its own axes: the units differ


def plot(result: dict[str, Any], path: Path, only: str | None = None) -> None:
    """Log-log error against time: colour error and t error on separate axes (side by side when both
    occur), one line per series in knob order, Pareto front circled and dashed, one 8-bit level as a
    line on the colour axes, each backend's answer starred; only=backend keeps that backend's series.
    Times below the timer's resolution are drawn hollow at the resolution, with a left arrow."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter

    rows = [r for r in result["rows"] if only is None or r["backend"] == only]
    groups: dict[str, list[tuple[str, str, list[dict[str, Any]]]]] = {}
    for key, rs in _series(rows).items():
        m = SERIES.get(key, {}).get("metric", "rmse")
        pts = [r for r in rs if _usable(r, m)]  # in knob order
        if pts:
            groups.setdefault(AXES.get(m, m), []).append((key, m, pts))
    panels = [g for g in ("colour", "geometry") if g in groups] + [g for g in groups if g not in AXES.values()]
    n = max(len(panels), 1)
    fig, axes = plt.subplots(1, n, figsize=(6.4 * n, 5.4), dpi=100, squeeze=False)
    chosen = {(a.get("backend"), a.get("knob"), a.get("value")) for a in result.get("answer") or [] if a.get("met")}
    w, h = result["size"]
    for ax, panel in zip(axes[0], panels or [None], strict=True):
        if panel is None:
            ax.text(0.5, 0.5, "no measurements", ha="center", va="center", transform=ax.transAxes)
            ax.set_title(f"{result['scene']} {w}x{h}" + (f" ({only})" if only else ""), fontsize=10)
            continue
        metrics = []
        floored = starred = False
        for key, m, pts in groups[panel]:
            metrics.append(m)
            x = [r["seconds_median"] for r in pts]
            y = [r["error"][m] for r in pts]
            c = PALETTE.get(key, "#000000")
            fit = result["slopes"].get(key, {})
            label = key
            if fit.get("slope_cost") is not None:
                label += f": ∝ cost^{fit['slope_cost']:.2f}"
            mk = MARKERS.get(key, "o")
            ax.plot(x, y, marker=mk, color=c, lw=1.2, ms=5, label=label)
            for r, xi, yi in zip(pts, x, y, strict=True):
                ax.annotate(str(r["value"]), (xi, yi), textcoords="offset points", xytext=(4, 3), fontsize=7, color=c)
                if r.get("seconds_at_resolution"):
                    floored = True
                    ax.plot([xi], [yi], marker=mk, ms=5, color="#ffffff", mec=c, ls="none")
                    ax.annotate("", (xi * 0.6, yi), xytext=(xi, yi), arrowprops={"arrowstyle": "->", "color": c,
                                                                                   "lw": 0.8})  # fmt: skip
                if (r["backend"], r["knob"], r["value"]) in chosen:
                    starred = True
                    ax.plot([xi], [yi], marker="*", ms=15, color=c, mec="#000000", mew=0.6, ls="none", zorder=5)
            front = sorted((r for r in pts if r["pareto"]), key=lambda r: r["seconds_median"])
            if front:
                ax.plot([r["seconds_median"] for r in front], [r["error"][m] for r in front], ls="--", lw=0.8,
                        color="#000000", marker="o", ms=11, mfc="none", mec="#000000", mew=1.0)  # fmt: skip
        ax.plot([], [], ls="--", lw=0.8, color="#000000", marker="o", ms=11, mfc="none", label="Pareto front")
        if panel == "colour":
            ax.axhline(COLOR_LEVEL, color="#555555", lw=0.9, ls=":", label="one 8-bit level (1/255)")
        elif panel == "geometry":
            ax.axhline(GEOMETRY_T_REL, color="#555555", lw=0.9, ls=":",
                       label=f"the check's float32 t tolerance ({GEOMETRY_T_REL:.2g})")  # fmt: skip
        if starred:
            goal = "below 1/255" if panel == "colour" else f"below {GEOMETRY_T_REL:.2g}"
            ax.plot([], [], marker="*", ms=12, color="#bbbbbb", mec="#000000", ls="none", label=f"cheapest {goal}")
        if floored:
            note = f"below the timer's {POVRAY_RESOLUTION * 1e3:g} ms: drawn at it (an upper bound)"
            ax.plot([], [], marker="o", ms=5, color="#ffffff", mec="#000000", ls="none", label=note)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.xaxis.set_minor_formatter(NullFormatter())  # a span under a decade would label every minor tick
        ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=2, frameon=False)
        names = [METRIC_LABELS.get(m, m) for m in dict.fromkeys(metrics)]
        ax.set_xlabel("time per render, median of the timed runs [s]")
        ax.set_ylabel("error vs converged answer: " + "; ".join(names), fontsize=8)
        title = f"{result['scene']} {w}x{h}: {panel} error against time" + (f" ({only})" if only else "")
        ax.set_title(title, fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", metadata={"Software": None})
    plt.close(fig)


def write_outputs(result: dict[str, Any], out_dir: Path) -> dict[str, Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {"json": out_dir / "sweep.json", "csv": out_dir / "sweep.csv", "md": out_dir / "sweep.md",
             "png": out_dir / "sweep.png"}  # fmt: skip
    write_json(paths["json"], result)
    write_csv(result, paths["csv"])
    with atomic_path(paths["md"]) as tmp:
        tmp.write_text(markdown(result))
    plot(result, paths["png"])
    known = set(bk.all_names())  # a file name never comes from an unknown (user-typed) backend name
    for name in dict.fromkeys(r["backend"] for r in result["rows"] if r["backend"] in known):
        p = out_dir / f"sweep-{name}.png"
        plot(result, p, only=name)
        paths[f"png:{name}"] = p
    return paths
