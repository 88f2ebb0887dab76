"""``minirt check --backend program:SPEC``: a program gives only an image, so its geometry check says
SKIP (never PASS) with the reason, and its image is compared with the reference's level by level off the
edges -- PASS for the exercise, FAIL for a program with a rule changed; a comparison that judges too
little is inconclusive; a scene of several samples a pixel is not compared; the program's flags; bad
input as one line with exit status 2."""

from __future__ import annotations

import json
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from support.inproc import minirt as here
from support.programs import minirt

from minirt.cli.check import program_backends
from minirt.errors import MinirtError
from minirt.harness.image_only import check_image_only
from minirt.harness.references import ReferenceCache
from minirt.model.bundled import find_scene
from minirt.model.result import RenderResult
from minirt.model.rules import resolve
from minirt.model.scene import load_scene

ROOT = Path(__file__).resolve().parents[2]
TRACER = ROOT / "tests" / "support" / "numpy_tracer.py"
MINIRT = [sys.executable, "-m", "minirt"]
# the NumPy tracer draws rules and three_balls as the model at 48^2 (tests/program/test_program_page.py)
SIZE = "48x48"


def program(*changes: str) -> str:
    rules = " ".join(f"--rule {c}" for c in changes)
    return f"program:{sys.executable} {TRACER} {rules} {{scene}} {{out}}"


def backends_of(doc: dict) -> dict[str, dict]:
    return {s["scene"]: next(iter(s["backends"].values())) for s in doc["scenes"]}


def test_the_exercise_passes_shading_and_skips_geometry(tmp_path):
    p = minirt("check", "rules", "three_balls", "soft", "-b", program(), "--size", SIZE, "-q", "--json", "c.json",
               "--junit", "c.xml", cwd=tmp_path)  # fmt: skip
    assert p.returncode == 0, p.stderr
    got = backends_of(json.loads((tmp_path / "c.json").read_text()))
    for scene in ("rules", "three_balls"):
        b = got[scene]
        assert b["geometry"]["verdict"] == "skip" and "gives only an image" in b["geometry"]["reason"]
        assert b["shading"]["verdict"] == "pass" and b["shading"]["color8_over_1"] == 0
        assert b["shading"]["compared_pixels"] > 2304 // 2  # judged on most of the image: conclusive
        assert b["verdict"] == "pass"
    # soft takes 16 samples a pixel: nothing is compared, and the backend says so (not PASS)
    assert got["soft"]["verdict"] == "skip" and "16 samples a pixel" in got["soft"]["reason"]
    assert got["soft"]["geometry"]["verdict"] == "skip"
    junit = ET.parse(tmp_path / "c.xml").getroot()
    geometry = [c for c in junit.iter("testcase") if c.get("name") == "geometry"]
    assert len(geometry) == 3 and all(c.find("skipped") is not None for c in geometry)


# check of a program with a rule changed, in this process's loop (no --workers): what
# test_a_program_with_a_rule_changed_fails_shading_and_the_rule_is_named asserts, and what
# test_on_worker_processes_the_verdicts_are_the_same compares the worker processes' run with
CHANGED = ["check", "rules", "-b", program("pixel_sample=center"), "--size", SIZE, "-q", "--json", "-"]


@pytest.fixture(scope="module")
def changed_here(tmp_path_factory) -> subprocess.CompletedProcess:
    return minirt(*CHANGED, cwd=tmp_path_factory.mktemp("changed"))


def test_a_program_with_a_rule_changed_fails_shading_and_the_rule_is_named(changed_here):
    p = changed_here
    assert p.returncode == 1, p.stderr
    b = backends_of(json.loads(p.stdout))["rules"]
    assert b["verdict"] == "fail" and b["shading"]["verdict"] == "fail" and b["shading"]["color8_over_1"] > 100
    assert b["geometry"]["verdict"] == "skip"
    assert b["rule_diagnosis"]["rules_explaining"] == {"pixel_sample": "center"}


def test_a_program_beside_an_oracle_in_one_list(tmp_path):
    p = minirt("check", "rules", "-b", f"embree,{program()}", "--size", SIZE, "-q", "--json", "-", cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    (scene,) = json.loads(p.stdout)["scenes"]
    embree, prog = scene["backends"].values()
    assert next(iter(scene["backends"])) == "embree" and embree["geometry"]["verdict"] == "pass"
    assert prog["geometry"]["verdict"] == "skip" and prog["shading"]["verdict"] == "pass"


def test_too_small_an_image_to_judge_is_inconclusive_not_pass(tmp_path):
    p = minirt("check", "rules", "-b", program(), "--size", "6x6", "-q", "--json", "-", cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    b = backends_of(json.loads(p.stdout))["rules"]
    assert b["shading"]["verdict"] == "warn" and b["shading"]["reason"].startswith("inconclusive: ")
    assert b["verdict"] == "warn" and b["inconclusive"] is True


def test_a_nonfinite_colour_off_the_edges_fails():
    scene = load_scene(find_scene("rules")).with_overrides(width=32, height=32, samples=1)
    rules = resolve(scene)
    refs = ReferenceCache(scene)
    color = refs.get(rules, samples=1).color.copy()
    res = RenderResult("image", 32, 32, color=color)
    assert check_image_only(scene, rules, "image", refs, res)["shading"].verdict == "pass"
    color[::2] = np.nan  # every other row
    shading = check_image_only(scene, rules, "image", refs, res)["shading"]
    n = shading.figures["nonfinite_color"]
    assert shading.verdict == "fail" and f"NaN or infinite colour at {n} pixel(s) off the edges" in shading.reason
    assert 0 < n < 32 * 16  # those off the edges (an edge pixel's NaN is not judged)


def test_the_program_flags_go_into_the_backends_name():
    spec = "program:python3 t.py {scene} {out}"
    assert program_backends(["embree", spec], timeout=5.0, no_sandbox=True) == [
        "embree",
        "program(timeout=5,sandbox=off):python3 t.py {scene} {out}",
    ]
    own = "program(timeout=9):python3 t.py {scene} {out}"
    assert program_backends([own], no_sandbox=True) == ["program(timeout=9,sandbox=off):python3 t.py {scene} {out}"]
    try:
        program_backends(["embree"], edition="2013")
    except MinirtError as e:
        assert "--edition goes with a program backend" in str(e)
    else:
        raise AssertionError("--edition without a program was taken")


def test_bad_input_is_one_line_and_exit_2(tmp_path):
    spec = program()
    for args, words in (
        (["check", "rules", "-b", "program:python3 t.py {scene}"], "needs {scene}"),
        (["check", "rules", "-b", "program:missing.cpp"], "missing.cpp: no such file"),
        (["check", "rules", "-b", "embree", "--no-sandbox"], "--no-sandbox goes with a program backend"),
        (["check", "rules", "-b", spec, "--edition", "2013"], "--edition and --adapter go with a C++ source"),
        (["check", "rules", "-b", "program(colour=red):x {scene} {out}"], "unknown option colour"),
        (["fuzz", "-b", spec], "a program gives a colour image"),
        # the cache knows a backend by its name: a script changed under the same SPEC would be answered from it
        (["check", "rules", "-b", spec, "--cache", "cache"], "checked afresh every time"),
    ):
        p = here(*args, cwd=tmp_path)  # in this process: an exit status and a line, no process needed
        assert p.returncode == 2 and words in p.stderr, (args, p.stderr)
        assert "Traceback" not in p.stderr and len(p.stderr.strip().splitlines()) == 1, p.stderr
    assert not (tmp_path / "cache").exists()


def test_on_worker_processes_the_verdicts_are_the_same(tmp_path, changed_here):
    here, there = changed_here, minirt(*CHANGED, "--workers", "2", cwd=tmp_path)
    assert here.returncode == there.returncode == 1, there.stderr
    a, b = (backends_of(json.loads(p.stdout))["rules"] for p in (here, there))
    for key in ("verdict", "reason", "geometry", "shading"):
        assert a[key] == b[key], key
    assert (
        a["rule_diagnosis"]["rules_explaining"] == b["rule_diagnosis"]["rules_explaining"] == {"pixel_sample": "center"}
    )


def test_a_2014_source_is_compared_under_its_edition_with_the_scene_it_was_given(tmp_path):
    # The 2014 interface passes no rule settings: the program follows the edition's rules, and a check compares
    # it under them (``rules_followed``), as grade --program does. Nor has it a specular colour: the program
    # weights its highlights with the reflection colour (minirt.oracles.program.edition_scene), and the
    # reference it is compared with does the same -- else three_balls' highlights are pixels no rule explains.
    from minirt.model.rules import PROFILES

    shipped = (ROOT / "scenes" / "samples" / "raytracer2014.cpp").read_text()
    # the sample with two of its three bugs mended: only its offset (1e-4 along the ray) is not the edition's
    mended = shipped.replace("#define PIXEL 0.0", "#define PIXEL 0.5").replace(
        "#define FROM_PLANE 1", "#define FROM_PLANE 0"
    )
    assert mended != shipped
    verdicts = {}
    for name, text in (("mended", mended), ("shipped", shipped)):
        (tmp_path / name).mkdir()
        (tmp_path / name / "raytracer.cpp").write_text(text)
        args = ("check", "three_balls", "-b", "program:raytracer.cpp", "--size", SIZE, "-q", "--json", "-")
        p = minirt(*args, cwd=tmp_path / name)
        b = backends_of(json.loads(p.stdout))["three_balls"]
        assert b["rules_followed"] == json.loads(json.dumps(PROFILES["eth2014"].as_dict()))
        assert b["geometry"]["verdict"] == "skip"
        verdicts[name] = (p.returncode, b["shading"]["verdict"])
    # the offset shows on no pixel of this scene; the sample's pixel corners and rays from the image plane do
    assert verdicts == {"mended": (0, "pass"), "shipped": (1, "fail")}


def test_report_takes_a_program_too(tmp_path):
    p = minirt("report", "rules", "-b", program("pixel_sample=center"), "--size", SIZE, "-q", "-o", "rep", cwd=tmp_path)
    assert p.returncode == 1, p.stderr
    html = (tmp_path / "rep" / "index.html").read_text()
    assert "gives only an image" in html and "pixel_sample=center" in html
    b = backends_of(json.loads((tmp_path / "rep" / "report.json").read_text()))["rules"]
    assert b["geometry"]["verdict"] == "skip" and b["shading"]["verdict"] == "fail"


def test_all_and_a_program_in_one_list():
    from minirt.harness.backends import all_names, oracles_among, parse_backends

    names = parse_backends("all,program:python3 t.py {scene},{out}")
    assert names == [*all_names(), "program:python3 t.py {scene},{out}"]  # the program's SPEC keeps its commas
    assert oracles_among(names)[-1] == names[-1] and "reference" not in oracles_among(names)


def test_no_sandbox_here_is_said_in_one_line_before_any_work(tmp_path):
    (tmp_path / "bin").mkdir()  # a PATH without bubblewrap
    env = {"MINIRT_PROGRAM_CACHE": str(tmp_path / "programs"), "PATH": str(tmp_path / "bin")}
    args = ["check", "rules", "-b", program(), "--json", "c.json"]
    p = subprocess.run([*MINIRT, *args], capture_output=True, text=True, cwd=tmp_path, env=env, timeout=600)
    assert p.returncode == 2 and "bubblewrap (bwrap) is not installed" in p.stderr and "--no-sandbox" in p.stderr
    assert "Traceback" not in p.stderr and len(p.stderr.strip().splitlines()) == 1, p.stderr
    assert not (tmp_path / "c.json").exists()


NAN_IMAGE = """\
import sys
w, h = 48, 48
with open(sys.argv[2] + ".pfm", "wb") as f:
    f.write(b"PF\\n%d %d\\n-1.0\\n" % (w, h) + b"\\x00\\x00\\xc0\\x7f" * (3 * w * h))  # every channel NaN
"""


def test_a_nan_image_is_the_programs_error_in_the_same_words_every_run(tmp_path):
    (tmp_path / "nan.py").write_text(NAN_IMAGE)
    args = ["check", "rules", "-b", f"program:{sys.executable} nan.py {{scene}} {{out}}", "--size", SIZE, "-q"]
    reasons = []
    for _ in range(2):
        p = minirt(*args, "--json", "-", cwd=tmp_path)
        assert p.returncode == 2, p.stderr  # a backend's error
        reasons.append(backends_of(json.loads(p.stdout))["rules"]["reason"])
    assert reasons[0] == reasons[1] == "the program's image image.pfm: the image holds NaN or infinite values"
