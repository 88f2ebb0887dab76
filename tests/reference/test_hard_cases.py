"""Hard cases for the reference tracer's numerics: far, huge and tiny balls, grazing and tangent rays,
rays from inside, translated and scaled scenes, ties and extreme inputs.

Each test names the case it guards in its docstring. Criteria:
- t accuracy: backward error k = |Δt| / (ε (max(|o|, |C|) + r)) <= 10 against a 60-digit reference
  computed with `decimal` from the exact float inputs the tracer received (measured: the stable
  forms stay at k <= 10, the textbook form reaches 1e8). ε is the machine epsilon of the precision traced. Near a
  silhouette t is ill-conditioned (dt/dh = h / sqrt(r^2 - h^2) for a ray at distance h from the centre),
  so the denominator carries the factor 1 + h / sqrt(r^2 - h^2): an input perturbation of size k ε S moves
  t by that much, and a backward-stable solver is allowed it (found with a ray 1e-9 r from tangent: k = 29
  without the factor, in float64).
- hit/miss: must be right wherever the exact perpendicular distance from the centre to the ray is
  more than K ε (max(|o|, |C|) + r) from the radius (K = 10); closer than that, a rounding of the
  inputs can flip the decision, and only "no NaN, decided" is asked.
- images: never a NaN for a scene the validator accepts.

Five tracer bugs were found here (NaN at a light on a surface and at a sub-ulp ball, overflow past 1e154,
f32 NaN beyond its range); the tests that found them now guard the fixes.
Images are small (16..64 pixels square) to keep the file fast: every distinct scene compiles its own kernels.
"""

from __future__ import annotations

import math
import re
from dataclasses import replace
from decimal import Decimal, localcontext

import drjit as dr
import numpy as np
import pytest
from support.scenes import ball, material, plane, scene_text

from minirt.errors import MinirtError, SceneError
from minirt.model import camera
from minirt.model.rules import PROFILES, Rules
from minirt.model.scene import Ball, Light, Plane, Scene, load_scene, parse_scene
from minirt.reference.tracer import Tracer

EPS = {"f64": float(np.finfo(np.float64).eps), "f32": float(np.finfo(np.float32).eps)}
NP = {"f64": np.float64, "f32": np.float32}
K_MAX = 10.0
PRECISIONS = ["f64", "f32"]
Vec = tuple[float, float, float]


# ---------------------------------------------------------------------------------------------
# helpers


_MATERIALS = {
    "m": material((0.7, 0.6, 0.5), ambient=0.1, specular=0.5, reflection=0.2),
    "other": material((0.2, 0.9, 0.1), ambient=(0.0, 0.3, 0.0)),
}


def make_scene(
    shapes: str,
    light: Vec = (0.0, 5.0, 0.0),
    distance: float = 2.0,
    size: int = 16,
    profile: str = "exercise",
    max_depth: int = 2,
    light_color: Vec = (1.0, 1.0, 1.0),
) -> Scene:
    """``shapes`` (``ball``, ``plane``) in a size x size image, with two materials, "m" and "other"."""
    render = {"background": (0.1, 0.2, 0.3), "profile": profile, "max_depth": max_depth}
    text = scene_text(
        shapes, distance=distance, size=size, light=light, color=light_color, render=render, materials=_MATERIALS
    )
    return parse_scene(text)


def trace(scene: Scene, rules: Rules, o, d, precision: str = "f64", record: bool = False):
    """Trace custom rays; returns (shape ids, t, colours, levels). d is used as given (not re-normalised)."""
    tr = Tracer(scene, rules, precision=precision)
    o = np.atleast_2d(np.asarray(o, dtype=np.float64))
    d = np.atleast_2d(np.asarray(d, dtype=np.float64))
    c, levels = tr.trace(tr.load(o), tr.load(d), record=record)
    dr.eval(c, levels[0].shape_id, levels[0].t)  # one kernel (without record, trace leaves them lazy)
    ids = np.asarray(levels[0].shape_id)
    t = np.asarray(levels[0].t, dtype=np.float64)
    return ids, t, tr.to_numpy3(c), levels


def unit(v) -> np.ndarray:
    v = np.atleast_2d(np.asarray(v, dtype=np.float64))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def exact_ball(o, d, center, radius) -> tuple[list[Decimal | None], list[Decimal]]:
    """Exact (60 digits) first root t > 0 (None on a miss) and the signed margin r - |perpendicular distance|
    for rays o + t d (any |d|) and a ball, from the float inputs exactly as given."""
    ts, margins = [], []
    with localcontext() as ctx:
        ctx.prec = 60
        C = [Decimal(float(x)) for x in center]
        r = Decimal(float(radius))
        for oi, di in zip(o, d, strict=True):
            f = [Decimal(float(oi[k])) - C[k] for k in range(3)]
            dd = [Decimal(float(di[k])) for k in range(3)]
            a = sum(x * x for x in dd)
            b = sum(f[k] * dd[k] for k in range(3))
            ff = sum(x * x for x in f)
            perp2 = ff - b * b / a
            perp = perp2.sqrt() if perp2 > 0 else Decimal(0)
            margins.append(r - perp)
            disc = b * b - a * (ff - r * r)
            if disc < 0:
                ts.append(None)
                continue
            sq = disc.sqrt()
            t0 = (-b - sq) / a
            ts.append(t0 if t0 > 0 else None)  # the exercise: near root only (origins are outside)
    return ts, margins


def as_precision(a: np.ndarray, precision: str) -> np.ndarray:
    """The values the tracer actually receives (rounded to its precision), back as float64."""
    return np.asarray(a, dtype=np.float64).astype(NP[precision]).astype(np.float64)


def rounded_ball(center, radius, precision: str) -> tuple[tuple[float, ...], float]:
    c = tuple(float(x) for x in as_precision(np.asarray(center), precision))
    return c, float(as_precision(np.asarray([radius]), precision)[0])


def check_ball_rays(o, d, center, radius, precision: str) -> dict[str, float]:
    """Trace rays at one ball; assert hit/miss where decidable and k <= 10 on hits. Returns statistics."""
    o = as_precision(o, precision)
    d = as_precision(d, precision)
    scene = make_scene(ball(center, radius))
    ids, t, _, _ = trace(scene, PROFILES["exercise"], o, d, precision)
    assert not np.isnan(t).any()
    assert set(np.unique(ids).tolist()) <= {-1, 0}
    C, r = rounded_ball(center, radius, precision)
    exact_t, margin = exact_ball(o, d, C, r)
    eps = EPS[precision]
    scale = np.maximum(np.linalg.norm(o, axis=1), np.linalg.norm(C)) + r
    decidable = np.array([abs(float(m)) for m in margin]) > K_MAX * eps * scale
    want_hit = np.array([e is not None for e in exact_t])
    got_hit = ids == 0
    wrong = decidable & (want_hit != got_hit)
    assert not wrong.any(), f"{wrong.sum()} decidable rays classified wrongly, first {np.argwhere(wrong)[0]}"
    both = want_hit & got_hit
    k = np.zeros(len(o))
    for i in np.flatnonzero(both):
        h = r - float(margin[i])  # perpendicular distance of the ray from the centre
        cond = 1 + h / math.sqrt(max(r * r - h * h, 0.0)) if h < r else math.inf
        k[i] = float(abs(Decimal(float(t[i])) - exact_t[i])) / (eps * scale[i] * cond)
    assert np.isfinite(t[got_hit]).all() and (t[got_hit] > 0).all()
    assert k.max() <= K_MAX, f"backward error k = {k.max():.3g} > {K_MAX} (ray {k.argmax()})"
    return {"decidable": float(decidable.mean()), "hits": float(both.sum()), "k_max": float(k.max())}


def far_ball_rays(distance: float, radius: float, n: int, seed: int):
    """n rays from near the origin at a ball on the direction (0.3, 0.2, 1), aimed at points of the
    disc of radius 1.5 r around the centre: about half hit, many graze the silhouette."""
    rng = np.random.default_rng(seed)
    axis = unit([0.3, 0.2, 1.0])[0]
    center = axis * distance
    u = unit(np.cross(axis, [0.0, 1.0, 0.0]))[0]
    v = np.cross(axis, u)
    rho = radius * np.concatenate([rng.uniform(0, 1.5, n - 4), [1.0, 1.0 - 1e-9, 1.0 + 1e-9, 0.0]])
    phi = rng.uniform(0, 2 * np.pi, n)
    target = center + rho[:, None] * (np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v)
    o = rng.uniform(-1, 1, (n, 3))
    return o, unit(target - o), tuple(center), radius


# ---------------------------------------------------------------------------------------------
# small ball far away; huge ball as ground


@pytest.mark.parametrize("precision", PRECISIONS)
@pytest.mark.parametrize("distance", [1e2, 1e8])
def test_small_ball_far_away(distance, precision):
    """Small ball (r = 1) at distance 1e2 and 1e8: the textbook discriminant b'^2 - c cancels
    (measured: 16 % wrong hit/miss at 1e8 in f64). Hit/miss must be right wherever it is decidable and
    t accurate to backward error k <= 10. At 1e8 in float32 nothing is decidable (ε·|C| = 12 > r):
    only "no NaN, t accurate on agreed hits" is asked there."""
    o, d, center, r = far_ball_rays(distance, 1.0, 400, seed=1)
    st = check_ball_rays(o, d, center, r, precision)
    if precision == "f64" or distance < 1e5:
        assert st["decidable"] > 0.9 and st["hits"] > 100  # the test is not vacuous


@pytest.mark.parametrize("precision", PRECISIONS)
def test_huge_ball_ground_t(precision):
    """Huge ball (r = 1e6) used as ground, ray origins 1 above its top: the near root -b' - sqrt(...)
    cancels in the textbook form (f32: 10 % error). k <= 10 against the exact root."""
    rng = np.random.default_rng(2)
    r = 1e6
    center = (0.0, -r - 1.0, 0.0)
    n = 300
    o = np.column_stack([rng.uniform(-1, 1, n), np.zeros(n), rng.uniform(-1, 1, n)])
    d = unit(np.column_stack([rng.uniform(-1, 1, n), -rng.uniform(0.05, 1, n), rng.uniform(-1, 1, n)]))
    st = check_ball_rays(o, d, center, r, precision)
    assert st["hits"] == n  # all rays point down at the ground


def ground_scene(profile: str, size: int = 32) -> Scene:
    # ground: r = 1e6, top at y = -1 (camera 1 above the ground... image plane from y = -0.5 to 0.5)
    return make_scene(ball((0.0, -1e6 - 1.0, 4.0), 1e6), light=(0.0, 100.0, 4.0), size=size, profile=profile)


def lit_fraction_of_ground(scene: Scene, rules: Rules, precision: str) -> tuple[float, int]:
    res = Tracer(scene, rules, precision=precision).render()
    assert np.isfinite(res.color).all()
    ground = res.shape_id == 0
    lit = res.terms["diffuse"].max(axis=-1) > 0
    return float(lit[ground].mean()), int(ground.sum())


@pytest.mark.parametrize("precision", PRECISIONS)
def test_huge_ball_ground_no_acne_conventional(precision):
    """Huge ball as ground, lit from above, nothing else in the scene: every ground pixel must be lit
    (no speckle) in the conventional profile, whose error-bound offset scales with r + |p|."""
    frac, n = lit_fraction_of_ground(ground_scene("conventional"), PROFILES["conventional"], precision)
    assert n > 100
    assert frac == 1.0


def test_huge_ball_ground_exercise_offset():
    """The exercise's fixed offset (1e-6 along the normal) on the r = 1e6 ground. What actually happens:
    the ground is fully lit in float64 *and* float32, although in float32 ulp(1e6) = 0.06 >> 1e-6 puts
    shadow-ray origins inside the ball -- because the exercise's near_root_only rule makes a ball
    invisible from inside (the near root is behind the ray), which hides the acne. With near_root_only
    switched off (the exercise otherwise unchanged) the acne appears in float32 (about 13 % of ground
    pixels dark here) and still not in float64 (the hit point errs by ~ulp(1e6) = 1.2e-10 << 1e-6)."""
    sc = ground_scene("exercise")
    ex = PROFILES["exercise"]
    assert lit_fraction_of_ground(sc, ex, "f64")[0] == 1.0
    assert lit_fraction_of_ground(sc, ex, "f32")[0] == 1.0
    far_root = replace(ex, near_root_only=False)
    assert lit_fraction_of_ground(sc, far_root, "f64")[0] == 1.0
    assert lit_fraction_of_ground(sc, far_root, "f32")[0] < 0.95


# ---------------------------------------------------------------------------------------------
# tangent and grazing rays


@pytest.mark.parametrize("profile", list(PROFILES))
@pytest.mark.parametrize("precision", PRECISIONS)
def test_tangent_and_grazing_rays(profile, precision):
    """Rays exactly tangent to a ball and within a few ulps of tangent, rays grazing a plane: no NaN in
    t or colour, each ray decided (hit with finite t > 0, or miss with t = inf)."""
    shapes = ball((0.0, 0.0, 0.0), 1.0) + plane((0.0, 1.0, 0.0), -1.0)
    sc = make_scene(shapes, light=(3.0, 4.0, -5.0), profile=profile)
    one = 1.0
    ys = [one, np.nextafter(one, 2), np.nextafter(one, 0), 1 + 1e-12, 1 - 1e-12, 1 + 1e-7, 1 - 1e-7]
    o = [[0.0, y, -3.0] for y in ys] + [[x, 0.0, -3.0] for x in ys]
    d = [[0.0, 0.0, 1.0]] * (2 * len(ys))
    # grazing the plane y = -1 from just above it, and rays tangent from the side at a slant
    o += [[0.0, -1.0 + 1e-9, -3.0], [0.0, -1.0 + 1e-15, -3.0], [0.0, -0.5, -3.0]]
    d += list(unit([[0.0, -1e-12, 1.0], [0.0, -1e-17, 1.0], [0.0, -1e-9, 1.0]]))
    a = 1 / math.sqrt(2)
    o += [[-3.0, a, -a - 3.0]]
    d += [[1.0, 0.0, 1.0 / 1.0]]
    d = unit(d)
    ids, t, col, _ = trace(sc, PROFILES[profile], o, d, precision)
    assert not np.isnan(t).any() and np.isfinite(col).all()
    hit = ids >= 0
    assert (np.isfinite(t[hit]) & (t[hit] > 0)).all()
    assert np.isinf(t[~hit]).all()
    # clear cases: 1 + 1e-7 above the top misses, 1 - 1e-7 hits (far beyond rounding in both precisions)
    n = len(ys)
    assert ids[5] == -1 and ids[6] == 0 and ids[n + 5] == -1 and ids[n + 6] == 0


# ---------------------------------------------------------------------------------------------
# camera inside a ball or at its centre


@pytest.mark.parametrize("precision", PRECISIONS)
def test_camera_inside_ball(precision):
    """A ball (r = 5) enclosing the camera (0, 0, -2) and the image plane, light inside it.
    Exercise: only the near root counts, so the enclosing ball is invisible (every pixel misses).
    Conventional: every pixel sees the inside, and every inside point faces the light, so all are lit
    (no acne on a concave surface: the offset goes to the side the shadow ray leaves to)."""
    sc = make_scene(ball((0.0, 0.0, -1.0), 5.0), light=(0.5, 1.0, 1.0), size=24)
    ex = Tracer(sc, PROFILES["exercise"], precision=precision).render()
    assert not ex.hit.any() and np.isfinite(ex.color).all()
    cv = Tracer(sc, PROFILES["conventional"], precision=precision).render()
    assert cv.hit.all() and np.isfinite(cv.color).all() and (cv.t > 0).all()
    assert (cv.terms["diffuse"].max(axis=-1) > 0).all()


@pytest.mark.parametrize("precision", PRECISIONS)
def test_camera_at_ball_centre(precision):
    """Rays starting exactly at a ball's centre (rule ray_origin = "camera", ball centred on the camera):
    f = 0, b = 0, disc = r^2. Exercise: miss (near root -r < 0). Conventional: t = r for every ray."""
    sc = make_scene(ball((0.0, 0.0, -2.0), 3.0), light=(0.5, 1.0, -1.0), size=16)
    for profile in PROFILES:
        rules = replace(PROFILES[profile], ray_origin="camera")
        res = Tracer(sc, rules, precision=precision).render()
        assert np.isfinite(res.color).all()
        if profile == "exercise":
            assert not res.hit.any()
        else:
            assert res.hit.all()
            np.testing.assert_allclose(res.t, 3.0, rtol=4 * EPS[precision])


# ---------------------------------------------------------------------------------------------
# ray origin on a surface; planes: parallel rays, plane through the origin


@pytest.mark.parametrize("precision", PRECISIONS)
def test_ray_origin_exactly_on_ball(precision):
    """Origins exactly on the unit sphere (representable points): outward and tangent rays miss in both
    profiles (t = 0 is not > 0; q = 0 guarded); the inward ray misses in the exercise (its near root is
    the origin itself) and hits the far side at t = 2 in the conventional profile."""
    sc = make_scene(ball((0.0, 0.0, 0.0), 1.0))
    o = [[0.0, 0.0, -1.0]] * 3 + [[1.0, 0.0, 0.0]] * 2
    d = [[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]]
    ids_e, _, col_e, _ = trace(sc, PROFILES["exercise"], o, d, precision)
    ids_c, t_c, col_c, _ = trace(sc, PROFILES["conventional"], o, d, precision)
    assert np.isfinite(col_e).all() and np.isfinite(col_c).all()
    assert ids_e.tolist() == [-1, -1, -1, -1, -1]
    assert ids_c.tolist() == [-1, -1, 0, -1, 0]
    assert t_c[2] == 2.0 and t_c[4] == 2.0


@pytest.mark.parametrize("precision", PRECISIONS)
def test_ray_origin_on_ball_within_rounding(precision):
    """Origins on the unit sphere up to rounding (normalised random points, up to an ulp inside or outside),
    leaving outward: no NaN, and any hit reported is within rounding of the origin (t <= 10 ε) -- never a
    distant false hit. (Secondary rays avoid these self-hits with the offsets tested below.)"""
    rng = np.random.default_rng(3)
    p = as_precision(unit(rng.normal(size=(200, 3))), precision)
    sc = make_scene(ball((0.0, 0.0, 0.0), 1.0))
    for profile in PROFILES:
        ids, t, col, _ = trace(sc, PROFILES[profile], p, p, precision)
        assert not np.isnan(t).any() and np.isfinite(col).all()
        assert (t[ids == 0] <= 10 * EPS[precision]).all()


@pytest.mark.parametrize("precision", PRECISIONS)
def test_ray_parallel_to_plane(precision):
    """Rays parallel to a tilted plane (n·d rounds to 0 or to a tiny non-zero number), and a ray lying in
    the plane (0/0): a miss or a far hit, never a NaN, in t or in the shaded colour."""
    n = unit([1.0, 1.0, 1.0])[0]
    sc = make_scene(plane(n, 1.0), light=(5.0, 5.0, 5.0))
    along = unit([[1.0, -1.0, 0.0], [1.0, 0.0, -1.0], [0.0, 1.0, -1.0], [1.0, 1.0, -2.0]])
    o = np.concatenate([np.zeros((4, 3)), np.tile(n * 1.0, (4, 1))])  # 4 off the plane, 4 on it
    d = np.concatenate([along, along])
    for profile in PROFILES:
        ids, t, col, _ = trace(sc, PROFILES[profile], o, d, precision)
        assert not np.isnan(t).any() and np.isfinite(col).all()
        assert set(ids.tolist()) <= {-1, 0}


@pytest.mark.parametrize("precision", PRECISIONS)
def test_plane_through_ray_origin(precision):
    """A plane through the ray origin (distance 0, origin at 0; and origin on a tilted plane): t = ±0 is not
    > 0, so every ray misses whatever its direction, including the parallel one (0/0 masked)."""
    sc = make_scene(plane((0.0, 0.0, 1.0), 0.0) + plane((1.0, 2.0, 3.0), 0.0))
    d = unit([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1.0, 1.0, 1.0], [1.0, 0.0, 0.0], [-1.0, -2.0, -3.0]])
    for profile in PROFILES:
        ids, t, col, _ = trace(sc, PROFILES[profile], np.zeros((5, 3)), d, precision)
        assert ids.tolist() == [-1] * 5 and np.isinf(t).all() and np.isfinite(col).all()


# ---------------------------------------------------------------------------------------------
# coincident surfaces


@pytest.mark.parametrize("precision", PRECISIONS)
def test_coincident_surfaces_tie_break(precision):
    """Coincident surfaces -- two identical balls, and the same plane written twice with opposite normals --
    with different materials: the lower shape id wins every tie, and two renders are bit-identical."""
    shapes = (
        ball((0.0, 0.0, 4.0), 1.0, "other")
        + ball((0.0, 0.0, 4.0), 1.0, "m")
        + plane((0.0, 1.0, 0.0), -1.0, "other")
        + plane((0.0, -1.0, 0.0), 1.0, "m")
    )
    for profile in PROFILES:
        sc = make_scene(shapes, light=(3.0, 5.0, 0.0), size=32, profile=profile)
        a = Tracer(sc, PROFILES[profile], precision=precision).render()
        b = Tracer(sc, PROFILES[profile], precision=precision).render()
        assert set(np.unique(a.shape_id).tolist()) <= {-1, 0, 2}
        assert (a.shape_id == 0).sum() > 10 and (a.shape_id == 2).sum() > 10
        assert np.array_equal(a.color, b.color) and np.array_equal(a.shape_id, b.shape_id)


# ---------------------------------------------------------------------------------------------
# scene far from the origin; shadow acne across scales (custom rays: the camera is fixed at (0, 0, -d))


def transformed(scene: Scene, scale: float = 1.0, shift=(0.0, 0.0, 0.0)) -> Scene:
    """The scene under x -> scale * x + shift (shapes and light; the rays are transformed by the caller)."""
    s = np.asarray(shift, dtype=np.float64)

    def pt(p) -> tuple[float, float, float]:
        return tuple(float(x) for x in np.asarray(p) * scale + s)

    shapes = []
    for sh in scene.shapes:
        if isinstance(sh, Ball):
            shapes.append(replace(sh, center=pt(sh.center), radius=sh.radius * scale))
        else:
            assert isinstance(sh, Plane)
            shapes.append(replace(sh, distance=sh.distance * scale + float(np.dot(sh.normal, s))))
    return replace(scene, shapes=tuple(shapes), light=Light(pt(scene.light.position), scene.light.color))


THREE = load_scene(__import__("pathlib").Path(__file__).resolve().parents[2] / "scenes" / "three_balls.toml")


def render_transformed(rules: Rules, precision: str, scale: float = 1.0, shift=(0.0, 0.0, 0.0), size: int = 48):
    sc = THREE.with_overrides(width=size, height=size)
    o, d = camera.primary_rays(sc, rules)
    o = o * scale + np.asarray(shift)
    tsc = transformed(sc, scale, shift)
    ids, _, col, levels = trace(tsc, rules, o, d, precision, record=True)
    return tsc, ids, col, levels


def self_shadowed_fraction(scene: Scene, rules: Rules, ids, levels) -> float:
    """Among primary hits whose surface faces the light, the fraction whose shadow ray hits its own shape
    before the light. On a plane or (from outside) a ball that can only be a self-hit: acne."""
    rec = levels[0].record
    ns = np.stack([np.asarray(rec["shading_normal"][i], dtype=np.float64) for i in range(3)], axis=1)
    s = np.stack([np.asarray(rec["shadow_dir"][i], dtype=np.float64) for i in range(3)], axis=1)
    dist = np.asarray(rec["light_dist"], dtype=np.float64)
    facing = (ids >= 0) & (np.einsum("ij,ij->i", ns, s) > 0)
    own = np.full(len(ids), np.inf)
    for k in range(len(scene.shapes)):
        tk = np.asarray(rec["shadow_ts"][k], dtype=np.float64)
        own = np.where(ids == k, tk, own)
    blocked_by_self = facing & (own < dist)
    assert facing.sum() > 100
    return float(blocked_by_self.sum() / facing.sum())


@pytest.mark.parametrize("precision", PRECISIONS)
@pytest.mark.parametrize("scale", [1e-3, 1.0, 1e3])
def test_no_shadow_acne_across_scales(scale, precision):
    """three_balls scaled by 1e-3, 1 and 1e3 (rays scaled with it): with the error-bound offset no lit-facing
    pixel shadows itself, in float64 and float32."""
    rules = PROFILES["conventional"]
    sc, ids, col, levels = render_transformed(rules, precision, scale=scale)
    assert np.isfinite(col).all()
    assert self_shadowed_fraction(sc, rules, ids, levels) == 0.0


def test_fixed_offset_acne_across_scales():
    """The exercise's fixed 1e-6 offset, same scenes: no self-shadowing at scale 1 and 1e-3 in float64... and
    what actually happens elsewhere, pinned down: at scale 1e3 in float32 the hit point's rounding
    (ulp(1e3) = 6e-5) exceeds the offset and shadow rays restart behind the surface (acne); at scale 1e-3
    the offset (1e-6) is comparable to the scene (balls of radius ~5e-4) and skips nothing in float64."""
    rules = PROFILES["exercise"]
    got = {}
    for precision in PRECISIONS:
        for scale in (1e-3, 1.0, 1e3):
            sc, ids, col, levels = render_transformed(rules, precision, scale=scale)
            assert np.isfinite(col).all()
            got[precision, scale] = self_shadowed_fraction(sc, rules, ids, levels)
    assert got["f64", 1.0] == got["f64", 1e-3] == got["f64", 1e3] == 0.0
    assert got["f32", 1e3] > 0.01, got


TRANSLATIONS = {"f64": 1e6, "f32": 1e2}


@pytest.mark.parametrize("precision", PRECISIONS)
def test_scene_far_from_origin_conventional(precision):
    """three_balls translated by (T, T, T) -- T = 1e6 in float64; 1e2 in float32, where ulp(1e6) = 0.06 would
    move the rays' origins by a sixteenth of the image plane and nothing could match -- rendered with
    translated rays: the same image within tolerance in the conventional profile (error-bound offsets).
    Pixels whose rays moved by rounding may flip at silhouettes/shadow edges: at most 1 % of pixels
    may differ by more than 1/255, and the rest must agree to 1e-3."""
    rules = PROFILES["conventional"]
    T = TRANSLATIONS[precision]
    _, _, col0, _ = render_transformed(rules, precision)
    sc, ids1, col1, levels = render_transformed(rules, precision, shift=(T, T, T))
    assert np.isfinite(col1).all()
    diff = np.abs(col1 - col0).max(axis=1)
    assert (diff > 1 / 255).mean() <= 0.01
    assert np.percentile(diff, 95) <= 1e-3
    assert self_shadowed_fraction(sc, rules, ids1, levels) == 0.0


def back_faces_unshadowed(scene: Scene, ids, levels) -> float:
    """Among primary hits on balls facing away from the light, the fraction whose shadow ray misses the ball
    itself. With an offset along the outward normal the shadow ray must re-enter its ball (blocked: the
    back of a ball is in its own shadow); a miss means the origin rounded to inside the ball, where the
    exercise's near_root_only rule sees nothing -- the fixed offset's failure mode in that profile."""
    rec = levels[0].record
    ns = np.stack([np.asarray(rec["shading_normal"][i], dtype=np.float64) for i in range(3)], axis=1)
    s = np.stack([np.asarray(rec["shadow_dir"][i], dtype=np.float64) for i in range(3)], axis=1)
    balls = [k for k, sh in enumerate(scene.shapes) if isinstance(sh, Ball)]
    back = np.isin(ids, balls) & (np.einsum("ij,ij->i", ns, s) < 0)
    own = np.full(len(ids), np.inf)
    for k in balls:
        own = np.where(ids == k, np.asarray(rec["shadow_ts"][k], dtype=np.float64), own)
    assert back.sum() > 20
    return float((back & np.isinf(own)).sum() / back.sum())


def test_scene_far_from_origin_exercise_offset():
    """The same translation with the exercise's fixed 1e-6 offset. What actually happens:
    float64, T = 1e6: ulp(1e6) = 1.2e-10 is below the offset: the image matches (no pixel differs by
    1/255) and no pixel shadows itself.
    float32, T = 1e2: ulp(1e2) = 7.6e-6 exceeds the offset. No acne (near_root_only hides self-hits on
    balls, see test_huge_ball_ground_exercise_offset, and the floor's shadow rays do not re-hit it), but
    the opposite failure: most back-facing ball pixels lose their own shadow (the shadow ray starts inside
    the ball and sees nothing), so the unclamped negative diffuse shows, and > 1 % of pixels change. At
    T = 0 only one terminator pixel (1 of 73) does that."""
    rules = PROFILES["exercise"]
    _, _, c64, _ = render_transformed(rules, "f64")
    sc, ids, t64, lv = render_transformed(rules, "f64", shift=(1e6, 1e6, 1e6))
    assert np.isfinite(t64).all()
    assert (np.abs(t64 - c64).max(axis=1) > 1 / 255).mean() == 0.0
    assert self_shadowed_fraction(sc, rules, ids, lv) == 0.0
    sc0, ids0, c32, lv0 = render_transformed(rules, "f32")
    sc, ids, t32, lv = render_transformed(rules, "f32", shift=(1e2, 1e2, 1e2))
    assert np.isfinite(t32).all()
    assert self_shadowed_fraction(sc, rules, ids, lv) == 0.0
    assert back_faces_unshadowed(sc0, ids0, lv0) < 0.05
    assert back_faces_unshadowed(sc, ids, lv) > 0.3
    assert (np.abs(t32 - c32).max(axis=1) > 1 / 255).mean() > 0.01


# ---------------------------------------------------------------------------------------------
# the light on a surface; NaN / inf / zero / denormal inputs


@pytest.mark.parametrize("precision", PRECISIONS)
@pytest.mark.parametrize("profile", list(PROFILES))
def test_light_on_surface(profile, precision):
    """The light exactly on a surface (on the floor plane and on top of a ball), seen from the camera:
    no NaN anywhere in the image (the centre ray hits neither light position exactly)."""
    shapes = ball((0.3, 0.0, 4.0), 0.5) + plane((0.0, 1.0, 0.0), -1.0)
    for light in ((0.7, -1.0, 3.0), (0.3, 0.5, 4.0)):
        sc = make_scene(shapes, light=light, size=32, profile=profile)
        res = Tracer(sc, PROFILES[profile], precision=precision).render()
        assert np.isfinite(res.color).all()


@pytest.mark.parametrize("precision", PRECISIONS)
@pytest.mark.parametrize("profile", list(PROFILES))
def test_light_exactly_at_a_hit_point(profile, precision):
    """The light exactly on the surface where a primary ray hits (the centre pixel of an even-sized image
    has o = (0, 0, 0), d = (0, 0, 1) exactly): the image must not contain a NaN. (Was a bug: the light
    direction was 0/0; that point is now unlit.)"""
    for shapes, light in (
        (plane((0.0, 0.0, -1.0), -3.0), (0.0, 0.0, 3.0)),
        (ball((0.0, 0.0, 4.0), 0.5), (0.0, 0.0, 3.5)),
    ):
        sc = make_scene(shapes, light=light, profile=profile)
        res = Tracer(sc, PROFILES[profile], precision=precision).render()
        assert res.hit[8, 8]
        assert np.isfinite(res.color).all(), f"NaN at {np.argwhere(~np.isfinite(res.color).all(-1)).tolist()}"


REJECTED = [
    ("radius nan", ball((0, 0, 4), 1).replace("radius = 1.0", "radius = nan")),
    ("radius inf", ball((0, 0, 4), 1).replace("radius = 1.0", "radius = inf")),
    ("radius 0", ball((0, 0, 4), 1).replace("radius = 1.0", "radius = 0.0")),
    ("radius -0", ball((0, 0, 4), 1).replace("radius = 1.0", "radius = -0.0")),
    ("radius negative", ball((0, 0, 4), 1).replace("radius = 1.0", "radius = -1.0")),
    ("center nan", ball((0, 0, 4), 1).replace("4.0]", "nan]")),
    ("center -inf", ball((0, 0, 4), 1).replace("4.0]", "-inf]")),
    ("normal zero", plane((0, 0, 0), 1)),
    ("normal -0", plane((-0.0, 0.0, -0.0), 1)),
    ("normal denormal (|n|^2 underflows)", plane((5e-324, 0, 0), 1)),
    ("normal overflowing |n|", plane((1e200, 1e200, 0), 1)),
    ("normal inf", plane((0, 0, 1), 1).replace("1.0]", "inf]")),
    ("plane distance nan", plane((0, 0, 1), 1).replace("distance = 1.0", "distance = nan")),
]


@pytest.mark.parametrize("what,shapes", REJECTED, ids=[r[0] for r in REJECTED])
def test_invalid_numbers_rejected_at_load(what, shapes):
    """NaN, infinite, zero and negative radii, zero normals (also ones whose length underflows or overflows)
    are rejected by the validator with a SceneError, never traced."""
    with pytest.raises(SceneError):
        make_scene(shapes)


CAMERA_LIGHT_BAD = {
    "camera distance 0": ("distance = 2.0", "distance = 0.0"),
    "camera distance inf": ("distance = 2.0", "distance = inf"),
    "light position nan": ("position = [0.0, 5.0, 0.0]", "position = [0.0, nan, 0.0]"),
    "light colour inf": ("color = [1.0, 1.0, 1.0]", "color = [inf, 1.0, 1.0]"),
    "background negative": ("background = [0.1, 0.2, 0.3]", "background = [-0.1, 0.2, 0.3]"),
}


@pytest.mark.parametrize("what", list(CAMERA_LIGHT_BAD))
def test_invalid_camera_light_rejected(what):
    """NaN, infinite and zero values in the camera, the light and the colours are rejected at load."""
    old, new = CAMERA_LIGHT_BAD[what]
    text = _scene_text(ball((0, 0, 4), 1))
    assert old in text
    parse_scene(text)  # the unmodified scene is valid
    with pytest.raises(SceneError):
        parse_scene(text.replace(old, new, 1))


def _scene_text(shapes: str) -> str:
    return scene_text(
        shapes,
        size=16,
        light=(0.0, 5.0, 0.0),
        color=(1.0, 1.0, 1.0),
        render={"background": (0.1, 0.2, 0.3)},
        materials={"m": material((0.7, 0.6, 0.5))},
    )


# ---------------------------------------------------------------------------------------------
# extreme but valid scenes: never a NaN, never a crash


def _render_centre(shapes: str, profile: str, precision: str, light: Vec = (0.0, 5.0, 0.0), **kw):
    sc = make_scene(shapes, light=light, profile=profile, **kw)
    return Tracer(sc, PROFILES[profile], precision=precision).render()


EXTREME_OK = {
    "plane distance 1e99": plane((0.0, 0.0, -1.0), -1e99),
    "normal with a denormal component": plane((5e-324, 1.0, 0.0), -1.0),
    "ball at 1e99, r 1e98": ball((0.0, 0.0, 1e99), 1e98),
    "denormal centre coordinates": ball((5e-324, -5e-324, 4.0), 0.5),
}

OUT_OF_RANGE = {
    "plane distance 1e300": (plane((0.0, 0.0, -1.0), -1e300), "shapes[0].distance: must be >= -1e+100"),
    "ball at 1e150": (ball((0.0, 0.0, 1e150), 1e149), "shapes[0].center[2]: must be <= 1e+100"),
    "ball at 4e200": (ball((0.0, 0.0, 4e200), 1e200), "shapes[0].center[2]: must be <= 1e+100"),
    "radius 1e-150": (ball((0.0, 0.0, 4.0), 1e-150), "shapes[0].radius: must be >= 1e-100"),
    "radius 5e-324": (ball((0.0, 0.0, 4.0), 5e-324), "shapes[0].radius: must be >= 1e-100"),
    "normal overflowing": (plane((1e100, 1e100, 0.0), 1.0), "shapes[0].normal: must have a length within"),
}


@pytest.mark.parametrize("what", list(OUT_OF_RANGE))
def test_out_of_range_rejected_at_load(what):
    """Geometry beyond 1e-100 .. 1e100 is rejected at load, naming the key: past it, squared lengths
    over- or underflow float64 and a visible ball was silently missed (a ball at 4e200) or set-up
    crashed with an OverflowError (found by this file; fixed by the range check in minirt/model/scene.py)."""
    shapes, message = OUT_OF_RANGE[what]
    with pytest.raises(SceneError, match=re.escape(message)):
        make_scene(shapes)


@pytest.mark.parametrize("profile", list(PROFILES))
@pytest.mark.parametrize("what", list(EXTREME_OK))
def test_extreme_valid_scenes_finite(what, profile):
    """Extreme values the validator accepts (huge and denormal coordinates and radii) render in float64
    without a NaN or inf and without an exception."""
    res = _render_centre(EXTREME_OK[what], profile, "f64")
    assert np.isfinite(res.color).all()


def test_camera_distance_denormal_rejected():
    """Camera distance 5e-324 is rejected at load (the directions' lengths would underflow)."""
    with pytest.raises(SceneError, match=re.escape("camera.distance: must be >= 1e-100")):
        make_scene(plane((0.0, 0.0, -1.0), -3.0), distance=5e-324)


@pytest.mark.parametrize("profile", list(PROFILES))
def test_camera_distance_tiny(profile):
    """Camera distance 1e-99 (valid): every direction is nearly (x, y, 0); the image is finite."""
    res = _render_centre(plane((0.0, 0.0, -1.0), -3.0), profile, "f64", distance=1e-99)
    assert np.isfinite(res.color).all()


@pytest.mark.parametrize("precision", PRECISIONS)
def test_huge_light_colour_no_nan(precision):
    """Light colour 1e300 (valid: colours have no upper bound): float64 stays finite; float32 overflows to
    inf (1e300 is not a float32), which is expected, but never to NaN (inf * 0 would be)."""
    for profile in PROFILES:
        res = _render_centre(ball((0.0, 0.0, 4.0), 0.5), profile, precision, light_color=(1e300, 1e300, 1e300))
        assert not np.isnan(res.color).any()
        if precision == "f64":
            assert np.isfinite(res.color).all()


@pytest.mark.parametrize("radius", [1e-20, 1e-90])
@pytest.mark.parametrize("profile", list(PROFILES))
def test_tiny_ball_hit_through_centre(radius, profile):
    """A ball far smaller than an ulp of its centre (r = 1e-20, 1e-90 at z = 4), centred exactly on the
    centre pixel's ray: the hit point rounds onto the centre, so p - C = 0 has no direction. Was a bug
    (normalize(0) = NaN in the colour); the normal now faces the ray."""
    res = _render_centre(ball((0.0, 0.0, 4.0), radius), profile, "f64")
    assert np.isfinite(res.color).all(), f"non-finite at {np.argwhere(~np.isfinite(res.color).all(-1)).tolist()}"


@pytest.mark.parametrize("profile", list(PROFILES))
def test_tiny_ball_float32(profile):
    """In float32 a radius of 1e-17 (just inside its safe range) behaves the same; 1e-20 is refused
    with a message that says to use float64."""
    res = _render_centre(ball((0.0, 0.0, 4.0), 1e-17), profile, "f32")
    assert np.isfinite(res.color).all()
    with pytest.raises(MinirtError, match="use --precision f64"):
        _render_centre(ball((0.0, 0.0, 4.0), 1e-20), profile, "f32")


@pytest.mark.parametrize("profile", list(PROFILES))
def test_far_ball_is_hit(profile):
    """A ball at (0, 0, 4e99) with r = 1e99 (angular radius 14 degrees; near the range limit) is hit in
    float64, and set-up (rules.effects squares these coordinates in Python floats) does not overflow."""
    res = _render_centre(ball((0.0, 0.0, 4e99), 1e99), profile, "f64")
    assert np.isfinite(res.color).all()
    assert res.hit[8, 8] and res.hit.sum() > 20


def test_light_far_away():
    """The light at (0, 1e99, 0): float64 renders it without a NaN; float32 cannot hold it and refuses
    with a message (was a bug: NaN colours)."""
    for profile in PROFILES:
        res = _render_centre(ball((0.0, 0.0, 4.0), 0.5), profile, "f64", light=(0.0, 1e99, 0.0))
        assert np.isfinite(res.color).all()
        with pytest.raises(MinirtError, match="beyond float32's safe range"):
            _render_centre(ball((0.0, 0.0, 4.0), 0.5), profile, "f32", light=(0.0, 1e99, 0.0))
