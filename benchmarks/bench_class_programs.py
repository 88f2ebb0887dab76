"""A class of programs graded at once: what ``minirt grade --class DIR --program-file NAME`` costs.

    .venv/bin/python benchmarks/bench_class_programs.py [--students 50] [--kind cpp|python] [--size N]
                                                         [--workers N] [--out FILE.json]

Generates a class of ``--students`` programs in a temporary folder and grades it with one child process,
``python -m minirt grade --class ... -q`` (start-up, the compiles, the sandboxed runs, the diagnoses and the
files included), at the suite's default size unless ``--size``:

- ``cpp``: variants of the bundled 2014 sample (scenes/samples/raytracer2014.cpp), its three ``#define``\\ s
  (offset, pixel position, rays from the image plane) and its highlight's exponent set per student from
  ``VARIANTS`` in turn, one in 25 with a compile error; each source carries its student's name in a comment,
  so every source is distinct and compiled (as a real class's are), from an empty build cache.
- ``python``: tests/support/numpy_tracer.py with its default rules changed per student (``PY_VARIANTS``),
  run by this interpreter (``--program-command "python {file} {scene} {out}"``).

Reported: wall seconds and CPU seconds (user + system of the child and every process it waited for:
``resource.getrusage(RUSAGE_CHILDREN)`` around the run -- the compilers, the sandboxed programs, the Dask
workers), per student, and the class's verdict counts, with the machine's line (bench_cpu.machine).
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT / "benchmarks") not in sys.path:
    sys.path.insert(0, str(ROOT / "benchmarks"))

SAMPLE = ROOT / "scenes" / "samples" / "raytracer2014.cpp"
TRACER = ROOT / "tests" / "support" / "numpy_tracer.py"
# (OFFSET, PIXEL, FROM_PLANE, the highlight's exponent): the edition's, and the bugs real solutions have
VARIANTS = (
    ("1e-3", "0.5", "0", "16"),  # the edition
    ("1e-4", "0.0", "1", "16"),  # the sample as shipped: corners, rays from the image plane
    ("1e-3", "0.0", "0", "16"),  # pixel corners
    ("1e-3", "0.5", "1", "16"),  # rays from the image plane
    ("1e-3", "0.5", "0", "8"),  # the 2013 edition's exponent
)
PY_VARIANTS = (
    {},
    {"pixel_sample": "center"},
    {"specular_exponent": 16},
    {"background": "on-miss"},
    {"shadow_range": "to-light", "two_sided": "true"},
)
BROKEN_EVERY = 25  # one student in this many hands in a source that does not compile


def _define(text: str, name: str, value: str) -> str:
    start = text.index(f"#define {name} ")
    return text[:start] + f"#define {name} {value}" + text[text.index("\n", start) :]


def cpp_class(folder: Path, n: int) -> None:
    base = SAMPLE.read_text()
    for k in range(n):
        offset, pixel, plane, exponent = VARIANTS[k % len(VARIANTS)]
        text = base
        for name, value in (("OFFSET", offset), ("PIXEL", pixel), ("FROM_PLANE", plane)):
            text = _define(text, name, value)
        text = text.replace("std::pow(rs, 16)", f"std::pow(rs, {exponent})")
        if k % BROKEN_EVERY == BROKEN_EVERY - 1:
            text = text.replace("void add_shape(const Shape& s) {", "void add_shape(const Shape& s) { undeclared();")
        student = folder / f"student{k:03d}"
        student.mkdir(parents=True)
        (student / "raytracer.cpp").write_text(f"// {student.name}\n{text}")


def python_class(folder: Path, n: int) -> None:
    base = TRACER.read_text()
    for k in range(n):
        text = base
        for rule, value in PY_VARIANTS[k % len(PY_VARIANTS)].items():
            start = text.index(f'"{rule}": ')
            end = text.index(",", start)
            text = text[:start] + f'"{rule}": {json.dumps(value)}' + text[end:]
        student = folder / f"student{k:03d}"
        student.mkdir(parents=True)
        (student / "tracer.py").write_text(text)


def run(kind: str, students: int, size: str | None, workers: int | None) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="bench-class-programs-") as tmp:
        tmp = Path(tmp)
        cls = tmp / "class"
        (cpp_class if kind == "cpp" else python_class)(cls, students)
        args = [sys.executable, "-m", "minirt", "grade", "--class", str(cls), "-o", str(tmp / "out"), "-q"]
        if kind == "cpp":
            args += ["--program-file", "raytracer.cpp"]
        else:
            args += ["--program-file", "tracer.py", "--program-command", f"{sys.executable} {{file}} {{scene}} {{out}}"]
        args += ["--size", size] if size else []
        args += ["--workers", str(workers)] if workers else []
        env = {"PATH": "/usr/bin:/bin", "MINIRT_PROGRAM_CACHE": str(tmp / "builds"), "HOME": str(Path.home())}
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        p = subprocess.run(args, capture_output=True, text=True, env=env, cwd=ROOT, check=False)
        wall = time.perf_counter() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        if p.returncode != 0:
            raise SystemExit(f"grade --class failed ({p.returncode}): {p.stderr.strip()[-2000:]}")
        doc = json.loads((tmp / "out" / "grades.json").read_text())
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"kind": kind, "students": students, "size": size or "the suite's default", "wall_s": round(wall, 1),
            "cpu_s": round(cpu, 1), "wall_per_student_s": round(wall / students, 2),
            "cpu_per_student_s": round(cpu / students, 2), "verdicts": doc["verdicts"],
            "summary": p.stdout.strip()}  # fmt: skip


def main(argv: list[str] | None = None) -> None:
    from bench_cpu import machine

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--students", type=int, default=50)
    ap.add_argument("--kind", choices=("cpp", "python"), default="cpp")
    ap.add_argument("--size", default=None, help="WIDTHxHEIGHT (default: the suite's size)")
    ap.add_argument("--workers", type=int, default=None, help="local processes (default: minirt's)")
    ap.add_argument("--out", type=Path, default=None, help="write the figures as JSON")
    a = ap.parse_args(argv)
    print(machine())
    r = run(a.kind, a.students, a.size, a.workers)
    per = f"{r['wall_per_student_s']} s wall, {r['cpu_per_student_s']} s CPU per student"
    print(f"{r['students']} {r['kind']} programs at {r['size']}: wall {r['wall_s']} s, CPU {r['cpu_s']} s ({per})")
    print(f"verdicts: {r['verdicts']}")
    print(r["summary"])
    if a.out:
        a.out.write_text(json.dumps({"machine": machine(), **r}, indent=2, sort_keys=True) + "\n")


if __name__ == "__main__":
    main()
