"""The margins through the ball tree (minirt.reference.band.Rays) give the same bits as testing every ball.

``Rays`` computes a ball's margins only for the rays whose line passes near it (the candidates the tree
finds); the silhouette, origin and overall margins are exact below the caller's ``bound`` and inf elsewhere,
everything else exact. So every array must equal the every-ball path's clipped at the same bound, bit for
bit: on the bundled and the fuzz regression scenes, random scenes of many balls, rays that graze a ball
exactly, rays that start on a ball far from the origin, and with per-shape scales.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from support.scenes import ball, scene_text

from minirt.campaign.generate import balls_scene
from minirt.harness.references import ReferenceCache
from minirt.model import camera
from minirt.model.rules import resolve
from minirt.model.scene import load_scene, parse_scene
from minirt.model.tolerance import Margins
from minirt.reference import band


@pytest.fixture(autouse=True)
def _through_the_tree(monkeypatch):
    """Every test here takes the tree's path, however few the balls (band.FEW_BALLS)."""
    monkeypatch.setattr(band, "FEW_BALLS", 0)


SCENES = sorted(Path(__file__).parents[1].joinpath("scenes").glob("*.toml"))
STARTS = ((0.0, 0.0, 0.0), (1e-4, 2e-7, 2e-7), (0.0, 1e-6, 1e-6))


def _same(scene, o, d, scales=(None,) * 4, bound=band.BOUND) -> None:
    with np.errstate(all="ignore"):
        want = band._every_ball(scene, o, d, *scales, bound=bound)
        rays = band.Rays(scene, o, d)
        got = rays.margins(*scales, bound=bound)
    assert want.keys() == got.keys()
    for k in want:
        assert want[k].tobytes() == got[k].tobytes(), k
    for t_min, plane_err, ball_err in STARTS:
        assert np.array_equal(band._start_every_ball(scene, o, d, t_min, plane_err, ball_err),
                              rays.start_band(t_min, plane_err, ball_err))  # fmt: skip


def _random_scales(n: int, seed: int) -> tuple:
    rng = np.random.default_rng(seed)
    return tuple(10.0 ** rng.uniform(-7, 0.5, n) for _ in range(4))


def _rays(scene):
    return camera.primary_rays(scene, resolve(scene))


@pytest.mark.parametrize("bound", [band.BOUND, 1e-6, 3.0])
def test_bundled_and_regression_scenes(scene_path, bound):
    for path in [scene_path, *SCENES]:
        sc = load_scene(path).with_overrides(width=40, height=40)
        _same(sc, *_rays(sc), bound=bound)


def test_per_shape_scales():
    for k, path in enumerate(SCENES):
        sc = load_scene(path).with_overrides(width=40, height=40)
        _same(sc, *_rays(sc), _random_scales(len(sc.shapes), k), bound=1.0)


@pytest.mark.parametrize("n", [1, 40, 600])
def test_random_scenes_of_many_balls(n):
    sc = parse_scene(balls_scene(n, seed=n, width=48, height=48, max_depth=1))
    o, d = _rays(sc)
    _same(sc, o, d)
    _same(sc, o, d, _random_scales(len(sc.shapes), n), bound=1.0)
    # per-ray origin errors (an oracle's start band), gathered per candidate
    err = np.random.default_rng(n).uniform(0, 1e-3, len(o))
    got = band.Rays(sc, o, d).start_band(0.0, err, err)
    assert np.array_equal(got, band._start_every_ball(sc, o, d, 0.0, err, err))


@pytest.mark.parametrize("where", [1.0, 1e6])
def test_tangent_rays_and_origins_on_the_surface(where):
    """Rays at distance r (1 + tiny) from the centre, some of them starting on the ball's surface, near the
    origin and a million units away: the tree's slack must keep every pair whose computed margins count."""
    c = np.array([where, 0.5 * where, 3.0 * where])
    sc = parse_scene(scene_text(ball(c, 0.75), size=8))
    rng = np.random.default_rng(int(where))
    n = 4000
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    side = np.cross(d, rng.normal(size=(n, 3)))
    side /= np.linalg.norm(side, axis=1)[:, None]
    h = 0.75 * (1 + rng.choice([0.0, 1e-16, -1e-16, 1e-12, 1e-6, band.BOUND, 2 * band.BOUND], n))
    foot = c + side * h[:, None]  # the ray's nearest point to the centre
    o = foot - d * rng.uniform(-5, 5, n)[:, None]
    o[::3] = c + side[::3] * 0.75  # on the surface: origin margin ~0
    _same(sc, o, d)
    _same(sc, o, d, bound=1e-9)


def test_the_bound_clips_what_lies_beyond_it():
    """Not vacuous: beyond the bound the every-ball path knows the margin, the tree's reports inf."""
    sc = parse_scene(balls_scene(30, seed=3, width=32, height=32))
    o, d = _rays(sc)
    exact = band.margins(sc, o, d)["silhouette"]
    got = band.Rays(sc, o, d).margins(bound=0.01)["silhouette"]
    beyond = exact >= 0.01
    assert beyond.any() and np.isinf(got[beyond]).all()
    assert np.array_equal(got[~beyond], exact[~beyond])


def test_below_widens_the_bound_for_a_larger_threshold():
    """Margins.below: a threshold above the shared margins' bound is answered from margins exact below it."""
    sc = parse_scene(balls_scene(30, seed=4, width=32, height=32))
    o, d = _rays(sc)
    rays = band.Rays(sc, o, d)
    measured = Margins(rays.margins(bound=1e-3), rays.start_band, None, 1e-3, lambda eps: rays.margins(bound=eps))
    exact = band.margins(sc, o, d)
    for key in ("margin", "silhouette", "origin"):
        for eps in (1e-4, 0.05, 0.7):
            want = (exact[key] < eps).reshape(32, 32)
            assert np.array_equal(measured.below(key, eps, 32, 32), want), (key, eps)
    assert (exact["margin"] < 0.7).sum() > (exact["margin"] < 1e-3).sum()  # the widening changed something


def test_a_check_shares_one_set_of_rays_per_camera_rules():
    sc = parse_scene(balls_scene(20, seed=5, width=16, height=16))
    refs = ReferenceCache(sc)
    rules = resolve(sc)
    assert refs.rays(rules) is refs.rays(replace(rules, shadow_range="to-light"))  # the same rays
    other = refs.rays(replace(rules, pixel_sample="corner" if rules.pixel_sample != "corner" else "center"))
    assert other is not refs.rays(rules)
    assert other.balls is refs.rays(rules).balls  # one ball tree per scene


def test_few_balls_are_tested_every_one(monkeypatch):
    """Up to band.FEW_BALLS balls Rays tests every ball: the same arrays as the every-ball path, as ever."""
    monkeypatch.setattr(band, "FEW_BALLS", 4)
    sc = load_scene(SCENES[0]).with_overrides(width=24, height=24)
    o, d = _rays(sc)
    rays = band.Rays(sc, o, d)
    assert rays._few()
    want, got = band._every_ball(sc, o, d, bound=band.BOUND), rays.margins()
    assert all(want[k].tobytes() == got[k].tobytes() for k in want)
    assert rays._pairs is None  # no tree was searched
