"""minirt scale benchmark: how the reference tracer's time grows with the number of balls.

Usage::

    .venv/bin/python benchmarks/bench_scale.py [--quick] [--sections threshold,layouts,check,slope] [--out FILE.json]

Scenes are fresh random layouts (``minirt.campaign.generate.balls_scene``: n balls over a mirror floor, 512²,
max_depth 3, seeded), so every scene is a layout no kernel cache has seen. Sections:

- ``threshold``: few balls, the unrolled path (every shape compiled into the kernel) against the BVH
  (``minirt.reference.accel``), each as a child process from an empty Dr.Jit kernel cache (``DRJIT_CACHE_DIR``):
  import, parse, render, compile included; and the warm render time in process (median of 3 after a
  warm-up). The crossover is what ``tracer.ACCEL_MIN_SHAPES`` should be.
- ``layouts``: the whole command ``python -m minirt render FILE --out TMP`` from an empty kernel cache
  for n = 1 ... 100,000 (what a user waits for). Targets: 1,024 balls within 3x the time of 1 ball;
  100,000 balls under 60 s.
- ``check``: the whole ``minirt check`` against every oracle (warm kernel cache) of 1,024 and of 10,000 random
  balls at 128², and of the bundled scenes, each with its peak memory (the minirt process's VmHWM; the
  renderers' own processes not counted) and each backend's seconds: the oracles' exports, bands and rule
  diagnosis at many shapes. Targets: the bundled scenes <= 15 s, 1,024 balls <= 20 s, 10,000 balls <= 120 s.
- ``slope``: the warm trace time (primary rays, every level, ``dr.eval``; no read-out) against n, and
  its log-log slope from 16 to 100,000 balls (goal <= 0.3), beside POV-Ray's own trace time (its
  statistics, start-up and parse excluded) on the same scenes up to 10,000 balls.

--quick: 64², fewer sizes, one repetition (finishes in about a minute; the targets are then n/a).
--sections: only these sections (default: all).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench import timed_child, trace_seconds  # noqa: E402  (benchmarks/ is the script's folder: on sys.path)

from minirt.campaign.generate import balls_scene  # noqa: E402

_CHILD = r"""
import json, sys, time
t0 = time.perf_counter()
from minirt.model.rules import resolve
from minirt.model.scene import load_scene
from minirt.reference.tracer import Tracer
sc = load_scene(sys.argv[1])
t1 = time.perf_counter()
Tracer(sc, resolve(sc), accel=sys.argv[2]).render()
t2 = time.perf_counter()
print(json.dumps({"import_parse": t1 - t0, "render": t2 - t1}))
"""


def _write(tmp: Path, n: int, size: int, seed: int) -> Path:
    p = tmp / f"balls_{n}_{seed}.toml"
    p.write_text(balls_scene(n, seed=seed, width=size, height=size, max_depth=3))
    return p


def _warm(tracer, reps: int) -> float:
    tracer.render()
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        tracer.render()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _trace_kernel(tracer, reps: int) -> float:
    """Primary rays and every level traced and evaluated (bench.py's ``trace``): the median of ``reps``
    runs after a warm-up."""
    trace_seconds(tracer)
    return statistics.median([trace_seconds(tracer) for _ in range(reps)])


def bench_threshold(tmp: Path, sizes: list[int], size: int, reps: int) -> list[dict[str, Any]]:
    from minirt.model.rules import resolve
    from minirt.model.scene import load_scene
    from minirt.reference.tracer import Tracer

    rows = []
    for n in sizes:
        path = _write(tmp, n, size, seed=1000 + n)
        row: dict[str, Any] = {"balls": n, "shapes": n + 1}
        sc = load_scene(path)
        for accel in ("unrolled", "bvh"):
            cache = Path(tempfile.mkdtemp(dir=tmp, prefix="jit-"))
            wall, out = timed_child([sys.executable, "-c", _CHILD, str(path), accel], cache)
            row[f"{accel}_cold_wall_s"] = wall
            row[f"{accel}_cold_render_s"] = json.loads(out.strip().splitlines()[-1])["render"]
            row[f"{accel}_warm_render_s"] = _warm(Tracer(sc, resolve(sc), accel=accel), reps)
        rows.append(row)
        print(f"threshold n={n}: {row}", file=sys.stderr, flush=True)
    return rows


def bench_layouts(tmp: Path, sizes: list[int], size: int) -> list[dict[str, Any]]:
    rows = []
    for n in sizes:
        path = _write(tmp, n, size, seed=n)
        cache = Path(tempfile.mkdtemp(dir=tmp, prefix="jit-"))
        out = tmp / f"out-{n}"
        wall, _ = timed_child([sys.executable, "-m", "minirt", "render", str(path), "--out", str(out)], cache)
        rows.append({"balls": n, "whole_command_cold_s": wall, "kernels_compiled": len(list(cache.iterdir()))})
        print(f"layouts n={n}: {wall:.2f} s", file=sys.stderr, flush=True)
    return rows


# ``python -m minirt ARGS`` that writes its peak resident memory (VmHWM, kB) to $MINIRT_BENCH_PEAK at exit
_PEAK = r"""
import atexit, os, runpy, sys

def _peak():
    with open("/proc/self/status") as f:
        kb = next(line.split()[1] for line in f if line.startswith("VmHWM"))
    with open(os.environ["MINIRT_BENCH_PEAK"], "w") as f:
        f.write(kb)

atexit.register(_peak)
sys.argv = ["minirt", *sys.argv[1:]]
runpy.run_module("minirt", run_name="__main__")
"""


def _check(tmp: Path, files: list[str], label: str) -> tuple[float, float, list[dict[str, Any]]]:
    """The whole ``python -m minirt check FILES -q --json OUT``: wall seconds, peak MB, the document's scenes."""
    doc, peak = tmp / f"check-{label}.json", tmp / f"peak-{label}"
    args = [sys.executable, "-c", _PEAK, "check", *files, "-q", "--json", str(doc)]
    os.environ["MINIRT_BENCH_PEAK"] = str(peak)
    try:
        wall, _ = timed_child(args, ok=(0, 1))  # 1: a FAIL verdict, still a timing
    finally:
        del os.environ["MINIRT_BENCH_PEAK"]
    return wall, int(peak.read_text()) / 1024, json.loads(doc.read_text())["scenes"]


def bench_check(tmp: Path, n: int, size: int) -> dict[str, Any]:
    """The whole ``python -m minirt check FILE --json OUT`` of n random balls against every oracle (warm kernel
    cache: what a user waits for on a second run), with its peak memory and each backend's own seconds from
    the document. The oracles' exports, bands and the rule diagnosis all see every shape: a per-shape step in
    any of them shows here (a per-shape Mitsuba call once made 1,024 balls at 128x128 a 9-minute check)."""
    path = _write(tmp, n, size, seed=7)
    wall, peak, scenes = _check(tmp, [str(path)], str(n))
    per = {k: {"verdict": v["verdict"], "seconds": v["seconds"]} for k, v in scenes[0]["backends"].items()}
    row = {"balls": n, "size": size, "whole_command_s": wall, "peak_mb": peak, "backends": per}
    print(f"check n={n} at {size}x{size}: {wall:.1f} s, {peak:.0f} MB {row['backends']}", file=sys.stderr, flush=True)
    return row


def bench_check_bundled(tmp: Path) -> dict[str, Any]:
    """``minirt check`` over the bundled scenes (its default), whole command, with its peak memory."""
    wall, peak, scenes = _check(tmp, [], "bundled")
    verdicts = sorted({b["verdict"] for s in scenes for b in s["backends"].values()})
    row = {"scenes": len(scenes), "whole_command_s": wall, "peak_mb": peak, "verdicts": verdicts}
    print(f"check of the bundled scenes: {wall:.1f} s, {peak:.0f} MB", file=sys.stderr, flush=True)
    return row


def bench_slope(tmp: Path, sizes: list[int], pov_max: int, size: int, reps: int) -> dict[str, Any]:
    from minirt.harness import backends
    from minirt.model.rules import resolve
    from minirt.model.scene import load_scene
    from minirt.reference.tracer import Tracer

    rows = []
    pov = backends.info("povray")
    for n in sizes:
        sc = load_scene(_write(tmp, n, size, seed=n))
        rules = resolve(sc)
        row: dict[str, Any] = {"balls": n, "reference_trace_s": _trace_kernel(Tracer(sc, rules), reps)}
        if n <= pov_max and pov.available:
            res = backends.render("povray", sc, rules)
            row["povray_trace_s"] = res.meta["timings"].get("trace")
            row["povray_parse_s"] = res.meta["timings"].get("parse")
        rows.append(row)
        print(f"slope n={n}: {row}", file=sys.stderr, flush=True)

    def fit(key: str, lo: int) -> float | None:
        pts = [(r["balls"], r[key]) for r in rows if r.get(key) and r["balls"] >= lo]
        if len(pts) < 2:
            return None
        x, y = np.log([p[0] for p in pts]), np.log([max(p[1], 1e-3) for p in pts])
        return float(np.polyfit(x, y, 1)[0])

    return {
        "rows": rows,
        "reference_slope_16_up": fit("reference_trace_s", 16),
        "povray_slope_16_up": fit("povray_trace_s", 16),
        "povray_unavailable": None if pov.available else pov.detail,
    }


def evaluate(res: dict[str, Any], quick: bool) -> list[dict[str, Any]]:
    def verdict(ok: bool | None) -> str:
        return "n/a" if quick or ok is None else ("PASS" if ok else "MISS")

    lay = {r["balls"]: r["whole_command_cold_s"] for r in res.get("layouts", [])}
    ratio = lay[1024] / lay[1] if 1 in lay and 1024 in lay else None
    big = lay.get(100000)
    slope = res["slope"]["reference_slope_16_up"] if "slope" in res else None
    chk = {r["balls"]: r["whole_command_s"] for r in res.get("check", {}).get("balls", []) if r["size"] == 128}
    bundled = res.get("check", {}).get("bundled", {}).get("whole_command_s")
    checks = [
        {"name": f"minirt check, {what}, whole command", "target": f"<= {limit} s", "measured": got,
         "verdict": verdict(None if got is None else got <= limit)}
        for what, got, limit in (("the bundled scenes", bundled, 15), ("1,024 balls at 128x128", chk.get(1024), 20),
                                 ("10,000 balls at 128x128", chk.get(10000), 120))
    ]  # fmt: skip
    return [
        *checks,
        {"name": "1,024 balls / 1 ball, whole command, cold cache", "target": "<= 3", "measured": ratio,
         "verdict": verdict(None if ratio is None else ratio <= 3)},
        {"name": "100,000 balls, whole command, cold cache", "target": "< 60 s", "measured": big,
         "verdict": verdict(None if big is None else big < 60)},
        {"name": "log-log slope of trace time vs balls, 16 up", "target": "<= 0.3 (goal)", "measured": slope,
         "verdict": verdict(None if slope is None else slope <= 0.3)},
    ]  # fmt: skip


SECTIONS = ("threshold", "layouts", "check", "slope")


def _git() -> str:
    try:
        return subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True
        ).stdout.strip()
    except OSError:
        return "unknown"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="small sizes, one repetition")
    ap.add_argument("--out", type=Path, help="also write the results as JSON")
    ap.add_argument("--sections", default=",".join(SECTIONS), help="comma list of sections to run (default: all)")
    a = ap.parse_args(argv)
    sections = [s for s in a.sections.split(",") if s]
    unknown = sorted(set(sections) - set(SECTIONS))
    if unknown:
        ap.error(f"unknown section(s) {', '.join(unknown)} (known: {', '.join(SECTIONS)})")
    size = 64 if a.quick else 512
    reps = 1 if a.quick else 3
    with tempfile.TemporaryDirectory(prefix="minirt-bench-scale-") as tmp_s:
        tmp = Path(tmp_s)
        res: dict[str, Any] = {
            "meta": {
                "cores": os.cpu_count(),
                "machine": platform.machine(),
                "commit": _git(),
                "quick": a.quick,
                "size": size,
                "load_before": os.getloadavg(),
            },
        }
        if "threshold" in sections:
            res["threshold"] = bench_threshold(tmp, [1, 4, 16] if a.quick else [1, 2, 4, 8, 16, 32, 64], size, reps)
        if "layouts" in sections:
            res["layouts"] = bench_layouts(tmp, [1, 1024] if a.quick else [1, 16, 128, 1024, 10000, 100000], size)
        if "check" in sections:
            res["check"] = {
                "bundled": bench_check_bundled(tmp),
                "balls": [bench_check(tmp, n, 32 if a.quick else 128) for n in ([64] if a.quick else [1024, 10000])],
            }
        if "slope" in sections:
            res["slope"] = bench_slope(
                tmp, [16, 256] if a.quick else [16, 128, 1024, 10000, 100000], 256 if a.quick else 10000, size, reps
            )
    res["meta"]["load_after"] = os.getloadavg()
    res["targets"] = evaluate(res, a.quick)
    if a.out:
        a.out.write_text(json.dumps(res, indent=2, allow_nan=False) + "\n")
    print(json.dumps(res, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
