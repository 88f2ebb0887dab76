"""Bugs seen in real solutions: the rules the diagnosis reads off an image, and the groups it makes of what
no rule explains.

Student images come from tests/support/plain.py (the pure-Python transcription, which follows t_max and
raw_normals_* on its own: p - c and the plane's normal as written, not the fast tracer's code) with
float32-like noise (tests/support/students.py). Acceptance:

- an image made with each new rule is reproduced by ``minirt render --rule ...`` with the rules of the
  diagnosis (the command the grade prints), to within REPRODUCE of its pixels;
- t_max and the offset are found as numbers from the image (29.3 from a cut between 29.28 and 29.31, 0.5/1024
  exactly), not as the nearest value of a list;
- images with bugs the rule table does not have (a shape's diffuse colour, a ball that casts no shadow) get
  groups whose shapes and conditions are where the bug is.
"""

from __future__ import annotations

import math
import shlex
from dataclasses import replace

import numpy as np
import pytest
from support.inproc import minirt
from support.plain import Plain
from support.students import levels_off, noisy, small_scene, student_image

from minirt import diagnose as dg
from minirt.diagnose.search import OFFSET_ROUNDS, Search, simplest
from minirt.grading import grade as grading
from minirt.io.images import read_image_u8, write_image
from minirt.model import bitmap, camera
from minirt.model import rules as R
from minirt.model.scene import Ball

REPRODUCE = 0.002  # as tests/diagnose/test_diagnose.py: pixels more than a level off the render of the rules found


@pytest.fixture(scope="module")
def cache() -> dg.VariantCache:
    return dg.VariantCache()


def _grade(tmp_path, scene, img: np.ndarray, cache) -> grading.Grade:
    path = tmp_path / "student.png"
    write_image(path, img)
    size = (scene.camera.width, scene.camera.height)
    return grading.grade_image(scene, scene.source, path, R.resolve(scene), cache, size_override=size)


def _reproduced_by_cli(tmp_path, g: grading.Grade, img: np.ndarray) -> int:
    """Pixels more than a level off between the image and the PNG of the grade's own reproduce command."""
    args = [*shlex.split(g.reproduce())[1:], "-o", str(tmp_path / "out"), "-q"]
    run = minirt(*args)
    assert run.returncode == 0, run.stderr
    (png,) = (tmp_path / "out").glob("*.png")
    return levels_off(read_image_u8(png), img)


@pytest.mark.parametrize(
    "stem,change",
    [
        ("exercise", {"t_max": 6.5}),
        ("three_balls", {"raw_normals_ball": "shading"}),
        ("three_balls", {"raw_normals_ball": "reflection"}),
        ("three_balls", {"raw_normals_ball": "both"}),
        ("colored_specular", {"raw_normals_plane": "shading"}),  # its plane's normal is written [0, 2, 0]
    ],
    ids=lambda v: v if isinstance(v, str) else ",".join(f"{k}={v}" for k, v in v.items()),
)
def test_new_rules_are_found_and_reproduced_by_render(tmp_path, cache, stem, change):
    scene = small_scene(stem, 64, 64)
    injected = replace(R.resolve(scene), **change)
    img = student_image(scene, injected)
    g = _grade(tmp_path, scene, img, cache)
    d = g.diagnosis
    # named, or (the floor's normal in colored_specular: it reflects nothing, so "shading" and "both" draw the
    # same; a t_max cut between hits far apart) undecided among values that include the injected one
    assert set(d.changed) | set(d.undetermined) == set(change), (d.changed, d.undetermined)
    for name, values in d.undetermined.items():
        truth = getattr(injected, name)
        assert R.format_rule_value(name, truth) in values or any(
            isinstance(v, dict) and v["from"] <= truth <= v["to"] for v in values
        ), (name, values)
    assert d.mismatch_pixels == 0 and d.unexplained == []
    assert _reproduced_by_cli(tmp_path, g, img) <= REPRODUCE * img.shape[0] * img.shape[1]


def test_t_max_is_read_off_the_image(tmp_path, cache):
    """The cut between the farthest hit drawn and the nearest one not drawn, as the simplest number there."""
    scene = small_scene("exercise", 64, 64)
    given = R.resolve(scene)
    img = student_image(scene, replace(given, t_max=6.5))
    d = _grade(tmp_path, scene, img, cache).diagnosis
    sid, t = cache.first_hits(scene, given)
    t_found = d.best.t_max
    kept, dropped = t[(sid >= 0) & (t < 6.5)].max(), t[(sid >= 0) & (t >= 6.5)].min()
    assert kept < t_found <= dropped and t_found == simplest(kept, dropped)
    assert len(repr(t_found)) <= 4  # a number a student writes, not the grid's nor t's own digits


def test_simplest_number_of_an_interval():
    assert simplest(29.28, 29.31) == 29.3
    assert simplest(0.000487, 0.000489) == 0.5 / 1024
    assert simplest(0.0009, 0.0011) == 0.001
    assert simplest(3.0, 3.0) == 3.0  # an empty interval: its end
    for lo, hi in [(1e-7, 2e-7), (0.123, 0.1231), (5.0, 5.5), (100.0, 1e4)]:
        x = simplest(lo, hi)
        assert lo < x <= hi


@pytest.mark.slow
def test_offset_found_as_the_number_written(tmp_path, cache):
    """0.5 / 1024 (an offset in pixel units divided by the width) comes out as 0.00048828125: the pixels of
    a 200² image pin it to within 0.1 %, where the nearest value of the old list (1e-3) is 2x off."""
    scene = small_scene("three_balls", 200, 200)
    img = student_image(scene, replace(R.resolve(scene), offset=0.5 / 1024))
    d = _grade(tmp_path, scene, img, cache).diagnosis
    assert d.changed == {"offset": "0.00048828125"} and d.mismatch_pixels == 0
    (e,) = d.explained
    assert e.interval[0] < 0.5 / 1024 <= e.interval[1] <= e.interval[0] * 1.01  # narrow: named, with its interval


def test_the_offset_search_traces_each_grid_in_one_kernel():
    """The numeric offset is one number searched on a grid of 30 offsets, then narrowed round by round on
    finer grids: each grid is traced together -- one kernel, the offset each ray's data -- not one offset at a
    time (71 traces of one candidate each before)."""
    scene = small_scene("three_balls", 64, 64)
    given = R.resolve(scene)
    img = student_image(scene, replace(given, offset=0.5 / 1024))
    cache = dg.VariantCache(share=False)
    search = Search(scene, dg.Target(img, False, "student"), cache, True)
    groups, many = [], cache._trace_many
    cache._trace_many = lambda s, group, *a, **k: groups.append(group) or many(s, group, *a, **k)
    x = search.best_offset_everywhere(given)
    probes = [g for g in groups if len(g) > 1]
    assert all(r.offset != given.offset for g in probes for r in g)  # they are the search's offsets
    # the grid (its 1e-6 is the given rules' own, rendered already), the bracket's ends, the rounds
    assert len(probes[0]) == 29 and len(probes) <= 2 + OFFSET_ROUNDS, [len(g) for g in groups]
    assert sum(len(g) == 1 for g in groups) <= 2  # the given rules' own render and its float32 twin
    assert x is not None and abs(x - 0.5 / 1024) < 0.25 / 1024  # and it still finds the student's offset


# ---------------------------------------------------------------------------------------------
# Bugs outside the rule table: the groups must name the shapes and the conditions where they show.


class _NoShadowFrom(Plain):
    """A student whose shadow test skips one shape (the loop over the shapes starts at 1, say)."""

    skip = 0
    _closest = False

    def closest(self, o, d):
        self._closest = True
        try:
            return super().closest(o, d)
        finally:
            self._closest = False

    def intersect(self, shape, o, d):
        if not self._closest and shape is self.scene.shapes[self.skip]:
            return math.inf
        return super().intersect(shape, o, d)


def _plain_image(scene, rules, cls=Plain) -> np.ndarray:
    o, d = camera.primary_rays(scene, rules)
    colors = []
    for oo, dd in zip(o, d, strict=True):
        colors.append(cls(scene, rules).trace(tuple(map(float, oo)), tuple(map(float, dd)), scene.max_depth))
    h, w = scene.camera.height, scene.camera.width
    return bitmap.bitmap(noisy(np.array(colors).reshape(h, w, 3)), rules)


def _mistyped_floor(scene) -> tuple[np.ndarray, int]:
    """The exercise's model with the floor's diffuse colour 1.5 times the scene's (a bug outside the table),
    and the floor's index."""
    shapes = list(scene.shapes)
    floor = next(k for k, s in enumerate(shapes) if not isinstance(s, Ball))
    m = shapes[floor].material
    shapes[floor] = replace(shapes[floor], material=replace(m, diffuse=tuple(1.5 * c for c in m.diffuse)))
    return _plain_image(replace(scene, shapes=tuple(shapes)), R.resolve(scene)), floor


def test_a_wrong_diffuse_colour_is_grouped_on_its_shape_where_lit(tmp_path, cache):
    scene = small_scene("exercise", 64, 64)
    img, floor = _mistyped_floor(scene)
    g = _grade(tmp_path, scene, img, cache)
    d = g.diagnosis
    assert d.changed == {}, d.changed
    groups = d.unexplained
    assert sum(u.pixels for u in groups) >= 0.98 * d.mismatch_pixels
    top = groups[0]
    assert top.shapes == [floor] and top.conditions.get("lit") is True, top
    assert top.pixels >= 0.8 * d.mismatch_pixels
    # where the floor is seen in the ball's mirror, the ball's pixels: a group that says so
    ball = 1 - floor
    assert any(u.shapes == [ball] and u.conditions.get("reflects") == floor for u in groups), groups
    doc = g.as_dict()["diagnosis"]["unexplained"]
    assert [u["pixels"] for u in doc] == sorted((u["pixels"] for u in doc), reverse=True)
    assert doc[0]["shapes"] == [floor] and "lit by the light" in doc[0]["sentence"]
    x, y = top.example
    assert top.mask[y, x] and top.mask.sum() == top.pixels


def test_a_ball_that_casts_no_shadow_is_grouped_where_its_shadow_falls(tmp_path, cache):
    scene = small_scene("three_balls", 64, 64)
    rules = R.resolve(scene)
    img = _plain_image(scene, rules, _NoShadowFrom)
    d = _grade(tmp_path, scene, img, cache).diagnosis
    assert d.unexplained, d.changed
    groups = [(u.shapes, u.conditions) for u in d.unexplained]
    # its own dark side, in shadow for the reference (its shadow rays re-enter it), is lit in the image ...
    assert any(0 in s and c.get("lit") is False for s, c in groups), groups
    # ... and so is what the mirror floor and the other balls show of it
    assert any(c.get("reflects") == 0 for s, c in groups), groups
    assert sum(u.pixels for u in d.unexplained) >= 0.98 * d.mismatch_pixels


def test_probe_says_where_the_image_departs(tmp_path, cache):
    """``probe --image`` at a group's example pixel names the term that differs (the diffuse, 1.5x)."""
    scene = small_scene("exercise", 64, 64)
    img, _ = _mistyped_floor(scene)
    g = _grade(tmp_path, scene, img, cache)
    x, y = g.diagnosis.unexplained[0].example
    run = minirt(*shlex.split(g.probe_command(x, y))[1:])
    assert "where it departs: your diffuse term is 1.5 times the reference's" in run.stderr + run.stdout, run
