"""Warnings about scenes whose image depends on rounding or scale (minirt.reference.hazards): an offset below the hit
points' rounding (acne), an offset larger than a gap it jumps (near contacts), coordinates float32 cannot
hold to the scene's detail. `render` and `check` print one line each on stderr; `probe` explains a pixel."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from support import inproc
from support.scenes import ball, material, plane, scene_text, write_scene

from minirt.model.rules import resolve
from minirt.model.scene import Ball, Plane, parse_scene
from minirt.reference import hazards
from minirt.reference.tracer import render

ROOT = Path(__file__).resolve().parents[2]


_MATTE = material((0.7, 0.6, 0.5), ambient=0.1)


def _scene(*shapes: str, light=(0.0, 0.0, -1.0)) -> str:
    """16x16, no reflections, one matte material "m"."""
    return scene_text(*shapes, size=16, light=light, render={"max_depth": 0}, materials={"m": _MATTE})


_WALL = plane((0.0, 0.0, 1.0), 3.0)
# The exercise's normals are as given: this wall's points away from the camera, so the 1e-6 offset goes
# behind it, across a second plane 5e-7 behind (a near contact); 0.1 behind, nothing is jumped.
DECAL = _scene(_WALL, plane((0.0, 0.0, 1.0), 3.0000005))
APART = _scene(_WALL, plane((0.0, 0.0, 1.0), 3.1))
# A ground of radius 1e8 under y = -1: float32 rounds its centre's -1e8 - 1 to -1e8 (the ground's top to y = 0)
PLANET = _scene(ball((0.0, 0.0, 3.0), 1.0), ball((0.0, -100000001.0, 0.0), 100000000.0), light=(2.0, 3.0, -1.0))


def minirt(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return inproc.minirt(*args, cwd=cwd)  # in this process: the command's exit status and streams


def warnings(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if line.startswith("minirt: warning: ")]


def test_an_offset_jumping_a_near_contact_is_counted_per_pixel():
    for text, expected in ((DECAL, 256), (APART, 0)):
        sc = parse_scene(text)
        rules = resolve(sc)
        lines = hazards.offset_warnings(sc, rules, render(sc, rules))
        assert len(lines) == (1 if expected else 0), lines
        if expected:
            assert f"jumps over another shape's surface on {expected} pixel(s)" in lines[0]


def test_an_offset_below_the_hit_points_rounding_is_counted_in_float32_only():
    sc = parse_scene((ROOT / "scenes" / "three_balls.toml").read_text()).with_overrides(width=64, height=64)
    rules = resolve(sc)  # the exercise's 1e-6 along the normal
    f32 = hazards.offset_warnings(sc, rules, render(sc, rules, precision="f32"), "f32")
    assert len(f32) == 1 and "below the hit point's float32 rounding" in f32[0]
    n = int(f32[0].split(" on ")[1].split(" pixel")[0])
    assert 0 < n < 64 * 64  # the far floor (|p| in the hundreds), not the balls near the camera
    assert hazards.offset_warnings(sc, rules, render(sc, rules), "f64") == []
    eb = resolve(sc, None, {"offset": "error-bound"})
    assert hazards.offset_warnings(sc, eb, render(sc, eb, precision="f32"), "f32") == []


def test_float32_names_the_key_it_cannot_hold():
    sc = parse_scene(PLANET)
    lines = hazards.float32_warnings(sc)
    assert len(lines) == 1
    assert lines[0].startswith("shapes[1].center[1] = -100000001.0 is -100000000.0 in float32 (moved by 1,")
    assert hazards.float32_warnings(parse_scene(DECAL)) == []  # 3.0000005 moves by 2e-8: far below the detail


def test_render_and_check_warn_one_line_each(tmp_path):
    decal, planet = write_scene(tmp_path, "decal", DECAL), write_scene(tmp_path, "planet", PLANET)
    r = minirt("render", str(decal), "--out", str(tmp_path / "r1"), "-q", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert warnings(r.stderr) == [
        "minirt: warning: decal: offset 1e-06 (along the normal) jumps over another shape's surface on 256 pixel(s) "
        "(a near contact closer than the offset): their shadow or reflection rays start beyond it and miss it"
    ]
    r = minirt("render", str(planet), "--precision", "f32", "--out", str(tmp_path / "r2"), "-q", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    got = warnings(r.stderr)
    assert (
        len(got) == 1 and "planet: shapes[1].center[1] = -100000001.0 is -100000000.0 in float32 (reference)" in got[0]
    )
    r = minirt("render", str(planet), "--out", str(tmp_path / "r3"), "-q", cwd=tmp_path)
    assert warnings(r.stderr) == []  # float64 holds it
    r = minirt("check", str(planet), str(decal), "--backend", "embree", "-q", cwd=tmp_path)
    assert r.returncode == 0, r.stdout + r.stderr
    got = warnings(r.stderr)
    assert len(got) == 2, got
    assert "planet: shapes[1].center[1]" in got[0] and "float32 (embree)" in got[0]
    assert "decal: offset 1e-06" in got[1] and "on 256 pixel(s)" in got[1]


def test_probe_explains_the_offset_at_a_pixel(tmp_path):
    decal = write_scene(tmp_path, "decal", DECAL)
    r = minirt("probe", str(decal), "8", "8", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "offset 1e-06 along the normal: the shadow ray's origin jumps over shape 1's surface, 5e-07" in r.stdout
    r = minirt("probe", str(decal), "8", "8", "--json", cwd=tmp_path)
    off = json.loads(r.stdout)["offset"]
    assert off["jumps"] == [{"ray": "shadow", "shape": 1, "gap": off["jumps"][0]["gap"]}]
    assert abs(off["jumps"][0]["gap"] - 5e-7) < 1e-12 and off["below_rounding"] is False
    # three_balls in float32: at the far floor's horizon (|p| ~ 640) the point's rounding exceeds 1e-6
    far = minirt("probe", "three_balls", "1", "129", "--precision", "f32", cwd=tmp_path)
    assert "offset 1e-06 along the normal: below the hit point's rounding 3.8e-05" in far.stdout
    assert "(acne risk)" in far.stdout
    near = minirt("probe", "three_balls", "128", "120", "--precision", "f32", cwd=tmp_path)
    assert "offset 1e-06 along the normal (the hit point's rounding is 3.5e-07: safe)" in near.stdout


def _brute_jumped(shapes, p, q, sid):
    """The definition _jumped must match: every shape but the point's own, sign of its implicit function at
    both ends of the segment."""
    out = np.zeros(len(p), dtype=bool)
    with np.errstate(invalid="ignore"):
        for k, shape in enumerate(shapes):
            crossed = np.sign(hazards._surface(shape, p)) != np.sign(hazards._surface(shape, q))
            out |= (sid != k) & crossed
    return out


def _surface_points(rng, shapes, sid, on_plane) -> tuple[np.ndarray, np.ndarray]:
    """A random point on each shape ``sid`` names (``on_plane()`` for a plane's) and a random unit direction."""
    p = np.empty((sid.size, 3))
    for i, k in enumerate(sid):
        s = shapes[k]
        if isinstance(s, Ball):
            u = rng.normal(size=3)
            p[i] = np.asarray(s.center) + s.radius * u / np.linalg.norm(u)
        else:
            p[i] = on_plane()
    v = rng.normal(size=(sid.size, 3))
    return p, v / np.linalg.norm(v, axis=1, keepdims=True)


@pytest.mark.parametrize("seed", range(6))
def test_the_bvh_finds_the_same_jumps_as_testing_every_shape(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 300))
    center = rng.uniform(-5, 5, (n, 3)) * 10.0 ** rng.integers(-2, 4)
    radius = np.exp(rng.normal(-1, 1.5, n))
    # near contacts: ball k + 1 touches ball k from outside, with gaps 1e-9 ... 1e-3
    for k in range(0, n - 1, 4):
        u = rng.normal(size=3)
        u /= np.linalg.norm(u)
        center[k + 1] = center[k] + u * (radius[k] + radius[k + 1] + 10.0 ** rng.uniform(-9, -3))
    shapes = [Ball(tuple(c), float(r), None) for c, r in zip(center, radius, strict=True)]
    shapes.append(Ball((0.0, -1e8 - 1.0, 0.0), 1e8, None))  # a planet-sized ground
    shapes.append(Plane((0.0, 0.0, 1.0), 2.0, None))
    m = 20_000
    sid = rng.integers(0, len(shapes), m)
    p, v = _surface_points(rng, shapes, sid, lambda: (*rng.uniform(-50, 50, 2), 2.0))
    q = p + 10.0 ** rng.uniform(-9, 1, (m, 1)) * v
    got = hazards._jumped(SimpleNamespace(shapes=shapes), p, q, sid)
    want = _brute_jumped(shapes, p, q, sid)
    assert 0 < want.sum() < m  # the case can fail both ways
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("seed", range(3))
def test_the_screen_by_near_contacts_changes_no_answer(seed):
    # short segments (offsets 1e-9 .. 1e-5) from points on balls with near contacts (gaps 1e-9 .. 1e-3) and on
    # balls far from any: the points of the far ones are left out of the ball test (_near_shapes), and every
    # answer is still the one testing every shape gives
    rng = np.random.default_rng(100 + seed)
    n = int(rng.integers(20, 120))
    center = rng.uniform(-40, 40, (n, 3))
    radius = rng.uniform(0.2, 1.0, n)
    contacts = []
    for k in range(0, n - 1, 6):
        u = rng.normal(size=3)
        u /= np.linalg.norm(u)
        gap = 10.0 ** rng.uniform(-9, -3)
        center[k + 1] = center[k] + u * (radius[k] + radius[k + 1] + gap)
        contacts.append((k, u, gap))
    shapes = [Ball(tuple(c), float(r), None) for c, r in zip(center, radius, strict=True)]
    shapes.append(Plane((0.0, 1.0, 0.0), -41.0, None))
    m = 6_000
    sid = rng.integers(0, len(shapes), m)
    p, v = _surface_points(rng, shapes, sid, lambda: (rng.uniform(-50, 50), -41.0, rng.uniform(-50, 50)))
    q = p + 10.0 ** rng.uniform(-9, -5, (m, 1)) * v
    for i in range(0, 600, 3):  # segments from a contact towards the neighbour, some across its surface
        k, u, gap = contacts[i // 3 % len(contacts)]
        sid[i] = k
        p[i] = center[k] + radius[k] * u
        q[i] = p[i] + gap * rng.uniform(0.5, 2.0) * u
    scene = SimpleNamespace(shapes=shapes)
    near = hazards._near_shapes(scene, p, q, sid, hazards._Balls.of(scene))
    assert near is not None and 0 < near.sum() < 0.6 * m  # the screen leaves most points out
    want = _brute_jumped(shapes, p, q, sid)
    assert want.sum() > 0
    np.testing.assert_array_equal(hazards._jumped(scene, p, q, sid), want)
    assert not (want & ~near).any()  # no point left out could have jumped
