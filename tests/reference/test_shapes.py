"""Intersections (minirt.reference.shapes, through the tracer): the problem set's own test (b), misses, rays
from inside, planes from both sides."""

from __future__ import annotations

import dataclasses
import math

import drjit as dr
import numpy as np
import pytest
from support.scenes import ball, material, plane, scene_text

from minirt.model.rules import PROFILES
from minirt.model.scene import parse_scene
from minirt.reference.tracer import Tracer

BALL = ball((0.0, 0.0, 0.0), 1.0)
PLANE = plane((0.0, 0.0, -1.0), -2.0)


def _scene_text(shapes: str) -> str:
    """The problem set's scene (b): the camera 3 from the image plane, one white material."""
    return scene_text(shapes, distance=3.0, materials={"m": material(1.0)})


def _trace(shapes: str, o, d, profile="exercise", precision="f64"):
    scene = parse_scene(_scene_text(shapes))
    tr = Tracer(scene, PROFILES[profile], precision=precision)
    o = np.atleast_2d(np.array(o, dtype=float))
    d = np.atleast_2d(np.array(d, dtype=float))
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    _, levels = tr.trace(tr.load(o), tr.load(d))
    lvl = levels[0]
    dr.eval(lvl.shape_id, lvl.t, lvl.n)  # one kernel (trace leaves them lazy)
    ids = np.asarray(lvl.shape_id)
    t = np.asarray(lvl.t, dtype=float)
    # a component the same for every ray (one plane's normal) may be one constant: width 1
    n = np.stack([np.broadcast_to(np.asarray(lvl.n[i], dtype=float), t.shape) for i in range(3)], axis=1)
    return ids, t, n


@pytest.mark.parametrize("precision", ["f64", "f32"])
def test_problem_set_b(precision):
    """Ball at (0,0,0) radius 1, ray from (0,0,-3) along +z: t = 2, normal (0,0,-1)."""
    ids, t, n = _trace(BALL, [0, 0, -3], [0, 0, 1], precision=precision)
    assert ids[0] == 0
    assert t[0] == 2.0
    assert n[0].tolist() == [0.0, 0.0, -1.0]


@pytest.mark.parametrize("profile", list(PROFILES))
def test_misses(profile):
    ids, t, _ = _trace(
        BALL,
        [[0, 0, -3], [0, 2, -3], [0, 0, 3], [0, 1.0000001, -3]],
        [[0, 1, 0], [0, 0, 1], [0, 0, 1], [0, 0, 1]],
        profile,
    )
    assert ids.tolist() == [-1, -1, -1, -1]  # sideways, above, behind (pointing away), just past the top
    assert np.all(np.isinf(t))


def test_tangent_is_decided_without_nan():
    ids, t, _ = _trace(BALL, [0, 1, -3], [0, 0, 1])
    assert ids[0] in (0, -1) and not np.isnan(t[0])


def test_inside_ball_exercise_sees_nothing():
    """Exercise: only the near root counts, and from inside it lies behind the ray."""
    ids, t, _ = _trace(BALL, [0, 0, 0], [0, 0, 1], "exercise")
    assert ids[0] == -1 and math.isinf(t[0])


def test_inside_ball_conventional_sees_far_side():
    ids, t, n = _trace(BALL, [0, 0, 0.5], [0, 0, 1], "conventional")
    assert ids[0] == 0 and t[0] == pytest.approx(0.5, abs=1e-15)
    assert n[0].tolist() == [0.0, 0.0, 1.0]  # the buffer holds the shape's own (outward) normal


@pytest.mark.parametrize("profile", list(PROFILES))
def test_plane_from_both_sides(profile):
    ids, t, n = _trace(PLANE, [[0, 0, -3], [0, 0, 5]], [[0, 0, 1], [0, 0, -1]], profile)
    assert ids.tolist() == [0, 0]
    assert t.tolist() == [5.0, 3.0]  # the plane is z = 2
    assert n[0].tolist() == n[1].tolist() == [0.0, 0.0, -1.0]


@pytest.mark.parametrize("d", [[1, 0, 0], [0, 1, 0], [1, 1, 0], [1, 5e-324, 0]])
def test_plane_parallel_rays_miss(d):
    ids, t, _ = _trace(PLANE, [0, 0, -3], d)
    assert ids[0] == -1 and math.isinf(t[0])


def test_plane_through_origin_of_ray_is_not_hit():
    ids, _, _ = _trace(PLANE, [0, 0, 2], [0, 0, 1])  # the ray starts on the plane: t = 0 is not > 0
    assert ids[0] == -1


def test_ties_go_to_lower_id():
    two = BALL + BALL.replace("radius = 1.0", "radius = 1.0")
    ids, _, _ = _trace(two, [0, 0, -3], [0, 0, 1])
    assert ids[0] == 0


@pytest.mark.parametrize("near_root_only", [True, False])
@pytest.mark.parametrize("precision", ["f64", "f32"])
def test_shadow_predicate_decides_as_the_distance(near_root_only, precision):
    """occludes_ball (signs only, used for shadow rays under shadow_range = "any") against
    intersect_ball < inf, on rays built to sit on every boundary the signs decide: origins on, just
    inside and just outside the surface (one ulp and 1e-6 off), at the centre, far away; directions
    grazing (tangent), through the centre, away from it, and random. Any disagreement is a bug."""
    import drjit as dr

    rng = np.random.default_rng(7)
    rules = dataclasses.replace(PROFILES["exercise"], near_root_only=near_root_only)
    scene = parse_scene(_scene_text(BALL.replace("radius = 1.0", "radius = 0.75")))
    tr = Tracer(scene, rules, precision=precision)
    ball = scene.shapes[0]
    dirs = rng.normal(size=(4000, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    radial = rng.normal(size=(4000, 3))
    radial /= np.linalg.norm(radial, axis=1, keepdims=True)
    scale = np.array([0.0, 0.75, np.nextafter(0.75, 0), np.nextafter(0.75, 1), 0.75 - 1e-6, 0.75 + 1e-6, 5.0, 1e3])
    o = radial * scale[rng.integers(0, len(scale), 4000)][:, None]
    # a quarter of the rays: tangent to the ball at the origin's radius, or straight in/out
    tangent = np.cross(radial, rng.normal(size=(4000, 3)))
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    kind = rng.integers(0, 4, 4000)
    d = np.where((kind == 0)[:, None], tangent, np.where((kind == 1)[:, None], -radial,
                 np.where((kind == 2)[:, None], radial, dirs)))  # fmt: skip
    orig, dirn = tr.load(o), tr.load(d)
    with dr.scoped_set_flag(dr.JitFlag.FastMath, False):
        by_t = np.asarray(tr.intersect_ball(ball, orig, dirn) < math.inf)
        by_sign = np.asarray(tr.occludes_ball(ball, orig, dirn))
    assert 0.1 < by_t.mean() < 0.9  # both outcomes well represented (17% hits when inside origins never hit)
    bad = np.flatnonzero(by_t != by_sign)
    assert bad.size == 0, (o[bad[:3]], d[bad[:3]])
