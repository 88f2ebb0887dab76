"""What grade says must be true of the image's maker (minirt.diagnose.evidence, minirt.diagnose.fit).

Student images come from tests/support/plain.py -- the pure-Python transcription, which follows every rule
on its own code, the bugs of real solutions included -- with float32-like noise (tests/support/students.py).
Bugs outside the rule table are made there too: the image is drawn from a scene whose material differs
from the one graded (a student's own material formula). For single bugs, pairs and a tracer with the bugs
of a real 2013 solution, the diagnosis must be

- precise: no rule named that the maker did not use, none on zero evidence, none that breaks more than
  it explains, every undecided rule with the maker's value among those that fit, and no pixel the scene's
  own rules drew right reported as the student's (``broken_pixels`` counts every such pixel);
- complete: every table bug named (or undecided with its value), every outside-table bug localised to its
  shape and, where the exercise's formula with other colours draws it, fitted with those colours.
"""

from __future__ import annotations

import dataclasses
from dataclasses import replace

import numpy as np
import pytest
from support.students import small_scene, student_image

from minirt import diagnose as dg
from minirt.diagnose import evidence
from minirt.diagnose.search import Search
from minirt.model import rules as R
from minirt.model.scene import Ball, colour_warnings, load_scene


@pytest.fixture(scope="module")
def cache() -> dg.VariantCache:
    return dg.VariantCache()


def _with_material(scene, k: int, **colours):
    """The scene with shape k's material changed: what a student's own material formula draws."""
    shapes = list(scene.shapes)
    shapes[k] = dataclasses.replace(shapes[k], material=dataclasses.replace(shapes[k].material, **colours))
    return dataclasses.replace(scene, shapes=tuple(shapes))


def _diagnose(scene, injected: R.Rules, given: R.Rules, cache, drawn=None) -> dg.Diagnosis:
    img = student_image(drawn or scene, injected)
    return dg.diagnose(scene, given, dg.Target(img, False, "student"), cache)


def _precise(d: dg.Diagnosis, injected: R.Rules) -> None:
    for name, value in d.changed.items():
        assert R.format_rule_value(name, getattr(injected, name)) == value, f"named {name}={value}"
    for name, values in d.undetermined.items():
        truth = getattr(injected, name)
        assert R.format_rule_value(name, truth) in values or any(
            isinstance(v, dict) and v["from"] <= truth <= v["to"] for v in values
        ), (name, values, truth)
    for e in d.explained:
        assert e.pixels > 0 and e.pixels > e.against and e.pixels >= e.neither, e
    # a pixel the scene's own rules drew right that the answer gets wrong is counted, never the student's
    assert int((d.best_mask & ~d.as_given_mask).sum()) == d.broken_pixels


def _localised(d: dg.Diagnosis, k: int) -> None:
    """The unexplained pixels lie on shape k, where it is seen in a reflection, or are a stray edge pixel."""
    assert d.unexplained and d.unexplained[0].shapes == [k], [(g.shapes, g.sentence) for g in d.unexplained]
    for g in d.unexplained[1:]:
        seen = g.conditions.get("reflects") is not None or f"shape {k} is drawn otherwise" in g.sentence
        assert g.shapes == [k] or seen or g.pixels <= 2, (g.shapes, g.sentence)


SINGLE = [
    ("three_balls", None, {"shadow_rays": False}),
    ("three_balls", None, {"ball_normal": "inward"}),
    ("three_balls", None, {"light": "direction"}),
    ("three_balls", None, {"hit_point": "origin"}),
    ("three_balls", None, {"raw_normals_ball": "shading"}),
    ("three_balls", None, {"raw_normals_plane": "shading"}),
    ("rules", "eth2014", {"specular_s": "-s"}),
]
PAIRS = [
    ("three_balls", None, {"shadow_rays": False, "light": "direction"}),
    ("three_balls", None, {"ball_normal": "inward", "hit_point": "origin"}),
    ("three_balls", None, {"pixel_sample": "center", "raw_normals_ball": "reflection"}),
    ("exercise", None, {"light": "direction", "encoding": "floor256"}),
]


@pytest.mark.slow
@pytest.mark.parametrize("stem,profile,change", SINGLE + PAIRS, ids=lambda v: str(v))
def test_table_bugs_named_and_nothing_else(stem, profile, change, cache):
    scene = small_scene(stem, 64, 64)
    given = R.resolve(scene, profile)
    injected = replace(given, **change)
    d = _diagnose(scene, injected, given, cache)
    _precise(d, injected)
    assert set(d.changed) | set(d.undetermined) == set(change), (d.changed, d.undetermined)
    assert d.mismatch_pixels == 0 and d.broken_pixels == 0


@pytest.mark.slow
def test_an_unnormalised_plane_is_not_blamed_on_the_balls(cache):
    """A plane's normal used as written, balls right: only the plane's rule is named -- not raw normals for
    balls too, no exponent with zero evidence, and no pixel on a ball left as the student's."""
    scene = small_scene("three_balls", 64, 64)
    given = R.resolve(scene)
    injected = replace(given, raw_normals_plane="both")
    d = _diagnose(scene, injected, given, cache)
    _precise(d, injected)
    assert "raw_normals_ball" not in d.changed and "specular_exponent" not in d.changed
    assert "raw_normals_plane" in d.changed or "raw_normals_plane" in d.undetermined
    assert d.mismatch_pixels == 0


@pytest.mark.slow
def test_a_real_2013_solution(cache):
    """The bugs of a 2013 solution: no shadow test at all, the light's position as a direction, inward ball
    normals, the hit point as t·d, and a material formula that gives a negative diffuse colour (outside the
    table). The table's four are named and nothing else; the rest lies on that ball alone and is fitted with
    the colour the student's formula gave."""
    scene = small_scene("three_balls", 64, 64)
    given = R.resolve(scene)
    bugs = {"shadow_rays": False, "light": "direction", "ball_normal": "inward", "hit_point": "origin"}
    injected = replace(given, **bugs)
    red = scene.shapes[0].material
    wrong = (red.diffuse[0] * 1.5, -0.3, red.diffuse[2])
    d = _diagnose(scene, injected, given, cache, drawn=_with_material(scene, 0, diffuse=wrong))
    _precise(d, injected)
    assert set(d.changed) | set(d.undetermined) == set(bugs), (d.changed, d.undetermined)
    _localised(d, 0)
    fitted = [g.fit for g in d.unexplained if g.fit is not None and g.fit.reproduces]
    assert fitted, [g.fit.sentence for g in d.unexplained if g.fit]
    for f in fitted:
        (s,) = f.shapes
        assert np.allclose(s.parameters["diffuse"], wrong, atol=0.02), s.parameters
        assert "ball 0" in s.sentence and "diffuse" in s.sentence


@pytest.mark.slow
def test_an_outside_table_colour_is_fitted(cache):
    """A shape's diffuse colour 1.5 times the scene's (a bug no rule has): localised to that shape, fitted."""
    scene = small_scene("three_balls", 64, 64)
    given = R.resolve(scene)
    k = next(i for i, s in enumerate(scene.shapes) if isinstance(s, Ball))
    diffuse = tuple(1.5 * c for c in scene.shapes[k].material.diffuse)
    d = _diagnose(scene, given, given, cache, drawn=_with_material(scene, k, diffuse=diffuse))
    assert d.changed == {} and d.undetermined == {}
    _localised(d, k)
    for g in d.unexplained:
        if g.shapes != [k]:
            continue
        assert g.fit is not None and g.fit.reproduces, g.fit.sentence
        (s,) = g.fit.shapes
        assert np.allclose(s.parameters["diffuse"], diffuse, atol=0.02), s.parameters
        assert g.fit.as_dict()["parameters"][str(k)]["light"] == "position"


def test_a_rule_without_evidence_is_put_back(cache):
    """A rule set with one rule the image does not show: leave-one-out finds no pixel for it, puts it back
    and lists it as rejected."""
    scene = small_scene("rules", 48, 48)
    given = R.resolve(scene)
    img = student_image(scene, given)
    search = Search(scene, dg.Target(img, False, "student"), cache, True)
    claimed = replace(given, two_sided=True)
    best, found, rejected = evidence.confirm(search, given, claimed)
    assert best == given and found == []
    (r,) = rejected
    assert r.rule == "two_sided" and r.pixels == 0 and r.against > 0


@pytest.mark.slow
def test_one_of_where_the_image_cannot_decide(cache):
    """An offset of 1e-4 along the ray and one along the normal fit this image equally: neither is named;
    both rules are undecided, the student's value among those listed."""
    scene = small_scene("rules", 64, 64)
    given = R.resolve(scene)
    injected = replace(given, offset=1e-4, offset_along="ray")
    d = _diagnose(scene, injected, given, cache)
    _precise(d, injected)
    assert "offset" not in d.changed or "offset_along" in d.changed
    if d.undetermined:
        assert d.one_of is not None and "grade your program" in d.one_of.sentence


def test_negative_material_colours_load_with_a_warning(tmp_path):
    path = tmp_path / "neg.toml"
    path.write_text(
        "[camera]\ndistance = 2.0\nwidth = 8\nheight = 8\n[light]\nposition = [1.0, 1.0, -1.0]\n"
        '[materials.m]\ndiffuse = [0.1, -0.9, -0.9]\n[[shapes]]\ntype = "ball"\ncenter = [0.0, 0.0, 3.0]\n'
        'radius = 1.0\nmaterial = "m"\n'
    )
    scene = load_scene(path)
    assert scene.shapes[0].material.diffuse == (0.1, -0.9, -0.9)
    (line,) = colour_warnings(scene)
    assert "'m'" in line and "negative" in line and "-0.9" in line


@pytest.mark.slow
def test_one_diagnosis_for_several_images(cache):
    """A program's images weighed together (minirt.diagnose.joint): a rule one scene cannot show (the rules
    scene's planes are of unit length) is named from the scene that shows it, with nothing else."""
    injected_changes = {"raw_normals_plane": "shading", "pixel_sample": "center"}
    items = []
    for stem in ("rules", "three_balls"):
        scene = small_scene(stem, 48, 48)
        given = R.resolve(scene)
        items.append((scene, given, dg.Target(student_image(scene, replace(given, **injected_changes)), False, stem)))
    j = dg.diagnose_joint(items, cache)
    assert j.rules == {"raw_normals_plane": "shading", "pixel_sample": "center"}, (j.rules, j.undetermined)
    assert j.undetermined == {} and j.mismatch_pixels == 0 and j.broken_pixels == 0
    (e,) = [e for e in j.explained if e["rule"] == "raw_normals_plane"]
    assert e["per_scene"]["rules"] == 0 and e["per_scene"]["three_balls"] > 0
