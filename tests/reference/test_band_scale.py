"""Per-shape bands (minirt.reference.band.margins ``scale``, ``origin_scale``, ``inside_scale``;
oracles.povray.band_scales):
an oracle's precision differs from shape to shape, so each decision is measured against the precision of the shape it
is about. One scene-wide threshold is the worst shape's: a ball 1e6 radii away put every pixel of the
well-held ground beside it in POV-Ray's band, and the check said "inconclusive" on scenes it can judge.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from support.scenes import ball, material, plane, scene_text

from minirt.harness.run import check_scene
from minirt.model import camera
from minirt.model.rules import resolve
from minirt.model.scene import load_scene, parse_scene
from minirt.oracles import povray
from minirt.reference import band

SCENES = Path(__file__).parents[1] / "scenes"

_TWO = scene_text(
    ball((-0.6, 0.0, 4.0), 1.0),
    ball((0.8, 0.2, 4.5), 1.2),
    plane((0.0, 1.0, 0.0), -1.0),
    size=32,
    light=(2.0, 3.0, -1.0),
    materials={"m": material((0.6, 0.5, 0.4))},
)


def _rays(sc):
    return camera.primary_rays(sc, resolve(sc))


def test_unit_scales_change_nothing():
    sc = parse_scene(_TWO)
    o, d = _rays(sc)
    plain, ones = band.margins(sc, o, d), band.margins(sc, o, d, [1.0, 1.0, 1.0])
    for k in plain:
        np.testing.assert_array_equal(plain[k], ones[k], err_msg=k)


def test_each_margin_is_divided_by_its_own_shapes_scale():
    sc = parse_scene(_TWO)
    o, d = _rays(sc)
    plain = band.margins(sc, o, d)
    scaled = band.margins(sc, o, d, [1.0, 1e3, 1.0])  # ball 1 held 1000 times less exactly
    # silhouettes: the minimum over balls, ball 1's divided by 1000 -- never larger than before, and
    # smaller wherever ball 1's silhouette was the nearest
    assert (scaled["silhouette"] <= plain["silhouette"]).all()
    assert (scaled["silhouette"] < plain["silhouette"]).any()
    # the plane's grazing margin is its own: unchanged
    np.testing.assert_array_equal(scaled["grazing"], plain["grazing"])
    # a depth tie between ball 0 and the plane keeps its margin; one involving ball 1 is divided by 1000
    finite = np.isfinite(plain["tie"]) & (plain["tie"] > 0)
    ratio = np.round(plain["tie"][finite] / scaled["tie"][finite], 6)
    assert set(ratio) <= {1.0, 1000.0}
    assert (ratio == 1.0).any() and (ratio == 1000.0).any()
    # origins: their own scale, which defaults to the shapes' one
    only_origin = band.margins(sc, o, d, [1.0, 1.0, 1.0], [1.0, 1e3, 1.0])
    np.testing.assert_array_equal(only_origin["silhouette"], plain["silhouette"])
    assert (only_origin["origin"] <= plain["origin"]).all()


def test_an_inside_scale_bands_only_the_rays_that_meet_the_ball():
    """An error that can only lose a hit (POV-Ray's bounding boxes) widens the band over the ball's disc,
    never around it: rays that miss ball 1 keep their silhouette margin."""
    sc = parse_scene(_TWO)
    o, d = _rays(sc)
    plain = band.margins(sc, o, d)
    inside = band.margins(sc, o, d, [1.0, 1.0, 1.0], inside_scale=[1.0, 1e3, 1.0])
    f = o - np.asarray(sc.shapes[1].center)
    h = np.linalg.norm(f - np.einsum("ij,ij->i", f, d)[:, None] * d, axis=1)
    meets = h < sc.shapes[1].radius
    assert (inside["silhouette"] <= plain["silhouette"]).all()
    changed = inside["silhouette"] < plain["silhouette"]
    assert changed.any() and not (changed & ~meets).any()
    np.testing.assert_array_equal(inside["tie"], plain["tie"])  # depth ties keep the symmetric scale


def test_povray_thresholds_are_per_shape_and_bounded_by_the_scene_wide_one():
    sc = load_scene(SCENES / "fuzz_far_balls_over_a_ground.toml")
    rules = resolve(sc)
    scales = povray.band_scales(sc, rules)
    inside = povray.band_inside_scales(sc, rules)
    assert all(i >= s for i, s in zip(inside, scales, strict=True))
    assert max(inside) == povray.band_threshold(sc, rules)
    # the ground (radius 1.5e6) is held to ~1e-5 of its radius; the ball 4.6e6 radii away to none at all
    assert scales[0] < 1e-4 and scales[1] > 1.0
    origin = povray.band_origin_scales(sc, rules)
    assert all(o <= s for o, s in zip(origin, scales, strict=True))
    o, d = _rays(sc)
    wide = band.margins(sc, o, d)["margin"] < povray.band_threshold(sc, rules)
    own = band.margins(sc, o, d, scales, origin, inside)["margin"] < 1.0
    assert wide.all()  # the scene-wide threshold: every ray
    assert own.mean() < 0.2  # each shape's own: the far balls' few pixels and the horizon


@pytest.mark.slow
def test_povray_judges_the_ground_beside_far_balls():
    """fuzz far_2027_0: a ground of radius 1.5e6 0.47 under the camera, balls 5e5 and 4.6e6 radii away.
    With one scene-wide band, 100 % of the hit pixels were in it (inconclusive); per shape POV-Ray judges
    the ground and agrees."""
    sc = check_scene(SCENES / "fuzz_far_balls_over_a_ground.toml", ["povray"])
    b = sc.backends["povray"]
    assert b.verdict == "pass" and not b.inconclusive, b.reason
    fig = b.checks["geometry"].figures
    assert fig["inconclusive"]["band_fraction"] < 0.5
    assert fig["mask_mismatch_outside_band"] == 0 and fig["id_mismatch"] == 0


@pytest.mark.slow
def test_povray_cannot_judge_hits_beyond_its_max_distance():
    """fuzz far_2026_6: rays starting just inside a ground of radius 4.5e7 meet its far side 1.04e7 away,
    which POV-Ray drops (MAX_DISTANCE 1e7): those rays are in its band, the ones it can see are judged."""
    sc = check_scene(SCENES / "campaign" / "far_2026_6.toml", ["povray"])
    b = sc.backends["povray"]
    assert b.verdict != "fail", b.reason
    fig = b.checks["geometry"].figures
    assert fig["mask_mismatch"] > 0  # the case still has rays beyond POV-Ray's reach ...
    assert fig["mask_mismatch_outside_band"] == 0  # ... and none of them is judged
    assert b.result.meta["precision"]["max_distance"] == povray.MAX_DISTANCE


def test_povray_bounding_boxes_hold_a_ball_no_better_than_the_scene_they_span():
    """With 3 balls or more POV-Ray's single-precision bounding tree can shrink a node's face by 2^-24 of
    the scene's extent: beside a ball 1e8 away, a ball of radius 0.27 has no exactly held pixel."""
    sc = load_scene(SCENES / "campaign" / "far_2026_112.toml")
    rules = resolve(sc)
    assert povray.band_scales(sc, rules)[0] < 1e-4  # its own discriminant and distance: exact
    assert povray.band_inside_scales(sc, rules)[0] > 1.0  # the tree spanning the far ball: nothing


@pytest.mark.slow
def test_povray_loses_hits_to_its_bounding_boxes_only_inside_the_band():
    """fuzz far_2026_112: POV-Ray missed 5 pixels at the top of the near ball's disc (a box's upper y,
    lower + length in float, off by ulp(1.6e7)); judged against the ball's own precision they were a
    FAIL. With the boxes in the band the check says it cannot judge the scene."""
    sc = check_scene(SCENES / "campaign" / "far_2026_112.toml", ["povray"])
    b = sc.backends["povray"]
    fig = b.checks["geometry"].figures
    assert fig["mask_mismatch"] > 0  # POV-Ray still loses them ...
    assert fig["mask_mismatch_outside_band"] == 0  # ... inside the band
    assert b.verdict == "warn" and b.inconclusive, b.reason


def test_povray_root_error_grows_with_the_square_of_the_distance():
    """POV-Ray's textbook discriminant cancels as |f|^2: its root error (oracles.povray.root_errors, in the
    t and normal tolerances per pixel) is 12 2^-53 |f|^2/r, 100 times larger at 10 times the distance."""
    near = parse_scene(_TWO)
    far = parse_scene(_TWO.replace("center = [-0.6, 0.0, 4.0]", "center = [-0.6, 0.0, 58.0]"))
    e_near = povray.root_errors(near, resolve(near))
    e_far = povray.root_errors(far, resolve(far))
    assert e_near[2] == e_far[2] == 0.0  # the plane's t is one division
    # ball 0: |f| = its distance from the camera (0, 0, -2), plus r, plus the pinhole rays' lift
    lift = povray.origin_lift(near, resolve(near))
    d_near, d_far = np.hypot(0.6, 6.0), np.hypot(0.6, 60.0)
    assert e_far[0] / e_near[0] == pytest.approx(((d_far + 1 + lift) / (d_near + 1 + lift)) ** 2, rel=1e-12)
    assert e_far[1] == e_near[1]


# ---- Mitsuba (oracles.mitsuba.band_scales) --------------------------------------------------------


def _one_ball(distance: float, radius: float):
    """A ball `distance` away from the origin along (0.6, 0, 0.8), and its per-shape scales seen from there."""
    from minirt.oracles import mitsuba

    c = np.array([0.6, 0.0, 0.8]) * distance
    sc = parse_scene(scene_text(ball(c, radius), distance=1.0, light=(0.0, 5.0, 0.0)))
    return c, mitsuba.band_scales(sc, np.zeros((1, 3)))


def _float32_hits(c: np.ndarray, radius: float, h: float, n: int = 400) -> np.ndarray:
    """Mitsuba's float32 sphere test (f = o - c, A = d.d, B = 2 f.d, C = f.f - r^2, D = B^2 - 4AC >= 0), one
    rounding per operation, for n rays from the origin passing at distance h from the centre c in random
    directions around it (the rounding differs from ray to ray)."""
    rng = np.random.default_rng(7)
    e = c / np.linalg.norm(c)
    u = np.cross(e, [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(e, u)
    phi = rng.uniform(0, 2 * np.pi, n)
    side = np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v
    L = np.linalg.norm(c)
    s = h / L  # sin of the angle between the ray and the centre's direction
    d = np.sqrt(1 - s * s) * e + s * side
    f32 = np.float32
    d32, c32, r32 = d.astype(f32), c.astype(f32), f32(radius)
    f = f32(0.0) - c32
    a = (d32 * d32).sum(axis=1, dtype=f32)
    b = f32(2.0) * (f * d32).sum(axis=1, dtype=f32)
    cc = (f * f).sum(dtype=f32) - r32 * r32
    return (b * b - f32(4.0) * a * cc) >= 0


@pytest.mark.parametrize("ratio", [200.0, 3e3, 1e5])
def test_mitsuba_band_holds_every_float32_flip_and_is_needed(ratio):
    """The per-shape band against Mitsuba's own float32 arithmetic, simulated: outside the band (margin
    above the scale) the float32 decision is the exact one on every ray; well inside it (a 50th of the
    scale) some float32 decisions are wrong -- the band is not wider than the flips make it. (The band
    carries BAND_K's safety: scales divided by 4 still pass at the nearer distances, divided by 30 they
    let float32 flips through at every distance here.)"""
    r = 1.0
    c, s = _one_ball(ratio * r, r)
    out, inside = s["scale"][0], s["inside"][0]
    assert not _float32_hits(c, r, r * (1 + 1.05 * out)).any()  # misses, decided right
    if inside < 1:
        assert _float32_hits(c, r, r * (1 - 1.05 * inside)).all()  # hits, decided right
    wrong = _float32_hits(c, r, r * (1 + out / 50))
    assert wrong.any()  # exact: a miss; float32 says hit on some rays


def test_mitsuba_scales_agree_with_the_scene_wide_band_where_it_is_small():
    """For a ball held well (eps small) each shape's band is the scene-wide K eps; for a far one the exact
    form is far narrower than the linear K eps (which would band every ray in view), and every hit on a
    ball whose discriminant error exceeds r^2 is in the band (inside scale 2 > any margin)."""
    from minirt.oracles import mitsuba

    c, s = _one_ball(8.0, 1.0)
    eps = mitsuba.band_eps(parse_scene(_TWO), np.zeros((1, 3)))  # ~ u32 (|f|/r)^2, small
    assert eps < 1e-5
    f = np.linalg.norm(c) + 1.0
    k_eps = mitsuba.BAND_K * mitsuba.U32 * f * f
    assert s["scale"][0] == pytest.approx(k_eps, rel=1e-3)
    assert s["inside"][0] == pytest.approx(k_eps, rel=1e-3)
    assert s["tie"][0] == pytest.approx(k_eps, rel=1e-12)
    c, s = _one_ball(1e6, 1.0)
    k_eps = mitsuba.BAND_K * mitsuba.U32 * (1e6 + 1) ** 2
    assert s["scale"][0] == pytest.approx(np.sqrt(2 * k_eps), rel=1e-3)  # ~7.8e3 radii, not 9.5e5
    assert s["inside"][0] == 2.0 and s["origin"][0] == s["scale"][0]


@pytest.mark.slow
def test_mitsuba_judges_the_near_balls_beside_a_far_one():
    """Two balls before the camera and one 3.3e6 radii away on one pixel's ray. The scene-wide band
    (K eps of the far ball, ~9e5) put every ray in it: inconclusive. Per shape, only the far ball's pixel
    is in Mitsuba's band, and the near balls are judged, and agree."""
    sc = check_scene(SCENES / "far_ball_beside_near_ones.toml", ["mitsuba"])
    b = sc.backends["mitsuba"]
    assert b.verdict == "pass" and not b.inconclusive, b.reason
    fig = b.checks["geometry"].figures
    assert fig["tolerance"]["band_eps"] > 1.0  # the scene-wide band: every margin in view is below it
    assert 1 <= fig["band_pixels"] <= 4
    assert fig["mask_mismatch_outside_band"] == 0 and fig["id_mismatch"] == 0 and fig["depth_violations"] == 0


@pytest.mark.parametrize("seed", range(4))
def test_the_nearest_candidates_are_what_a_stable_sort_gives(seed):
    """band._Nearest keeps, per ray, the nearest candidate hit, the next one and the nearest of another
    shape as candidates are pushed, where margins() used to stack every candidate and sort them stably by
    t: the same picks, an earlier candidate winning a tie (t drawn from a few values, inf among them,
    so ties are everywhere)."""
    rng = np.random.default_rng(seed)
    rays, shapes = 500, 7
    cands = []  # (t, nd, cos, owner) in push order: a shape's candidates one after the other
    for k in range(shapes):
        for _ in range(rng.integers(1, 3)):  # a plane: one candidate, a ball: two
            t = rng.choice([0.5, 1.0, 1.0, 2.0, np.inf], rays)
            cands.append((t, rng.uniform(0, 1, rays), rng.uniform(0, 1, rays), k))
    near = band._Nearest(rays)
    for c in cands:
        near.push(*c)
    t = np.stack([c[0] for c in cands], axis=1)
    order = np.argsort(t, axis=1, kind="stable")
    owner = np.array([c[3] for c in cands])[order]
    rows = np.arange(rays)
    other = np.argmax(owner != owner[:, :1], axis=1)  # every ray has candidates of several shapes
    for got, col in ((near.first, order[:, 0]), (near.second, order[:, 1]), (near.other, order[rows, other])):
        want_t = t[rows, col]
        finite = np.isfinite(want_t)
        assert np.array_equal(got.t, want_t)
        for field, k in (("nd", 1), ("cos", 2)):
            want = np.stack([c[k] for c in cands], axis=1)[rows, col]
            assert np.array_equal(getattr(got, field)[finite], want[finite])
        assert np.array_equal(got.owner[finite], np.array([c[3] for c in cands])[col][finite])
