"""Grading a program: a NumPy tracer of the exercise (tests/support/numpy_tracer.py, no minirt inside) run
as a student's program with known rule changes, and a C++ solution of the 2014 edition compiled through
minirt's driver. The exercise itself must match on every scene; each change must be named, and nothing
else."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
from support.programs import grading_suite, program_cache  # noqa: F401 (program_cache: a fixture)

from minirt.grading import program as gp
from minirt.model.rules import PROFILES
from minirt.oracles.program import make_spec

ROOT = Path(__file__).resolve().parents[2]
TRACER = ROOT / "tests" / "support" / "numpy_tracer.py"
SAMPLE_2014 = ROOT / "scenes" / "samples" / "raytracer2014.cpp"
SIZE = 64  # every rule below shows on hundreds of pixels of the grading set at 64^2


def suite(stems=("rules", "three_balls", "exercise"), rules=None):
    return grading_suite(stems, SIZE, rules)


def numpy_program(*changes: str, fmt: str = "pfm") -> str:
    rules = " ".join(f"--rule {c}" for c in changes)
    return f"{sys.executable} {TRACER} --format {fmt} {rules} {{scene}} {{out}}"


def test_the_exercise_matches_on_every_scene():
    g = gp.grade_program(make_spec(numpy_program()), suite())
    assert [s.verdict for s in g.scenes] == ["match"] * 3, [s.as_dict() for s in g.scenes]
    assert g.verdict == "match" and g.diagnosis.rules == {} and g.exit_code == 0
    assert all(s.target.is_float for s in g.scenes)


def test_an_8bit_image_is_read_too():
    g = gp.grade_program(make_spec(numpy_program(fmt="ppm")), suite(("rules",)))
    assert g.scenes[0].verdict == "match" and not g.scenes[0].target.is_float


@pytest.mark.parametrize(
    "changes",
    [
        {"pixel_sample": "center"},
        {"ray_origin": "camera", "specular_exponent": "16"},
        {"background": "on-miss"},
        {"shadow_range": "to-light", "two_sided": "true"},
    ],
)
def test_known_rule_changes_are_named_and_nothing_else(changes):
    g = gp.grade_program(make_spec(numpy_program(*(f"{k}={v}" for k, v in changes.items()))), suite())
    assert g.verdict == "differs"
    assert g.diagnosis.rules == changes
    assert g.diagnosis.undetermined == {} and g.diagnosis.mismatch_pixels == 0
    doc = g.as_dict()
    assert [s["scene"] for s in doc["scenes"]] == ["rules", "three_balls", "exercise"]
    assert all(s["error"] == "" and s["mismatch_pixels"] == 0 for s in doc["scenes"])
    assert doc["program"]["kind"] == "command" and doc["program"]["compile"] is None


def _solution_2014(tmp_path: Path, offset="1e-3", pixel="0.5", from_plane="0") -> Path:
    text = SAMPLE_2014.read_text()
    for name, value in (("OFFSET", offset), ("PIXEL", pixel), ("FROM_PLANE", from_plane)):
        start = text.index(f"#define {name} ")
        end = text.index("\n", start)
        text = text[:start] + f"#define {name} {value}" + text[end:]
    path = tmp_path / "raytracer.cpp"
    path.write_text(text)
    return path


def test_a_correct_2014_solution_matches_the_edition(tmp_path):
    spec = make_spec(str(_solution_2014(tmp_path)))
    assert (spec.kind, spec.edition) == ("cpp", "2014")
    rules = PROFILES["eth2014"]
    g = gp.grade_program(spec, suite(rules=rules))
    assert g.compile["ok"], g.compile["message"]
    assert [s.verdict for s in g.scenes] == ["match"] * 3, [s.as_dict() for s in g.scenes]


def test_the_2014_sample_has_its_primary_ray_bugs_named(tmp_path):
    g = gp.grade_program(make_spec(str(SAMPLE_2014)), suite(rules=PROFILES["eth2014"]))
    assert g.diagnosis.rules == {"pixel_sample": "corner", "ray_origin": "image-plane"}
    assert g.diagnosis.mismatch_pixels == 0
    assert g.as_dict()["program"]["edition"] == "2014"


SAMPLE_2013 = ROOT / "scenes" / "samples" / "raytracer2013.cpp"
ADAPTER_2013 = ROOT / "scenes" / "samples" / "adapter2013.cpp"


def test_a_2013_solution_through_the_adapter_matches_and_its_change_is_named(tmp_path):
    spec = make_spec(str(SAMPLE_2013), adapter=ADAPTER_2013)
    assert (spec.kind, spec.edition) == ("cpp", "2013")
    g = gp.grade_program(spec, suite())
    assert g.compile["ok"], g.compile["message"]
    assert [s.verdict for s in g.scenes] == ["match"] * 3, [s.as_dict() for s in g.scenes]
    changed = tmp_path / "raytracer.cpp"
    changed.write_text(SAMPLE_2013.read_text().replace("r * shadow.dir, 8)", "r * shadow.dir, 16)"))
    g = gp.grade_program(make_spec(str(changed), adapter=ADAPTER_2013), suite())
    assert g.diagnosis.rules == {"specular_exponent": "16"} and g.diagnosis.mismatch_pixels == 0
