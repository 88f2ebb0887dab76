"""minirt benchmark: the reference tracer's throughput, a plain NumPy model for the ratio, cold CLI time,
peak memory, and every oracle on the same scenes -- all measured in one run, so ratios are like for like.

Usage::

    .venv/bin/python benchmarks/bench.py [--quick] [--out benchmarks/results.json]

Sections (JSON keys; the Markdown on stdout follows the same order):

- ``meta``: machine (cores, CPU, load average before and after), versions, git commit, mode.
- ``reference``: ``scenes/three_balls.toml`` (3 balls, mirror floor, max_depth 3, every effect) at
  1024x1024, float64 and float32. ``trace`` is the kernel alone (primary rays + ``Tracer.trace`` +
  ``dr.eval`` + ``dr.sync_thread``); ``render`` is the whole ``Tracer.render()`` including the buffers
  back to NumPy (``render_checked``: keeping only the two terms a check reads, harness.CHECKED_TERMS).
  Steady state: warm-up runs first (the JIT compiles), then the median of >= 5 runs; the f64 and f32
  traces interleaved run by run, so drift does not bias their ratio.
- ``numpy``: a compact vectorised NumPy implementation of the same model (exercise rules: primary
  rays, closest hit, shadow rays, ambient + diffuse + (r·s)^8 specular, 3 reflection levels), timed
  in the same run; its image is checked against the reference (max abs difference reported), and the
  speed-ups are ratios of medians measured here.
- ``cold``: whole-command wall time of ``python -m minirt render scenes/exercise.toml --out <tmp>``
  in a child process. Dr.Jit caches compiled kernels on disk (``~/.drjit``; the environment variable
  ``DRJIT_CACHE_DIR`` moves it): "cold cache" runs each get a fresh empty cache directory, "warm cache"
  runs share one directory primed by a first run. Python's own files are in the OS page cache either way.
- ``memory``: ``resource.getrusage(RUSAGE_SELF).ru_maxrss`` of a child process after imports and after
  rendering three_balls at 1024x1024 float64.
- ``oracles``: each oracle (Mitsuba, POV-Ray, Embree, Cycles) on exercise, three_balls and rules at
  256^2 and 512^2: wall time, the part outside set-up (from each result's ``meta["timings"]``, keys listed per row),
  Mpixel/s, and the ratio to the reference tracer's wall time on the same scene, size and rules (the
  reference renders under the oracle's adapted rules). A missing or failing backend is a SKIP/ERROR
  row with its reason, never a crash. One warm-up call per oracle first (imports, Mitsuba's JIT).
- ``targets``: >= 20 Mpixel/s float64 (reference trace kernel, 1024^2 three_balls) and a cold-cache
  CLI render of the 256^2 exercise scene under 3 s, each PASS or MISS (``n/a`` in --quick mode, whose
  sizes are too small for the targets' conditions).

--quick: small sizes and 1-2 repetitions (used by tests/package/test_bench.py; finishes well under a minute).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    # After PYTHONPATH, so that PYTHONPATH=TREE times TREE's minirt (--reference-only's A/B runs).
    sys.path.insert(1 + len([p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]), str(ROOT))

from minirt.harness import backends  # noqa: E402
from minirt.model import camera  # noqa: E402
from minirt.model.rules import PROFILES, Rules, resolve  # noqa: E402
from minirt.model.scene import Ball, Scene, load_scene  # noqa: E402

REF_SCENE = ROOT / "scenes" / "three_balls.toml"
COLD_SCENE = ROOT / "scenes" / "exercise.toml"
# rules: a ball crosses the image plane, so POV-Ray needs its mesh camera (one triangle per pixel)
ORACLE_SCENES = ("exercise", "three_balls", "rules")

SAMPLES_SPP = 16  # the supersampled render's rays per pixel
TARGET_MPIX_F64 = 20.0  # Mpixel/s, reference trace kernel, float64, 1024^2 three_balls, 2 cores
TARGET_COLD_S = 3.0  # s, cold-cache `minirt render scenes/exercise.toml` (256^2)
TARGET_RENDER_OVER_TRACE = 1.3  # whole render() over the trace kernel, f64, 1024^2 three_balls
TARGET_F32_SPEEDUP = 1.7  # f64 trace time over f32's
TARGET_VS_MITSUBA = 2.0  # Mitsuba `direct` render time over the f64 trace kernel's, same scene and size
TARGET_VS_POVRAY = 15.0  # POV-Ray's own trace time over the f64 trace kernel's, same scene and size

# The part of each oracle's meta["timings"] that is not set-up (what it spends rendering).
ORACLE_WORK_KEYS: dict[str, tuple[str, ...]] = {
    "povray": ("parse", "trace"),  # POV-Ray's own statistics, summed over its passes; start-up excluded
    "mitsuba": ("render",),  # Mitsuba's intersection/shading calls; scene loading is "setup"
    "embree": ("cast",),  # Embree's ray queries; tessellation and BVH build excluded
    # Cycles' bpy.ops.render.render calls inside Blender; Blender's start-up, the scene's build there, the
    # child process and reading its EXR excluded
    "cycles": ("render",),
}


@dataclass(frozen=True)
class Config:
    quick: bool
    ref_size: int
    warmup: int
    reps: int
    numpy_reps: int
    cold_reps: int
    mem_size: int
    oracle_sizes: tuple[int, ...]
    oracle_reps: int
    ref_compare_reps: int

    @classmethod
    def make(cls, quick: bool) -> Config:
        if quick:
            return cls(True, 128, 1, 2, 1, 1, 128, (64,), 1, 1)
        return cls(False, 1024, 2, 7, 3, 3, 1024, (256, 512), 2, 3)


# ---------------------------------------------------------------------------------------------
# helpers


def _stats(times: list[float], pixels: int) -> dict[str, Any]:
    med = statistics.median(times)
    return {
        "runs_s": [round(t, 6) for t in times],
        "median_s": med,
        "min_s": min(times),
        "mpix_s": pixels / med / 1e6,
    }


def _loadavg() -> list[float]:
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:  # pragma: no cover - not on Linux
        return []


def _cpu_model() -> str:
    try:
        for ln in Path("/proc/cpuinfo").read_text().splitlines():
            if ln.startswith("model name"):
                return ln.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def _git() -> str:
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True)
        dirty = subprocess.run(["git", "status", "--porcelain"], cwd=ROOT, capture_output=True, text=True)
        return head.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")
    except OSError:
        return "unknown"


def _scene(path: Path, size: int | None = None) -> Scene:
    sc = load_scene(path)
    return sc.with_overrides(width=size, height=size) if size else sc


def trace_seconds(tr: Any) -> float:
    """Wall time of one trace of every pixel's primary ray by the Tracer ``tr``: the rays, the kernels and
    their results evaluated (Dr.Jit is asynchronous: sync_thread waits for the work, not just its launch)."""
    import drjit as dr

    t0 = time.perf_counter()
    o, d = tr.primary_rays()
    c, _levels = tr.trace(o, d)
    dr.eval(c)
    dr.sync_thread()
    return time.perf_counter() - t0


def _planar_seconds(tr: Any) -> float:
    """Wall time of a trace whose first level's buffers -- colour, hit point, normal, every term, t and the
    ids -- are the kernel's own outputs: each component an array of its own (Dr.Jit writes those with
    non-temporal stores), nothing copied or read back. The fastest a render writing those buffers can
    be; ``render()`` at this size writes them so too (``film.planar_out``), and adds their hand-over to
    NumPy (``Planes``: RenderResult stacks a vector only when it is read)."""
    import drjit as dr

    t0 = time.perf_counter()
    o, d = tr.primary_rays()
    c, levels = tr.trace(o, d)
    first = levels[0]
    dr.eval(c, first.t, first.p, first.n, first.terms, first.shape_id)
    dr.sync_thread()
    return time.perf_counter() - t0


# ---------------------------------------------------------------------------------------------
# reference tracer


def bench_reference(cfg: Config) -> dict[str, Any]:
    import drjit as dr

    from minirt.harness.references import CHECKED_TERMS
    from minirt.reference.tracer import Tracer

    sc = _scene(REF_SCENE, cfg.ref_size)
    rules = resolve(sc)
    px = cfg.ref_size * cfg.ref_size
    out: dict[str, Any] = {"scene": sc.name, "width": cfg.ref_size, "height": cfg.ref_size,
                           "max_depth": sc.max_depth, "profile": sc.profile, "warmup": cfg.warmup,
                           "reps": cfg.reps}  # fmt: skip
    # The two precisions' traces interleaved, run by run: their ratio is a target, and this shared VM's
    # speed drifts over seconds (its memory bandwidth twofold between runs), which timing one precision
    # after the other would fold into the ratio. The renders are timed after them, not interleaved: a
    # render's buffers (268 MB) churn Dr.Jit's allocation cache and the CPU's, which slowed the float32
    # trace timed between renders by a fifth.
    tracers = {prec: Tracer(sc, rules, precision=prec) for prec in ("f64", "f32")}
    for _ in range(cfg.warmup):
        for tr in tracers.values():
            trace_seconds(tr)
    runs: dict[str, list[float]] = {prec: [] for prec in tracers}
    for _ in range(cfg.reps):
        for prec, tr in tracers.items():
            runs[prec].append(trace_seconds(tr))
    for prec, tr in tracers.items():
        out[prec] = {"trace": _stats(runs[prec], px), "effects": tr.effects.simulated()}
        # render: every buffer, as `minirt render` writes them; render_checked: the two terms a check
        # keeps of its reference renders (harness.CHECKED_TERMS), the other three never written.
        for kind, terms in (("render", None), ("render_checked", CHECKED_TERMS)):
            for _ in range(cfg.warmup):
                tr.render(terms=terms)
            times = []
            for _ in range(cfg.reps):
                t0 = time.perf_counter()
                tr.render(terms=terms)
                times.append(time.perf_counter() - t0)
            out[prec][kind] = _stats(times, px)
    out["writes"] = _write_floor(px, cfg)
    tr64 = tracers["f64"]
    for _ in range(cfg.warmup):
        _planar_seconds(tr64)
    out["f64"]["planar_outputs"] = _stats([_planar_seconds(tr64) for _ in range(cfg.reps)], px)
    # Thread scaling: the f64 trace kernel on one Dr.Jit worker thread against the default (every core).
    cores = dr.thread_count()
    tr = Tracer(sc, rules, precision="f64")
    scaling = {}
    for threads in sorted({1, cores}):
        dr.set_thread_count(threads)
        try:
            trace_seconds(tr)
            times = [trace_seconds(tr) for _ in range(cfg.reps)]
        finally:
            dr.set_thread_count(cores)
        scaling[str(threads)] = statistics.median(times)
    out["threads"] = {"trace_f64_median_s": scaling, "speedup": scaling["1"] / scaling[str(cores)]}
    # Stratified supersampling: the whole render at SAMPLES_SPP rays per pixel, a quarter of the pixels.
    side = max(4, cfg.ref_size // 2)
    ss = sc.with_overrides(width=side, height=side, samples=SAMPLES_SPP)
    tr = Tracer(ss, rules, precision="f64")
    tr.render()
    times = []
    for _ in range(max(1, cfg.reps // 2)):
        t0 = time.perf_counter()
        tr.render()
        times.append(time.perf_counter() - t0)
    st = _stats(times, side * side * SAMPLES_SPP)
    out["samples"] = {"width": side, "height": side, "spp": SAMPLES_SPP, "render": st}
    return out


def _write_floor(px: int, cfg: Config) -> dict[str, Any]:
    """The memory side of the roofline for ``render()``: one kernel that computes nothing and writes the
    buffers a full f64 render writes -- colour, position, normal and five terms, t as float64, the shape id
    as int32 -- in either of the film's layouts (minirt.reference.film): "outputs", the kernel's own outputs,
    one array a component (204 bytes a pixel), the layout of a render from 2^18 pixels (this one); and
    "packets", (x, y, z, 0) float64 packets scattered from a loop (``film.queue_out``, 268 bytes a pixel),
    that of smaller renders. A render can take no less than the longer of its trace and its writes.

    Dr.Jit writes outputs with non-temporal stores and packet scatters with ordinary ones (a cache line read
    for ownership before it is written): the two figures show what the store kind costs, apart from any
    arithmetic; "cached", the packet scatters' arithmetic without their memory traffic."""
    import drjit as dr

    from minirt.model.result import TERMS

    F64, A4, U32 = dr.llvm.Float64, dr.llvm.Array4f64, dr.llvm.UInt32
    vectors = 3 + len(TERMS)  # colour, position, normal and the terms

    def once(kind: str) -> float:
        bufs = [] if kind == "outputs" else [dr.empty(F64, 4 * px) for _ in range(vectors)]
        dr.eval(bufs)
        i = dr.arange(U32, px)
        x = F64(i) * 1e-6
        # "cached": the same scatters into the first 1,024 packets, which stay in the L1 cache: their
        # arithmetic (the packets' transposes and per-lane stores) without the memory traffic
        at = i & dr.opaque(U32, 1023) if kind == "cached" else i
        t0 = time.perf_counter()
        t, ids = x + 3, dr.llvm.Int32(i)
        if kind == "outputs":
            dr.eval([x + k for k in range(3 * vectors)], t, ids)
        else:
            for b in bufs:
                dr.scatter(b, A4(x, x + 1, x + 2, 0.0), at)
            dr.eval(t, ids)  # runs the scatters too: one kernel
        dr.sync_thread()
        return time.perf_counter() - t0

    kinds = ("packets", "outputs", "cached")
    for _ in range(cfg.warmup):
        for kind in kinds:
            once(kind)
    runs: dict[str, list[float]] = {kind: [] for kind in kinds}
    for _ in range(cfg.reps):  # interleaved: the three are compared
        for kind in kinds:
            runs[kind].append(once(kind))
    st, so, sc = (_stats(runs[kind], px) for kind in kinds)
    nbytes, obytes = px * (vectors * 32 + 8 + 4), px * (vectors * 24 + 8 + 4)
    outs = {"bytes": obytes, "median_s": so["median_s"], "gb_s": obytes / so["median_s"] / 1e9}
    return {"bytes": nbytes, "median_s": st["median_s"], "gb_s": nbytes / st["median_s"] / 1e9, "outputs": outs,
            "cached_median_s": sc["median_s"]}  # fmt: skip


# ---------------------------------------------------------------------------------------------
# the same model in plain NumPy (exercise rules), for the ratio


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("ij,ij->i", a, b)


def _np_intersect(shape, o: np.ndarray, d: np.ndarray) -> np.ndarray:
    """First t > 0 (near root only for balls, as the exercise says), +inf on a miss; stable forms."""
    if isinstance(shape, Ball):
        r = shape.radius
        f = o - np.asarray(shape.center)
        b = _dot(f, d)
        lg = np.linalg.norm(f - b[:, None] * d, axis=1)
        disc = (r - lg) * (r + lg)
        hit = disc >= 0
        q = -(b + np.copysign(np.sqrt(np.maximum(disc, 0.0)), b))
        lf = np.linalg.norm(f, axis=1)
        c = (lf - r) * (lf + r)
        with np.errstate(divide="ignore", invalid="ignore"):
            t0 = np.where(q != 0, c / q, 0.0)
        tn = np.minimum(t0, np.where(q != 0, q, 0.0))
        return np.where(hit & (tn > 0), tn, np.inf)
    n = np.asarray(shape.normal)
    denom = d @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        t = ((np.asarray(shape.point) - o) @ n) / denom
    return np.where((denom != 0) & (t > 0) & (t < np.inf), t, np.inf)


def numpy_render(scene: Scene, rules: Rules) -> np.ndarray:
    """The exercise's TraceRay, vectorised over rays with NumPy; returns (H, W, 3) float64 colours.

    Exercise rules only: background added at each hit, near root only, any shadow-ray hit blocks,
    one-sided normals, no clamping, origins offset by 1e-6 along the normal. Colour is accumulated
    front to back with the product of reflection colours (the same sum as the recursion).
    """
    if rules != PROFILES["exercise"]:
        raise ValueError("numpy_render follows the exercise profile only")
    shapes = scene.shapes
    w, h = scene.camera.width, scene.camera.height
    o, d = camera.primary_rays(scene, rules)
    # per-shape material rows; row -1 (a miss) is all zeros
    mat = {k: np.array([getattr(s.material, k) for s in shapes] + [(0.0, 0.0, 0.0)])
           for k in ("ambient", "diffuse", "specular", "reflection")}  # fmt: skip
    light, lc, bg = (np.asarray(v) for v in (scene.light.position, scene.light.color, scene.background))
    off = float(rules.offset)
    color = np.zeros((w * h, 3))
    weight = np.ones((w * h, 3))
    idx = np.arange(w * h)
    for level in range(scene.max_depth + 1):
        t_best = np.full(len(o), np.inf)
        sid = np.full(len(o), -1)
        for k, s in enumerate(shapes):
            tk = _np_intersect(s, o, d)
            closer = tk < t_best
            t_best = np.where(closer, tk, t_best)
            sid = np.where(closer, k, sid)
        hit = sid >= 0
        p = o + np.where(hit, t_best, 0.0)[:, None] * d
        nrm = np.zeros_like(p)
        for k, s in enumerate(shapes):
            m = sid == k
            nrm[m] = (p[m] - np.asarray(s.center)) / s.radius if isinstance(s, Ball) else np.asarray(s.normal)
        to_light = light - p
        sdir = to_light / np.linalg.norm(to_light, axis=1, keepdims=True)
        so = p + off * nrm
        blocked = np.zeros(len(o), dtype=bool)
        for s in shapes:
            blocked |= _np_intersect(s, so, sdir) < np.inf
        lit = (hit & ~blocked)[:, None]
        r = d - 2.0 * _dot(d, nrm)[:, None] * nrm
        rs2 = _dot(r, sdir) ** 2
        rs8 = (rs2 * rs2) ** 2  # (r·s)^8 by repeated squaring, as the tracer does
        local = mat["ambient"][sid] + np.where(lit, lc * mat["diffuse"][sid] * _dot(sdir, nrm)[:, None], 0.0)
        local += np.where(lit, lc * mat["specular"][sid] * rs8[:, None], 0.0)
        local += np.where(hit[:, None], bg, 0.0)
        color[idx] += weight * local
        if level == scene.max_depth:
            break
        kr = mat["reflection"][sid]
        spawn = hit & (kr != 0).any(axis=1)
        if not spawn.any():
            break
        weight = weight[spawn] * kr[spawn]
        o, d, idx = p[spawn] + off * nrm[spawn], r[spawn], idx[spawn]
    return color.reshape(h, w, 3)


def bench_numpy(cfg: Config, ref: dict[str, Any]) -> dict[str, Any]:
    from minirt.reference.tracer import Tracer

    sc = _scene(REF_SCENE, cfg.ref_size)
    rules = resolve(sc)
    px = cfg.ref_size * cfg.ref_size
    img = numpy_render(sc, rules)  # warm-up (allocator, caches)
    times = []
    for _ in range(cfg.numpy_reps):
        t0 = time.perf_counter()
        img = numpy_render(sc, rules)
        times.append(time.perf_counter() - t0)
    st = _stats(times, px)
    ref_img = Tracer(sc, rules, precision="f64").render().color
    diff = float(np.abs(img - ref_img).max())
    speedup = {f"{kind}_{prec}": st["median_s"] / ref[prec][kind]["median_s"]
               for prec in ("f64", "f32") for kind in ("trace", "render", "render_checked")}  # fmt: skip
    return {"scene": sc.name, "width": cfg.ref_size, "height": cfg.ref_size, "reps": cfg.numpy_reps, **st,
            "max_abs_diff_vs_reference": diff, "speedup": speedup}  # fmt: skip


# ---------------------------------------------------------------------------------------------
# cold whole-command time, peak memory (child processes)


def timed_child(args: list[str], cache: Path | None = None, ok: tuple[int, ...] = (0,)) -> tuple[float, str]:
    """Run a command from the repository root; its wall seconds and standard output. ``cache``: the Dr.Jit
    kernel cache it uses (``DRJIT_CACHE_DIR``; an empty folder times every compile), else the user's.
    An exit status outside ``ok`` raises, with the end of its standard error."""
    env = {**os.environ, "DRJIT_CACHE_DIR": str(cache)} if cache is not None else None
    t0 = time.perf_counter()
    p = subprocess.run(args, cwd=ROOT, env=env, capture_output=True, text=True, stdin=subprocess.DEVNULL)
    dt = time.perf_counter() - t0
    if p.returncode not in ok:
        raise RuntimeError(f"{' '.join(args)} failed ({p.returncode}): {p.stderr.strip()[-400:]}")
    return dt, p.stdout


def _cli_once(cache_dir: Path) -> float:
    with tempfile.TemporaryDirectory(prefix="minirt-bench-out-") as out:
        return timed_child([sys.executable, "-m", "minirt", "render", str(COLD_SCENE), "--out", out], cache_dir)[0]


def bench_cold(cfg: Config) -> dict[str, Any]:
    sc = load_scene(COLD_SCENE)
    px = sc.camera.width * sc.camera.height
    cold, warm = [], []
    with tempfile.TemporaryDirectory(prefix="minirt-bench-jit-") as tmp:
        tmp = Path(tmp)
        for i in range(cfg.cold_reps):
            d = tmp / f"cold{i}"
            d.mkdir()
            cold.append(_cli_once(d))
        kernels = len(list((tmp / "cold0").iterdir()))
        primed = tmp / "cold0"  # primed by the first cold run
        for _ in range(cfg.cold_reps):
            warm.append(_cli_once(primed))
    return {
        "command": "python -m minirt render scenes/exercise.toml --out <tmp>",
        "width": sc.camera.width,
        "height": sc.camera.height,
        "cache": "DRJIT_CACHE_DIR=<fresh empty dir> per cold run; warm runs share a primed dir",
        "kernels_cached": kernels,
        "cold_cache": _stats(cold, px),
        "warm_cache": _stats(warm, px),
    }


_MEM_CHILD = r"""
import json, resource, sys
sys.path.insert(0, sys.argv[1])


def hwm_kb():
    # VmHWM: the peak RSS of this process's own address space. ru_maxrss is not enough on its own:
    # Linux carries the parent's high-water mark across fork + exec, so a child of a big parent
    # reports the parent's peak.
    for ln in open("/proc/self/status"):
        if ln.startswith("VmHWM:"):
            return int(ln.split()[1])
    return None


from minirt.model.rules import resolve
from minirt.model.scene import load_scene
from minirt.reference.tracer import Tracer

base, base_hwm = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, hwm_kb()
sc = load_scene(sys.argv[2]).with_overrides(width=int(sys.argv[3]), height=int(sys.argv[3]))
res = Tracer(sc, resolve(sc), precision="f64").render()
peak, peak_hwm = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, hwm_kb()
print(json.dumps({"baseline_kb": base, "peak_kb": peak, "baseline_hwm_kb": base_hwm, "peak_hwm_kb": peak_hwm}))
"""


def bench_memory(cfg: Config) -> dict[str, Any]:
    cmd = [sys.executable, "-c", _MEM_CHILD, str(ROOT), str(REF_SCENE), str(cfg.mem_size)]
    p = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, stdin=subprocess.DEVNULL)
    if p.returncode != 0:
        raise RuntimeError(f"memory child failed ({p.returncode}): {p.stderr.strip()[-300:]}")
    m = json.loads(p.stdout.strip().splitlines()[-1])
    # Linux reports ru_maxrss and VmHWM in KiB. The child is started first thing in the run (small parent).
    hwm = m["peak_hwm_kb"] if m["peak_hwm_kb"] is not None else m["peak_kb"]
    base = m["baseline_hwm_kb"] if m["baseline_hwm_kb"] is not None else m["baseline_kb"]
    return {"scene": "three_balls", "width": cfg.mem_size, "height": cfg.mem_size, "precision": "f64",
            "peak_mb": hwm / 1024, "after_imports_mb": base / 1024, "render_adds_mb": (hwm - base) / 1024,
            "ru_maxrss_mb": m["peak_kb"] / 1024,
            "how": "VmHWM of the child (/proc/self/status); ru_maxrss also given (includes the parent's "
                   "high-water mark inherited across fork+exec)"}  # fmt: skip


# ---------------------------------------------------------------------------------------------
# oracles


def _work_time(name: str, timings: dict[str, Any]) -> tuple[float | None, list[str]]:
    keys = [k for k in ORACLE_WORK_KEYS.get(name, ()) if isinstance(timings.get(k), int | float)]
    if not keys:
        return None, []
    return float(sum(timings[k] for k in keys)), keys


def bench_oracles(cfg: Config) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = []
    ref_cache: dict[tuple[str, int, tuple], float] = {}

    def reference_wall(sc: Scene, rules: Rules) -> float:
        key = (sc.name, sc.camera.width, tuple(sorted(rules.as_dict().items())))
        if key not in ref_cache:
            backends.render(backends.REFERENCE, sc, rules)  # warm-up: compile this rule set's kernels
            walls = [backends.render(backends.REFERENCE, sc, rules).meta["timings"]["wall"]
                     for _ in range(cfg.ref_compare_reps)]  # fmt: skip
            ref_cache[key] = statistics.median(walls)
        return ref_cache[key]

    for name in backends.oracle_names():
        info = backends.info(name)
        base = {"backend": name, "version": info.detail if info.available else ""}
        if not info.available:
            for scn in ORACLE_SCENES:
                for size in cfg.oracle_sizes:
                    rows.append({**base, "scene": scn, "size": size, "status": "skip", "reason": info.detail})
            continue
        # warm-up: imports, Mitsuba's JIT, first-call costs; reported, not counted
        sc0 = _scene(ROOT / "scenes" / f"{ORACLE_SCENES[0]}.toml", cfg.oracle_sizes[0])
        t0 = time.perf_counter()
        backends.render(name, sc0, resolve(sc0))
        first_call = time.perf_counter() - t0
        for scn in ORACLE_SCENES:
            for size in cfg.oracle_sizes:
                sc = _scene(ROOT / "scenes" / f"{scn}.toml", size)
                rules = resolve(sc)
                row: dict[str, Any] = {**base, "scene": scn, "size": size, "first_call_s": first_call}
                walls, works, keys, res = [], [], [], None
                for _ in range(cfg.oracle_reps):
                    res = backends.render(name, sc, rules)
                    if not res.ok:
                        break
                    tm = res.meta.get("timings", {})
                    walls.append(float(tm["wall"]))
                    w, keys = _work_time(name, tm)
                    if w is not None:
                        works.append(w)
                assert res is not None
                if not res.ok:
                    rows.append({**row, "status": res.status, "reason": res.reason or "no reason given"})
                    continue
                px = size * size
                wall = statistics.median(walls)
                ref = reference_wall(sc, backends.rules_for(name, rules))
                work = statistics.median(works) if works else None
                row.update(
                    status="ok",
                    reason="",
                    reps=len(walls),
                    wall_s=wall,
                    work_s=work,
                    work_keys=keys,
                    setup_s=(wall - work) if work is not None else None,
                    mpix_s=px / wall / 1e6,
                    work_mpix_s=(px / work / 1e6) if work else None,
                    reference_wall_s=ref,
                    ratio_wall_to_reference=wall / ref,
                    ratio_work_to_reference=(work / ref) if work is not None else None,
                    rules_changed=rules.differs(backends.rules_for(name, rules)),
                    timings={k: v for k, v in res.meta.get("timings", {}).items() if isinstance(v, int | float)},
                )
                if name == "povray":
                    passes = res.meta.get("passes") or []
                    row["povray_frames"] = sum(len(p.get("frames", [])) for p in passes if isinstance(p, dict))
                    row["camera"] = res.meta.get("settings", {}).get("camera", "perspective")
                rows.append(row)
    return rows


# ---------------------------------------------------------------------------------------------
# the same scene in the established renderers, timed beside the reference (issue targets)


def bench_rivals(cfg: Config) -> dict[str, Any]:
    """The reference's f64 trace kernel against Mitsuba's ``direct`` integrator and POV-Ray's own trace
    time, on the same scene at the same size, interleaved (reference, Mitsuba, reference, POV-Ray, ...)
    so that a drift of the machine's speed hits both sides of each ratio alike.

    Not the same work: Mitsuba ``direct`` (its exported scene, ``llvm_ad_rgb``, 1 spp, one emitter
    sample, no BSDF sample) is float32 and follows no reflection; POV-Ray (the colour frame as the
    oracle exports it, ``-A``, every thread) is float64 with reflections, like the reference, and its
    "Trace Time" statistic excludes its start-up and parse. The reference traces in float64 to
    max_depth. These are the issue's yardsticks, not like-for-like renderers."""
    import drjit as dr

    from minirt.reference.tracer import Tracer

    sc = _scene(REF_SCENE, cfg.ref_size)
    rules = resolve(sc)
    tr = Tracer(sc, rules, precision="f64")
    out: dict[str, Any] = {"scene": sc.name, "width": cfg.ref_size, "height": cfg.ref_size}
    ref_times: list[float] = []
    for _ in range(cfg.warmup):
        trace_seconds(tr)
    # Mitsuba: its own `direct` render of the exported scene.
    mitsuba: dict[str, Any]
    try:
        from oracles import mitsuba as mo

        mi, variant = mo.load_mitsuba()
        msc = mi.load_string(mo.scene_to_xml(sc, rules))

        def mitsuba_render() -> float:
            t0 = time.perf_counter()
            img = mi.render(msc, spp=1)
            dr.eval(img)
            dr.sync_thread()
            return time.perf_counter() - t0

        for _ in range(cfg.warmup):
            mitsuba_render()
        mt = []
        for _ in range(cfg.reps):
            ref_times.append(trace_seconds(tr))
            mt.append(mitsuba_render())
        mitsuba = {"status": "ok", "variant": variant, "integrator": "direct", "spp": 1,
                   "median_s": statistics.median(mt), "runs_s": mt}  # fmt: skip
    except Exception as e:  # a missing renderer is a row, not a crash
        mitsuba = {"status": "skip", "reason": f"{type(e).__name__}: {e}"}
    out["mitsuba_direct"] = mitsuba
    # POV-Ray: the colour frame, its own "Trace Time" statistic.
    povray: dict[str, Any]
    if shutil.which("povray") is None:
        povray = {"status": "skip", "reason": "povray not on PATH"}
    else:
        from oracles import povray as po

        with tempfile.TemporaryDirectory() as tmp:
            Path(tmp, "scene.pov").write_text(po.scene_to_pov(sc, rules))
            cmd = po.command(sc, 1, 1, 1, "png8")
            pt, wall = [], []
            for _ in range(max(1, cfg.reps // 2)):
                ref_times.append(trace_seconds(tr))
                _, tm = po.run_povray(cmd, Path(tmp), timeout=600)
                pt.append(tm.get("trace", float("nan")))
                wall.append(tm["wall"])
        povray = {"status": "ok", "trace_median_s": statistics.median(pt), "trace_runs_s": pt,
                  "wall_median_s": statistics.median(wall), "frames": len(po.color_frames(sc, rules))}  # fmt: skip
    out["povray"] = povray
    out["reference_trace_f64_median_s"] = statistics.median(ref_times) if ref_times else trace_seconds(tr)
    ref = out["reference_trace_f64_median_s"]
    out["speedup_vs_mitsuba_direct"] = mitsuba["median_s"] / ref if mitsuba["status"] == "ok" else None
    out["speedup_vs_povray_trace"] = povray["trace_median_s"] / ref if povray["status"] == "ok" else None
    return out


# ---------------------------------------------------------------------------------------------
# targets, report


def evaluate_targets(cfg: Config, res: dict[str, Any]) -> list[dict[str, Any]]:
    f64 = res["reference"]["f64"]["trace"]["mpix_s"]
    cold = res["cold"]["cold_cache"]["median_s"]

    def verdict(ok: bool) -> str:
        return "n/a" if cfg.quick else ("PASS" if ok else "MISS")

    ref, riv = res["reference"], res["rivals"]
    render_ratio = ref["f64"]["render"]["median_s"] / ref["f64"]["trace"]["median_s"]
    f32_speedup = ref["f64"]["trace"]["median_s"] / ref["f32"]["trace"]["median_s"]

    def row(name: str, target: str, measured: float | None, unit: str, ok: bool | None) -> dict[str, Any]:
        return {"name": name, "target": target, "measured": measured, "unit": unit,
                "verdict": "SKIP" if ok is None else verdict(ok)}  # fmt: skip

    mit, pov = riv["speedup_vs_mitsuba_direct"], riv["speedup_vs_povray_trace"]
    return [
        row("reference float64 trace kernel, three_balls 1024x1024", f">= {TARGET_MPIX_F64} Mpixel/s", f64,
            "Mpixel/s", f64 >= TARGET_MPIX_F64),
        row("cold-cache `minirt render scenes/exercise.toml` (256x256)", f"< {TARGET_COLD_S} s", cold, "s",
            cold < TARGET_COLD_S),
        row("whole f64 `render()` / trace kernel", f"<= {TARGET_RENDER_OVER_TRACE}x", render_ratio, "x",
            render_ratio <= TARGET_RENDER_OVER_TRACE),
        row("f32 trace speed-up over f64", f">= {TARGET_F32_SPEEDUP}x", f32_speedup, "x",
            f32_speedup >= TARGET_F32_SPEEDUP),
        row("f64 trace speed-up over Mitsuba `direct` render", f">= {TARGET_VS_MITSUBA}x", mit, "x",
            None if mit is None else mit >= TARGET_VS_MITSUBA),
        row("f64 trace speed-up over POV-Ray's trace time", f">= {TARGET_VS_POVRAY}x", pov, "x",
            None if pov is None else pov >= TARGET_VS_POVRAY),
    ]  # fmt: skip


def _f(x: Any, nd: int = 3) -> str:
    if x is None:
        return "–"
    if isinstance(x, float):
        return f"{x:.{nd}g}" if abs(x) < 1e-3 or abs(x) >= 1e4 else f"{x:.{nd}f}"
    return str(x)


def markdown(res: dict[str, Any]) -> str:
    m, ref, npy, cold, mem = res["meta"], res["reference"], res["numpy"], res["cold"], res["memory"]
    L = [f"# minirt benchmark{' (--quick)' if m['quick'] else ''}", ""]
    L.append(f"{m['cpus']} cores ({m['cpu']}), load average {m['loadavg_start']} at start, {m['loadavg_end']} at "
             f"end; Python {m['python']}, Dr.Jit {m['drjit']}, NumPy {m['numpy']}; commit {m['git']}; "
             f"{m['elapsed_s']:.0f} s.")  # fmt: skip
    L += ["", f"## Reference tracer: {ref['scene']} {ref['width']}x{ref['height']}, max_depth {ref['max_depth']}, "
          f"median of {ref['reps']} after {ref['warmup']} warm-up", "",
          "| precision | part | median s | min s | Mpixel/s | NumPy / this |", "|---|---|---|---|---|---|"]  # fmt: skip
    for prec in ("f64", "f32"):
        for kind in ("trace", "render", "render_checked"):
            s = ref[prec][kind]
            L.append(f"| {prec} | {kind} | {_f(s['median_s'], 4)} | {_f(s['min_s'], 4)} | {_f(s['mpix_s'], 3)} | "
                     f"{_f(npy['speedup'][f'{kind}_{prec}'], 3)}x |")  # fmt: skip
    L.append(f"| NumPy f64 | whole model | {_f(npy['median_s'], 4)} | {_f(npy['min_s'], 4)} | "
             f"{_f(npy['mpix_s'], 3)} | 1x |")  # fmt: skip
    if "writes" in ref:
        w, tr64 = ref["writes"], ref["f64"]
        wo = w["outputs"]
        floor = max(tr64["trace"]["median_s"], wo["median_s"])
        L += ["", f"Memory roofline of `render()`: its buffers alone as the kernel's own outputs, its layout at "
              f"this size ({wo['bytes'] / 1e6:.0f} MB, a kernel that only writes them), take {_f(wo['median_s'], 4)} s "
              f"({_f(wo['gb_s'], 3)} GB/s); a render takes at least the longer of that and the trace: "
              f"{_f(floor, 4)} s, {_f(floor / tr64['trace']['median_s'], 3)}x the trace (measured: "
              f"{_f(tr64['render']['median_s'] / tr64['trace']['median_s'], 3)}x)."]  # fmt: skip
        L += ["", f"The same values as (x, y, z, 0) packets scattered from a loop (a small render's layout, "
              f"{w['bytes'] / 1e6:.0f} MB): {_f(w['median_s'], 4)} s ({_f(w['gb_s'], 3)} GB/s), "
              f"{_f(w['median_s'] / wo['median_s'], 3)}x the outputs' time; their arithmetic alone (into packets "
              f"that stay in the L1 cache) takes {_f(w['cached_median_s'], 4)} s."]  # fmt: skip
    if "planar_outputs" in ref["f64"]:
        po = ref["f64"]["planar_outputs"]["median_s"]
        ratio = po / ref["f64"]["trace"]["median_s"]
        L += ["", f"The same buffers as the trace kernel's own outputs (planar, non-temporal stores, nothing "
              f"read back: the fastest layout): {_f(po, 4)} s, {_f(ratio, 3)}x the trace."]  # fmt: skip
    smp = ref["samples"]
    L += ["", f"Supersampled: {smp['width']}x{smp['height']} at {smp['spp']} rays per pixel, whole f64 render: "
          f"median {_f(smp['render']['median_s'], 4)} s, {_f(smp['render']['mpix_s'], 3)} M rays/s."]  # fmt: skip
    thr = ref["threads"]
    L += ["", "Threads (f64 trace kernel, median s): "
          + ", ".join(f"{k}: {_f(v, 4)}" for k, v in thr["trace_f64_median_s"].items())
          + f"; speed-up {_f(thr['speedup'], 3)}x."]  # fmt: skip
    L += ["", f"NumPy model vs reference image: max abs difference {npy['max_abs_diff_vs_reference']:.3g}.", ""]
    L += ["## Cold whole command", "", f"`{cold['command']}` ({cold['width']}x{cold['height']}); {cold['cache']}; "
          f"{cold['kernels_cached']} kernels cached.", "", "| cache | runs s | median s |", "|---|---|---|",
          *(f"| {k} | {', '.join(_f(t, 3) for t in cold[f'{k}_cache']['runs_s'])} | "
            f"{_f(cold[f'{k}_cache']['median_s'])} |" for k in ("cold", "warm")),
          ""]  # fmt: skip
    L += ["## Peak memory", "", f"Child process, {mem['scene']} {mem['width']}x{mem['height']} {mem['precision']}: "
          f"peak RSS {mem['peak_mb']:.0f} MB (after imports {mem['after_imports_mb']:.0f} MB, "
          f"render adds {mem['render_adds_mb']:.0f} MB; ru_maxrss {mem['ru_maxrss_mb']:.0f} MB).", ""]  # fmt: skip
    L += ["## Oracles (same run)", "",
          "| backend | scene | size | status | wall s | work s (keys) | Mpixel/s wall | Mpixel/s work | "
          "reference s | wall / reference | work / reference |",
          "|---|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for r in res["oracles"]:
        if r["status"] != "ok":
            L.append(f"| {r['backend']} | {r['scene']} | {r['size']} | {r['status'].upper()}: {r['reason']} "
                     "| | | | | | | |")  # fmt: skip
            continue
        scene = r["scene"] + (" (mesh camera)" if r.get("camera") == "mesh_camera" else "")
        L.append(f"| {r['backend']} | {scene} | {r['size']} | ok | {_f(r['wall_s'])} | {_f(r['work_s'])} "
                 f"({'+'.join(r['work_keys'])}) | {_f(r['mpix_s'])} | {_f(r['work_mpix_s'])} | "
                 f"{_f(r['reference_wall_s'])} | {_f(r['ratio_wall_to_reference'], 3)}x | "
                 f"{_f(r['ratio_work_to_reference'], 3)}x |")  # fmt: skip
    riv = res["rivals"]
    L += ["", f"## The same scene in Mitsuba and POV-Ray ({riv['scene']} {riv['width']}x{riv['height']}, "
          "interleaved with the reference's f64 trace)", "",
          f"Reference f64 trace kernel: median {_f(riv['reference_trace_f64_median_s'], 4)} s.", ""]  # fmt: skip
    mit, pov = riv["mitsuba_direct"], riv["povray"]
    L.append(f"- Mitsuba `direct` ({mit.get('variant', '')}, 1 spp): " + (
        f"median {_f(mit['median_s'], 4)} s, reference {_f(riv['speedup_vs_mitsuba_direct'], 3)}x as fast"
        if mit["status"] == "ok" else f"SKIP: {mit['reason']}"))  # fmt: skip
    L.append("- POV-Ray trace time (its statistics): " + (
        f"median {_f(pov['trace_median_s'], 4)} s (whole command {_f(pov['wall_median_s'], 3)} s), "
        f"reference {_f(riv['speedup_vs_povray_trace'], 3)}x as fast" if pov["status"] == "ok"
        else f"SKIP: {pov['reason']}"))  # fmt: skip
    L += ["", "## Targets", "", "| target | measured | verdict |", "|---|---|---|"]
    for t in res["targets"]:
        L.append(f"| {t['name']}: {t['target']} | {_f(t['measured'])} {t['unit']} | {t['verdict']} |")
    return "\n".join(L) + "\n"


def run(cfg: Config) -> dict[str, Any]:
    import drjit as dr

    t_start = time.perf_counter()
    meta: dict[str, Any] = {
        "quick": cfg.quick,
        "cpus": os.cpu_count(),
        "cpu": _cpu_model(),
        "loadavg_start": _loadavg(),
        "python": platform.python_version(),
        "drjit": dr.__version__,
        "numpy": np.__version__,
        "git": _git(),
        "povray_on_path": shutil.which("povray") is not None,
        "config": cfg.__dict__,
    }
    res: dict[str, Any] = {"meta": meta}
    res["memory"] = bench_memory(cfg)  # first, while this process is small (see bench_memory)
    res["reference"] = bench_reference(cfg)
    res["numpy"] = bench_numpy(cfg, res["reference"])
    res["cold"] = bench_cold(cfg)
    res["oracles"] = bench_oracles(cfg)
    res["rivals"] = bench_rivals(cfg)
    res["targets"] = evaluate_targets(cfg, res)
    meta["loadavg_end"] = _loadavg()
    meta["elapsed_s"] = time.perf_counter() - t_start
    return res


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="small sizes, 1-2 repetitions (for tests)")
    ap.add_argument("--out", type=Path, help="write the results as JSON here")
    ap.add_argument(
        "--reference-only",
        action="store_true",
        help="time the reference tracer alone and print its figures as JSON (for A/B runs of two trees: "
        "PYTHONPATH=TREE python benchmarks/bench.py --reference-only, the trees in turn)",
    )
    args = ap.parse_args(argv)
    if args.reference_only:
        import minirt

        ref = bench_reference(Config.make(args.quick))
        ref["tree"] = str(Path(minirt.__file__).resolve().parent.parent)
        print(json.dumps(ref, default=float))
        return 0
    res = run(Config.make(args.quick))
    print(markdown(res))
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(res, indent=2, default=float) + "\n")
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
