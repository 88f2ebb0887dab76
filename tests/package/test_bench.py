"""benchmarks/bench.py --quick runs and writes every section with sane numbers.

No timing assertions: the machine is shared and timings are noisy; only structure, positivity and
finiteness are checked, and that a skipped or failed backend says why.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from minirt.harness.backends import oracle_names

ROOT = Path(__file__).resolve().parents[2]


def _start(script: str, out: Path) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, str(ROOT / "benchmarks" / script), "--quick", "--out", str(out)],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL,
    )  # fmt: skip


@pytest.fixture(scope="module")
def both(tmp_path_factory) -> dict[str, tuple[subprocess.CompletedProcess, Path]]:
    """bench.py --quick and bench_grade.py --quick, started together: two independent children whose
    time is mostly start-ups, compiles and POV-Ray's waits, so they overlap (no test asserts a timing)."""
    tmp = tmp_path_factory.mktemp("bench")
    runs = {s: (_start(s, tmp / f"{s}.json"), tmp / f"{s}.json") for s in ("bench.py", "bench_grade.py")}
    done = {}
    for script, (p, out) in runs.items():
        stdout, stderr = p.communicate(timeout=300)
        done[script] = (subprocess.CompletedProcess(p.args, p.returncode, stdout, stderr), out)
    return done


@pytest.fixture(scope="module")
def quick(both) -> tuple[dict, str]:
    p, out = both["bench.py"]
    assert p.returncode == 0, p.stderr[-2000:]
    return json.loads(out.read_text()), p.stdout


def _positive(x) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x) and x > 0


def _stats_ok(s: dict) -> None:
    assert _positive(s["median_s"]) and _positive(s["min_s"]) and _positive(s["mpix_s"])
    assert s["runs_s"] and all(_positive(t) for t in s["runs_s"])


@pytest.mark.slow
def test_sections_present(quick):
    res, stdout = quick
    assert set(res) >= {"meta", "reference", "numpy", "cold", "memory", "oracles", "targets"}
    assert res["meta"]["quick"] is True
    for heading in ("## Reference tracer", "## Cold whole command", "## Peak memory", "## Oracles", "## Targets"):
        assert heading in stdout


@pytest.mark.slow
def test_reference_and_numpy(quick):
    res, _ = quick
    for prec in ("f64", "f32"):
        for kind in ("trace", "render", "render_checked"):
            _stats_ok(res["reference"][prec][kind])
    _stats_ok(res["reference"]["f64"]["planar_outputs"])  # the render's floor, beside the render
    writes = res["reference"]["writes"]  # the write-only kernel: packet scatters, outputs, their arithmetic
    assert writes["outputs"]["bytes"] < writes["bytes"]  # outputs need no fourth (zero) component
    assert all(_positive(x) for x in (writes["gb_s"], writes["outputs"]["gb_s"], writes["cached_median_s"]))
    smp = res["reference"]["samples"]
    _stats_ok(smp["render"])
    assert smp["spp"] == 16 and smp["width"] >= 4
    npy = res["numpy"]
    _stats_ok(npy)
    assert set(npy["speedup"]) == {f"{k}_{p}" for k in ("trace", "render", "render_checked") for p in ("f64", "f32")}
    assert all(_positive(v) for v in npy["speedup"].values())
    # the NumPy version is the same model: it must reproduce the reference image
    assert npy["max_abs_diff_vs_reference"] < 1e-9


@pytest.mark.slow
def test_cold_and_memory(quick):
    res, _ = quick
    _stats_ok(res["cold"]["cold_cache"])
    _stats_ok(res["cold"]["warm_cache"])
    assert res["cold"]["kernels_cached"] > 0  # DRJIT_CACHE_DIR was honoured
    mem = res["memory"]
    assert _positive(mem["peak_mb"]) and _positive(mem["after_imports_mb"]) and _positive(mem["ru_maxrss_mb"])
    assert mem["peak_mb"] >= mem["after_imports_mb"]


@pytest.mark.slow
def test_oracle_rows(quick):
    res, _ = quick
    rows = res["oracles"]
    backends = {r["backend"] for r in rows}
    assert backends == set(oracle_names())  # every registered oracle
    for r in rows:
        assert r["status"] in ("ok", "skip", "error")
        if r["status"] != "ok":
            assert isinstance(r["reason"], str) and r["reason"].strip(), r
            continue
        for key in ("wall_s", "mpix_s", "reference_wall_s", "ratio_wall_to_reference"):
            assert _positive(r[key]), (key, r)
        if r["work_s"] is not None:
            assert _positive(r["work_s"]) and r["work_keys"]
            assert r["work_s"] <= r["wall_s"] * 1.01


@pytest.mark.slow
def test_targets(quick):
    res, _ = quick
    assert len(res["targets"]) == 6
    for t in res["targets"]:
        assert _positive(t["measured"]) and t["verdict"] in ("PASS", "MISS", "n/a")
        assert t["verdict"] == "n/a"  # --quick sizes are not the targets' conditions


@pytest.mark.slow
def test_rivals_are_timed_beside_the_reference(quick):
    """The issue's yardsticks: Mitsuba's own `direct` render and POV-Ray's own trace time of the same scene
    and size, interleaved with the reference's f64 trace; both renderers are installed by make test."""
    res, stdout = quick
    riv = res["rivals"]
    assert (riv["width"], riv["height"]) == (res["reference"]["width"], res["reference"]["height"])
    assert _positive(riv["reference_trace_f64_median_s"])
    mit, pov = riv["mitsuba_direct"], riv["povray"]
    assert mit["status"] == "ok", mit
    assert mit["integrator"] == "direct" and len(mit["runs_s"]) == res["meta"]["config"]["reps"]
    assert all(_positive(t) for t in mit["runs_s"]) and _positive(riv["speedup_vs_mitsuba_direct"])
    assert pov["status"] == "ok", pov
    assert pov["frames"] == 1 and all(_positive(t) for t in pov["trace_runs_s"])
    assert pov["trace_median_s"] < pov["wall_median_s"]  # its statistic leaves out start-up and parsing
    assert "## The same scene in Mitsuba and POV-Ray" in stdout


@pytest.mark.slow
def test_grade_benchmark_quick(both):
    """benchmarks/bench_grade.py --quick: every section present, times positive, every class image graded
    and every diagnosis reproducing its image (the quick class is 3 students x 6 scenes at 48x48)."""
    p, out = both["bench_grade.py"]
    assert p.returncode == 0, p.stderr[-2000:]
    r = json.loads(out.read_text())
    assert all(_positive(t) for t in r["single"]["cold_s"] + r["single"]["warm_kernels_s"])
    assert r["single"]["found"] == r["single"]["injected"]
    assert _positive(r["class_cache"]["second_s"]) and r["class_cache"]["second_found"]
    k = r["class"]
    assert k["images"] == 18 and k["verdicts"]["error"] == 0
    assert k["reproduced_fully"] == 18, k
    assert "| class 3×6 at 48², 1 process |" in p.stdout and k["worker_processes"] == 1
