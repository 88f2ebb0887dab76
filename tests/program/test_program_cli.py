"""``minirt grade --program`` and ``render -b program:SPEC`` from the command line: the JSON document,
the exit status, and bad input as one line with exit status 2."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from support.inproc import minirt as here
from support.programs import bare_env

ROOT = Path(__file__).resolve().parents[2]
TRACER = ROOT / "tests" / "support" / "numpy_tracer.py"
MINIRT = [sys.executable, "-m", "minirt"]


def minirt(*args: str, tmp_path: Path) -> subprocess.CompletedProcess:
    env = bare_env(tmp_path)
    return subprocess.run([*MINIRT, *args], capture_output=True, text=True, cwd=tmp_path, env=env, timeout=600)


def test_grade_program_writes_its_document_and_exits_1_when_it_differs(tmp_path):
    spec = f"{sys.executable} {TRACER} --rule pixel_sample=center {{scene}} {{out}}"
    p = minirt("grade", "--program", spec, "rules", "--size", "48x48", "--json", "-", "-q", tmp_path=tmp_path)
    assert p.returncode == 1, p.stderr
    doc = json.loads(p.stdout)
    assert doc["verdict"] == "differs" and doc["diagnosis"]["rules"] == {"pixel_sample": "center"}
    assert [s["scene"] for s in doc["scenes"]] == ["rules"] and doc["scenes"][0]["error"] == ""
    assert doc["program"]["spec"] == spec
    # the rules scene alone cannot show a plane's normal unnormalised (its planes are written of unit length)
    # nor the sign of s in an even, unclamped highlight: said, with why
    assert {i["rule"] for i in doc["indistinguishable"]} == {"raw_normals_plane", "specular_s"}
    assert all(i["why"] for i in doc["indistinguishable"])


def test_render_takes_a_program_as_a_backend(tmp_path):
    spec = f"program:{sys.executable} {TRACER} {{scene}} {{out}}"
    p = minirt("render", "rules", "--width", "16", "--height", "16", "-b", spec, "-o", "out", "-q", tmp_path=tmp_path)
    assert p.returncode == 0, p.stderr
    assert sorted(f.name for f in (tmp_path / "out").iterdir()) == [
        "rules.program.exr",
        "rules.program.json",
        "rules.program.png",
    ]


def test_bad_input_is_one_line_and_exit_2(tmp_path):
    for args, words in (
        (["grade", "--program", "python3 tracer.py {scene}"], "needs {scene}"),
        (["grade", "--program", "missing.cpp"], "no such file"),
        (["grade", "--edition", "2014", "rules", "x.png"], "--edition goes with --program"),
        (["fuzz", "-b", "program:python3 t.py {scene} {out}"], "a program gives a colour image"),
    ):
        p = here(*args, cwd=tmp_path)  # in this process: an exit status and a line, no process needed
        assert p.returncode == 2 and words in p.stderr and "Traceback" not in p.stderr, (args, p.stderr)


def test_grade_program_renders_the_whole_suite_by_default(tmp_path):
    from minirt.grading.suite import program_suite

    spec = f"{sys.executable} {TRACER} --rule offset=1e-4 {{scene}} {{out}}"
    p = minirt("grade", "--program", spec, "--json", "-", "-q", tmp_path=tmp_path)
    assert p.returncode == 1, p.stderr
    doc = json.loads(p.stdout)
    assert [s["scene"] for s in doc["scenes"]] == [s.name for s in program_suite()]
    assert all(s["size"] == [96, 96] for s in doc["scenes"])
    # the grading set alone could not tell 1e-4 from 1e-6; the offset scenes read it
    assert doc["diagnosis"]["rules"] == {"offset": "0.0001"}
    assert all("course_grid" not in s for s in doc["scenes"])  # a command is no 2014 source
