"""CPU-seconds per whole command: what a command costs on any machine, and this tree against another, paired.

    .venv/bin/python benchmarks/bench_cpu.py [--runs 5] [--versus TREE] [--only NAME ...] [--out FILE.json]

Each command runs as a child process (``TREE/.venv/bin/python -m minirt ...``: start-up, imports and files
included); its cost is the processor time of the child and of every process it waited for (user + system,
``resource.getrusage(RUSAGE_CHILDREN)`` around the run: the certified oracle's workers, POV-Ray, Blender, the
Dask workers), not the wall time a shared machine stretches. One warm-up run of each command first (it
compiles Dr.Jit's kernels into the cache the counted runs then read, except where a command asks for an empty
cache). With ``--versus TREE`` every command runs in both trees in turn, A B A B ..., and the ratio A/B is
taken pair by pair, so a machine whose speed drifts moves both sides of a ratio alike. Figures: min / median /
max. Each tree runs in its own virtual environment (``make setup`` there, or a copy of this one's with its
editable install pointed at TREE): the package maps ``minirt.oracles`` to the top-level ``oracles/`` folder
through its install, so another tree put first on ``PYTHONPATH`` would still import this one's oracles.

The first line names the machine: processor model, core count, and whether it has AVX-512 (Dr.Jit's LLVM
kernels and NumPy use it where it is there: the same command costs ~2x the CPU-seconds on an AVX2-only EPYC as
on an AVX-512 one, issue 50), so that tables from different machines are read side by side, not compared.

Commands (``COMMANDS``): ``help``; ``render`` (200 random balls over a mirror floor at 1024^2,
benchmarks/balls_scene.py, the reference); ``grade_cold`` / ``grade_warm`` (an 800^2 float32 render of
scenes/rules.toml with three wrong rules, bench_grade.py's ``single``, from an empty / a primed kernel
cache); ``check_exact`` (the bundled scenes against the certified oracle); ``check_all`` (the bundled scenes,
every oracle); ``grade_program`` (the 2014 sample C++ source graded over the program suite: minirt's own CPU,
its build and its compares -- the program's runs in bubblewrap's PID namespace do not reach ``RUSAGE_CHILDREN``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
SAMPLE_PROGRAM = ROOT / "scenes" / "samples" / "raytracer2014.cpp"
if str(ROOT / "benchmarks") not in sys.path:
    sys.path.insert(0, str(ROOT / "benchmarks"))


def machine() -> str:
    """The processor model, logical cores and AVX-512 (from /proc/cpuinfo where there is one)."""
    model, flags = platform.processor() or platform.machine(), set()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "model name":
                model = value.strip()
            elif key.strip() == "flags":
                flags = set(value.split())
    except OSError:
        pass
    avx = "AVX-512" if "avx512f" in flags else ("AVX2, no AVX-512" if "avx2" in flags else "no AVX2")
    return f"{model}, {os.cpu_count()} logical cores, {avx}"


def commands(tmp: Path) -> dict[str, tuple[list[str], dict[str, str]]]:
    """name -> (minirt's arguments, extra environment; "{fresh}": an empty folder of its own per run)."""
    grade = ["grade", "scenes/rules.toml", str(tmp / "single.png"), "--size", "800x800", "--quiet", "--json"]
    return {
        "help": (["--help"], {}),
        "render": (["render", str(tmp / "balls.toml"), "-b", "reference", "--out", str(tmp / "r"), "--quiet"], {}),
        "grade_cold": ([*grade, str(tmp / "g.json")], {"DRJIT_CACHE_DIR": "{fresh}"}),
        "grade_warm": ([*grade, str(tmp / "g.json")], {"DRJIT_CACHE_DIR": str(tmp / "kernels")}),
        "check_exact": (["check", "-b", "exact", "--quiet", "--json", str(tmp / "ce.json")], {}),
        "check_all": (["check", "--quiet", "--json", str(tmp / "ca.json")], {}),
        # this tree's 2014 sample as the program in both trees (a TREE before `grade --program` cannot run it)
        "grade_program": (["grade", "--program", str(SAMPLE_PROGRAM), "-q", "--json", str(tmp / "gp.json")], {}),
    }


def prepare(tmp: Path, names: list[str]) -> None:
    """The inputs: the 200-ball scene, the grade's image."""
    if "render" in names:
        from balls_scene import main as write_balls

        write_balls([str(tmp / "balls.toml"), "--balls", "200", "--size", "1024", "--seed", "1"])
    if any(n.startswith("grade") for n in names):
        from bench_grade import student_png

        wrong = {"pixel_sample": "center", "specular_exponent": 16, "encoding": "floor256"}  # bench_grade's single
        student_png(ROOT / "scenes/rules.toml", 800, wrong, tmp / "single.png")


def cpu_of(args: list[str], env: dict[str, str], tree: Path, tmp: Path) -> float:
    """User + system seconds of ``TREE/.venv/bin/python -m minirt ARGS`` and of every process it waited for."""
    full = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    for k, v in env.items():
        full[k] = tempfile.mkdtemp(dir=tmp, prefix="kernels-") if v == "{fresh}" else v
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    python = tree / ".venv" / "bin" / "python"
    done = subprocess.run([str(python), "-m", "minirt", *args], cwd=tree, env=full, capture_output=True)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode not in (0, 1):
        raise SystemExit(f"minirt {' '.join(args)} failed ({done.returncode}): {done.stderr.decode()[-2000:]}")
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def stats(xs: list[float]) -> dict[str, float]:
    return {"min": min(xs), "median": statistics.median(xs), "max": max(xs)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5, help="counted runs of each command (each tree)")
    ap.add_argument("--versus", type=Path, default=None, help="another checkout: paired runs, A = this tree")
    ap.add_argument("--only", nargs="*", default=None, help="these commands only (default: all)")
    ap.add_argument("--out", type=Path, default=None, help="write the figures as JSON")
    a = ap.parse_args(argv)
    tmp = Path(tempfile.mkdtemp(prefix="bench-cpu-"))
    table = commands(tmp)
    names = a.only or list(table)
    prepare(tmp, names)
    trees: dict[str, Path] = {"A": ROOT} | ({"B": a.versus.resolve()} if a.versus else {})
    for tree in trees.values():
        if not (tree / ".venv" / "bin" / "python").exists():
            raise SystemExit(f"{tree}: no .venv/bin/python (make setup there)")
    print(f"machine: {machine()}; python {platform.python_version()}")
    print("| command | " + " | ".join(f"{t} CPU-s (min / median / max)" for t in trees)
          + (" | A/B paired (min / median / max) |" if a.versus else " |"))  # fmt: skip
    print("|---" * (len(trees) + 1 + bool(a.versus)) + "|")
    figures: dict[str, Any] = {"machine": machine(), "runs": a.runs, "commands": {}}
    for name in names:
        args, env = table[name]
        for tree in trees.values():  # warm-up (kernels compiled into the cache the warm runs read)
            cpu_of(args, env, tree, tmp)
        got: dict[str, list[float]] = {t: [] for t in trees}
        for _ in range(a.runs):
            for t, tree in trees.items():
                got[t].append(cpu_of(args, env, tree, tmp))
        row: dict[str, Any] = {"args": args, **{t: stats(v) for t, v in got.items()}}
        cells = [f"{s['min']:.2f} / **{s['median']:.2f}** / {s['max']:.2f}" for s in (row[t] for t in trees)]
        if a.versus:
            ratio = stats([x / y for x, y in zip(got["A"], got["B"], strict=True)])
            row["ratio"] = ratio
            cells.append(f"{ratio['min']:.2f} / **{ratio['median']:.2f}** / {ratio['max']:.2f}")
        figures["commands"][name] = row
        print(f"| {name} | " + " | ".join(cells) + " |", flush=True)
    if a.out:
        a.out.write_text(json.dumps(figures, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
