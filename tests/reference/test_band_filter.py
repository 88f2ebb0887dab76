"""The band filter (minirt.reference.band_filter): its kernel lets through every primary ray whose exact
margin (minirt.reference.band.margins) is below eps, and few others; a rule diagnosis' band flags through
it are the exact ones, bit for bit.

A ray the filter wrongly held back would be a pixel the diagnosis counts as a rule's evidence where
rounding may decide it. So the superset is checked on every pixel of the bundled and regression scenes,
under each camera rule, at the diagnosis' eps and at wider ones (more rays near a decision), and on
scenes built to sit on decisions: a ball resting on a plane (three candidates at one depth), balls
crossing the image plane (origins on a surface), touching balls, a plane through the camera.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from support.scenes import ball, plane, scene_text

from minirt.campaign.generate import balls_scene
from minirt.diagnose.variants import EPS_REL, VariantCache
from minirt.model import camera
from minirt.model.rules import Rules
from minirt.model.scene import load_scene, parse_scene
from minirt.reference import band, band_filter

ROOT = Path(__file__).parents[2]
SCENES = [*sorted(ROOT.joinpath("scenes").glob("*.toml")), *sorted(ROOT.joinpath("tests/scenes").glob("*.toml"))]
CAMERAS = (
    Rules(),
    Rules(pixel_sample="center"),
    Rules(ray_origin="camera"),
    Rules(pixel_shift=(0.25, -0.5)),
)
EPSILONS = (EPS_REL, 2.0**-12, 2.0**-6)


def _check(sc, rules, eps) -> tuple[int, int]:
    """Asserts the superset; returns (exact rays below SLACK eps, rays let through)."""
    assert band_filter.usable(sc, band_filter.reach(sc, rules), eps)
    o, d = camera.primary_rays(sc, rules)
    with np.errstate(all="ignore"):
        margin = band.margins(sc, o, d)["margin"]
    through = band_filter.near_band(sc, o, d, eps)
    missed = np.flatnonzero((margin < eps) & ~through)
    assert missed.size == 0, f"{sc.source}: {missed.size} rays in the band held back, e.g. pixel {missed[:5]}"
    return int((margin < band_filter.SLACK * eps).sum()), int(through.sum())


@pytest.mark.parametrize("rules", CAMERAS, ids=lambda r: f"{r.pixel_sample}-{r.ray_origin}-{r.pixel_shift}")
def test_every_ray_in_the_band_is_let_through(rules):
    """Every pixel of every bundled and regression scene at 96x80, at the diagnosis' eps and wider."""
    looked = 0
    for path in SCENES:
        sc = load_scene(path).with_overrides(width=96, height=80)
        if not band_filter.usable(sc, band_filter.reach(sc, rules), EPS_REL):
            continue
        looked += 1
        for eps in EPSILONS:
            exact, through = _check(sc, rules, eps)
            # and at the diagnosis' eps it filters: beyond the rays within its slack of the band it lets
            # through few (wider, a tie's least gap times another candidate's cosine lets through more)
            if eps == EPS_REL:
                assert through - exact <= max(8, 0.01 * 96 * 80), (path.name, eps, exact, through)
    assert looked >= 10


def _decisions() -> list[str]:
    m = 0.5
    return [
        # a ball resting on a plane: at the contact point the plane's t and both roots meet
        scene_text(ball((0.0, -0.5 + m, 3.0), m), plane((0, 1, 0), -0.5), size=(64, 48)),
        # balls crossing the image plane (rays starting on their surfaces), touching each other
        scene_text(ball((0.0, 0.0, 0.0), 0.3), ball((0.6, 0.0, 0.0), 0.3), ball((0.0, 0.45, 2.0), 0.2), size=64),
        # a plane through the camera's point and one through the image plane
        scene_text(ball((0.2, 0.1, 4.0), 1.0), plane((1, 0, 0), 0.0), plane((0, 0, 1), 0.0), size=64),
        # a far ball and a near one at nearly the same silhouette
        scene_text(ball((0.0, 0.0, 2000.0), 400.0), ball((0.0, 0.0, 5.0), 1.0), size=64),
    ]


@pytest.mark.parametrize("k", range(4))
def test_scenes_built_on_decisions(k):
    sc = parse_scene(_decisions()[k])
    for rules in CAMERAS:
        for eps in EPSILONS:
            _check(sc, rules, eps)


@pytest.mark.parametrize("n", [3, 14])
def test_random_balls_over_a_mirror_floor(n):
    sc = parse_scene(balls_scene(n, seed=n, width=80, height=64))
    for rules in CAMERAS[:2]:
        for eps in EPSILONS:
            _check(sc, rules, eps)


def test_where_it_does_not_answer():
    """Too many shapes for one unrolled kernel, a ball too small for its distance, an eps below the
    kernel's own error: the caller computes every margin exactly."""
    many = parse_scene(balls_scene(band_filter.MAX_SHAPES, seed=1, width=8, height=8))  # and the floor
    assert not band_filter.usable(many, 1.0, EPS_REL)
    far = parse_scene(scene_text(ball((0.0, 0.0, 1e7), 1.0), size=8))
    assert not band_filter.usable(far, 1.0, EPS_REL)
    near = parse_scene(scene_text(ball((0.0, 0.0, 1e3), 1.0), size=8))
    assert band_filter.usable(near, 1.0, EPS_REL)
    assert not band_filter.usable(near, 1.0, 2.0**-30)


def test_reach_is_the_farthest_origin():
    sc = load_scene(ROOT / "scenes/rules.toml").with_overrides(width=33, height=17)
    for rules in CAMERAS:
        o, _ = camera.primary_rays(sc, rules)
        assert band_filter.reach(sc, rules) == float(np.sqrt((o * o).sum(1)).max())


def test_a_diagnosis_band_is_the_exact_one():
    """VariantCache.band through the filter (a request of the whole image, then small ones that read the
    kept filter): the exact flags on every pixel, and the filter was used."""
    sc = load_scene(ROOT / "scenes/rules.toml").with_overrides(width=400, height=400)
    n = 400 * 400
    for rules in (Rules(), replace(Rules(), pixel_sample="center")):
        cache = VariantCache()
        o, d = camera.primary_rays(sc, rules)
        with np.errstate(all="ignore"):
            want = band.margins(sc, o, d, bound=EPS_REL)["margin"] < EPS_REL
        assert want.any() or rules.pixel_sample == "center"  # the corners' rays meet silhouettes here
        rng = np.random.default_rng(1)
        part = np.sort(rng.choice(n, 20000, replace=False))
        assert np.array_equal(cache.band(sc, rules, part), want[part])
        assert cache._near and all(v is not None for v in cache._near.values())
        assert np.array_equal(cache.band(sc, rules, np.arange(n)), want)


@pytest.mark.parametrize("family", ["random", "start", "grazing", "contact", "far", "scaled", "f32"])
def test_the_campaigns_hard_families(family):
    """The fuzz campaign's families (minirt.campaign.families: rays starting on surfaces, grazing planes,
    balls resting on planes, far and scaled scenes, float32's limits), four scenes each: where the filter
    answers, it lets every ray in the band through, at every eps."""
    from minirt.campaign.families import scene_text as family_scene

    for index in range(4):
        sc = parse_scene(family_scene(family, 11, index, 48, 40))
        for rules in CAMERAS:
            if band_filter.usable(sc, band_filter.reach(sc, rules), EPS_REL):
                for eps in EPSILONS:
                    _check(sc, rules, eps)
