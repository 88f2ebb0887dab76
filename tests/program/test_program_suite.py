"""Programs graded over the whole default suite (minirt.grading.suite): Python programs written here, each
a few lines over a shared model (tests/support/numpy_tracer.py, the exercise in NumPy, nothing of minirt),
each with a known set of rule changes -- singles, pairs, the bugs of real solutions -- must be diagnosed
exactly: the named rules are those changes and nothing else, every image explained, and the only changes
the suite cannot tell apart are those no scene can (each with its reason)."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import pytest
from support.programs import program_cache  # noqa: F401 (a fixture: the module's C++ builds in a folder of its own)

from minirt import diagnose as dg
from minirt.grading import program as gp
from minirt.grading import suite as sm
from minirt.model.rules import PROFILES, resolve
from minirt.model.scene import load_scene
from minirt.oracles.program import make_spec

pytestmark = pytest.mark.slow  # a dozen programs over the whole suite: ~2 minutes

ROOT = Path(__file__).resolve().parents[2]
MODEL = ROOT / "tests" / "support" / "numpy_tracer.py"

PROGRAM = """import sys

import model  # the shared model, beside this file

model.DEFAULTS.update({changes!r})
model.main(sys.argv[1:])
"""

# Under the exercise's rules (clamp false, exponent 8) the sign of s in the highlight never shows:
# (r·(-s))^8 = (r·s)^8 in every scene. It is the one change the suite lists for a program of these rules.
SAME_EVERYWHERE = [("specular_s", "-s")]
# ... and the single changes a change makes impossible to see, or that only a contact shows
MOOT_UNDER = {
    ("shadow_rays", "false"): [("shadow_range", "to-light")],
    ("two_sided", "true"): [("ball_normal", "inward"), ("offset", "error-bound")],
}


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    d = tmp_path_factory.mktemp("programs")
    shutil.copy(MODEL, d / "model.py")
    return d


@pytest.fixture(scope="module")
def suite():
    out = []
    for s in sm.program_suite():
        scene = load_scene(s.path).with_overrides(width=s.size[0], height=s.size[1], samples=1)
        out.append((str(s.path), scene, resolve(scene)))
    return out


@pytest.fixture(scope="module")
def cache():
    return dg.VariantCache(share=False)


def grade(folder: Path, suite, cache, changes: dict[str, str]) -> gp.ProgramGrade:
    name = "_".join(f"{k}-{v}" for k, v in changes.items()).replace(".", "p") or "exercise"
    path = folder / f"{name}.py"
    path.write_text(PROGRAM.format(changes=changes))
    return gp.grade_program(make_spec(f"{sys.executable} {path} {{scene}} {{out}}"), suite, cache=cache)


def test_the_exercise_matches_on_every_scene_of_the_suite(folder, suite, cache):
    g = grade(folder, suite, cache, {})
    assert [s.verdict for s in g.scenes] == ["match"] * len(suite), [s.as_dict() for s in g.scenes]
    assert g.verdict == "match" and g.diagnosis.rules == {}
    assert [(i["rule"], i["value"]) for i in g.diagnosis.indistinguishable] == SAME_EVERYWHERE


@pytest.mark.parametrize(
    "changes",
    [
        {"shadow_rays": "false"},
        {"ball_normal": "inward"},
        {"light": "direction"},
        {"hit_point": "origin"},
        {"offset": "0.0001", "offset_along": "ray"},
        {"offset": "2e-06"},
        {"specular_exponent": "100"},
        {"t_max": "30000.0"},
        {"pixel_sample": "center", "specular_exponent": "16"},
        {"background": "on-miss", "light": "direction"},
        {"two_sided": "true", "near_root_only": "false"},
    ],
    ids=lambda c: ",".join(f"{k}={v}" for k, v in c.items()),
)
def test_known_rule_changes_are_named_exactly(folder, suite, cache, changes):
    g = grade(folder, suite, cache, changes)
    d = g.diagnosis
    assert d.rules == changes, g.as_dict()["diagnosis"]
    assert d.undetermined == {} and d.mismatch_pixels == 0
    same = [(i["rule"], i["value"]) for i in d.indistinguishable]
    # without shadow rays, where one would end cannot matter; with normals facing the ray, neither can the
    # ball normal's sign, and the offset along the normal shows only at contacts: said, each with why
    expected = sorted(SAME_EVERYWHERE + (MOOT_UNDER.get(next(iter(changes.items())), [])))
    assert same == expected, d.indistinguishable
    assert all(i["why"] and i["scene_that_tells"] is None for i in d.indistinguishable)
    doc = g.as_dict()
    assert [s["scene"] for s in doc["scenes"]] == [s.name for s in sm.program_suite()]
    assert all(s["error"] == "" for s in doc["scenes"])


def test_a_clamp_is_named_as_one_of_the_two_values_the_exercise_makes_the_same(folder, suite, cache):
    # clamping the diffuse term (true) or cutting the highlight at r·s <= 0 only ("specular") draw the same
    # pictures whenever secondary rays leave along the normal and anything on the shadow ray blocks
    # (minirt.diagnose.SAME_UNDER_EXERCISE): the suite says the clamp is on, and that it cannot say which
    g = grade(folder, suite, cache, {"clamp": "true"})
    assert g.diagnosis.rules == {} and g.diagnosis.mismatch_pixels == 0
    assert g.diagnosis.undetermined == {"clamp": ["true", "specular"]}
    assert ("clamp", "specular") in [(i["rule"], i["value"]) for i in g.diagnosis.indistinguishable]


# -- the 2014 edition: C++ sources compiled through minirt's driver, graded over the 2014 suite ----------------

BUGS_2014 = ROOT / "tests" / "program" / "data" / "raytracer2014_bugs.cpp"
SAMPLE_2014 = ROOT / "scenes" / "samples" / "raytracer2014.cpp"


# A 2014 program receives every plane with its normal of unit length (the course's Shape reads a plane's
# distance along the unit normal; minirt.oracles.program.edition_scene): whether it normalises a plane's
# normal cannot show. The one thing the 2014 suite cannot tell, with that reason.
SAME_IN_2014 = [("raw_normals_plane", v) for v in ("both", "reflection", "shading")]


@pytest.fixture(scope="module")
def cache_2014():
    return dg.VariantCache(share=False)  # the edition's scenes: apart from the exercise's renders


@pytest.fixture(scope="module")
def suite_2014():
    out = []
    for s in sm.program_suite("2014"):
        scene = load_scene(s.path).with_overrides(width=s.size[0], height=s.size[1], samples=1)
        out.append((str(s.path), scene, PROFILES["eth2014"]))
    return out


def _sample(folder: Path, **defines: str) -> Path:
    """The bundled 2014 sample with some of its bug switches (#define OFFSET, PIXEL, FROM_PLANE) set."""
    text = SAMPLE_2014.read_text()
    for name, value in defines.items():
        start = text.index(f"#define {name} ")
        text = text[:start] + f"#define {name} {value}" + text[text.index("\n", start) :]
    path = folder / "_".join(f"{k}{v}" for k, v in defines.items()).replace(".", "p") / "raytracer.cpp"
    path.parent.mkdir()
    path.write_text(text)
    return path


def test_a_2014_solution_with_four_real_bugs_is_diagnosed_exactly(suite_2014, cache_2014):
    g = gp.grade_program(make_spec(str(BUGS_2014)), suite_2014, cache=cache_2014)
    assert g.compile["ok"], g.compile["message"]
    d = g.diagnosis
    assert d.rules == {
        "offset": "0.0001",
        "ray_origin": "image-plane",
        "pixel_sample": "corner",
        "near_root_only": "true",
    }
    assert d.undetermined == {} and d.mismatch_pixels == 0
    assert [(i["rule"], i["value"]) for i in d.indistinguishable] == SAME_IN_2014
    assert all("unit length" in i["why"] for i in d.indistinguishable)
    doc = g.as_dict()
    assert doc["program"]["edition"] == "2014"
    course = [s for s in doc["scenes"] if s["scene"] in sm.COURSE_2014]
    assert [s["scene"] for s in course] == list(sm.COURSE_2014)
    # pixel corners move every grid point of a shaded surface: the course's own test fails it too
    assert "fail" in {s["course_grid"] for s in course}
    assert all("course_grid" not in s for s in doc["scenes"] if s["scene"] not in sm.COURSE_2014)


def test_the_course_grid_passes_an_offset_of_1e_4_that_the_suite_names(folder, suite_2014, cache_2014):
    # secondary rays 1e-4 along the ray (the edition: 1e-3), primary rays as the edition says: the course's
    # 10x10 grids see nothing wrong, the offset scenes read the offset
    g = gp.grade_program(make_spec(str(_sample(folder, PIXEL="0.5", FROM_PLANE="0"))), suite_2014, cache=cache_2014)
    assert g.diagnosis.rules == {"offset": "0.0001"}
    assert [(i["rule"], i["value"]) for i in g.diagnosis.indistinguishable] == SAME_IN_2014
    assert [s.course_grid for s in g.scenes if s.course] == ["pass"] * len(sm.COURSE_2014)


def test_a_correct_2014_solution_matches_every_scene_and_passes_the_course_grids(folder, suite_2014, cache_2014):
    path = _sample(folder, OFFSET="1e-3", PIXEL="0.5", FROM_PLANE="0")
    g = gp.grade_program(make_spec(str(path)), suite_2014, cache=cache_2014)
    assert g.verdict == "match", [s.as_dict() for s in g.scenes]
    assert [(i["rule"], i["value"]) for i in g.diagnosis.indistinguishable] == SAME_IN_2014
    assert [s.course_grid for s in g.scenes if s.course] == ["pass"] * len(sm.COURSE_2014)
