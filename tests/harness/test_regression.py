"""The regression suite: every bundled scene against every oracle, through the harness.

Each backend must PASS, or SKIP for a stated, expected reason. A failure leaves the evidence
(reference, oracle, mask and error images, the figures) under tests/_evidence/<scene>/<backend>/.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from support.evidence import dump_check
from support.scenes import SHINY, ball, plane, scene_text, write_scene

from minirt.harness import backends
from minirt.harness.backends import oracle_names
from minirt.harness.run import check_scene

SIZE = (64, 64)
# (scene, backend) -> a phrase the SKIP reason must contain
EXPECTED_SKIPS: dict[tuple[str, str], str] = {}  # none: every oracle renders every bundled scene


@pytest.mark.slow
def test_scene_against_every_oracle(scene_path):
    sc = check_scene(scene_path, ["reference", *oracle_names()], SIZE)
    problems = []
    for name, b in sc.backends.items():
        expected = EXPECTED_SKIPS.get((sc.scene, name))
        if expected:
            if b.verdict != "skip" or expected not in b.reason:
                problems.append(f"{name}: expected SKIP ({expected}), got {b.verdict.upper()} {b.reason}")
        elif b.verdict != "pass":
            where = dump_check(sc, name)
            problems.append(f"{name}: {b.verdict.upper()} {b.reason} (evidence: {where})")
    assert not problems, "\n".join(problems)


def test_every_rule_an_oracle_cannot_follow_is_attributed():
    sc = check_scene("scenes/shadows.toml", ["povray"], (48, 48))
    b = sc.backends["povray"]
    assert b.verdict == "pass"
    assert set(b.rules) == {"shadow_range", "near_root_only", "two_sided", "clamp", "offset"}
    assert b.rules["shadow_range"] > 100  # the ball beyond the light darkens the big ball
    assert b.rule_masks["shadow_range"].sum() == b.rules["shadow_range"]


# Degenerate but valid scenes: every oracle must PASS on them, not crash or cry wolf.
def _edge_scene(size: str, shapes: str) -> str:
    """WIDTHxHEIGHT pixels, one shiny material "m" (tests/support/scenes.py)."""
    w, h = size.split("x")
    return scene_text(
        shapes,
        size=(int(w), int(h)),
        light=(2.0, 3.0, -1.0),
        render={"background": (0.1, 0.2, 0.3)},
        materials={"m": SHINY},
    )


_BALL = ball((0.0, 0.0, 3.0), 1.0)
_FLOOR = plane((0.0, 1.0, 0.0), -1.0)
EDGE_SCENES = {
    "no_shapes": ("32x32", ""),
    "one_pixel": ("1x1", _BALL),
    "wide_strip": ("40x3", _BALL + _FLOOR),
    # a ball around the camera position: POV-Ray needs its mesh camera, the near root is behind every ray
    "ball_at_camera": ("24x24", _BALL + ball((0.0, 0.0, -2.0), 0.5)),
    "plane_through_camera": ("24x24", plane((1.0, 0.0, 0.0), 0.0)),
    # Found by fuzzing random scenes through every oracle:
    # two planes of one material: Mitsuba's loader merged them into one shape without an id
    "two_planes_one_material": ("24x24", _FLOOR + plane((1.0, 0.0, 0.0), -1.5)),
    # a plane seen almost edge-on (|n·d| down to 4e-4): t is conditioned by 1/|n·d| in every oracle
    "grazing_plane": ("24x24", _BALL + plane((-0.696, 0.666, -0.031), -0.197)),
    # a plane through the image plane: a line of rays starts exactly on it (t = 0, a miss under t > 0);
    # Mitsuba's and Embree's float32 put a hit at t ~ 1e-7, POV-Ray's mesh camera drops hits within 1e-4
    # (all three FAILed before the start band, minirt.reference.band.start_band)
    "plane_through_image_plane": ("48x48", _BALL + plane((0.3, 0.7, -0.5), 0.0)),
    # a big ball crossing the image plane, rays near its silhouette: Mitsuba's float32 discriminant
    "ball_across_image_plane": ("24x24", ball((-0.994, 1.429, 0.359), 1.386)),
}


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(EDGE_SCENES))
def test_edge_scene_against_every_oracle(name, tmp_path):
    size, shapes = EDGE_SCENES[name]
    path = write_scene(tmp_path, name, _edge_scene(size, shapes))
    sc = check_scene(path, ["reference", *oracle_names()])
    bad = {n: f"{b.verdict} {b.reason}" for n, b in sc.backends.items() if b.verdict != "pass"}
    assert not bad, bad


@pytest.mark.slow
def test_edges_seen_in_reflections_are_classified():
    """A fuzzed scene: a reflected silhouette crosses a pixel whose primary hit is far from any edge.
    POV-Ray differs there by 4 levels; the reference's ray-tree labels (aux ray_tree) put the pixel in
    the 'in_reflection' edge class, reported apart, instead of failing the check."""
    sc = check_scene(Path(__file__).parents[1] / "scenes" / "fuzz_reflected_edges.toml", ["povray"])
    b = sc.backends["povray"]
    assert b.verdict == "pass", b.reason
    shading = b.checks["shading"]
    assert shading.figures["edge_pixels"]["in_reflection"] > 0
    assert shading.figures["color8_diff_on_edges"] > 0  # the legitimate difference is there, on an edge


def _rays_pass_sensor_inconclusive(b) -> None:
    """Scenes of 4 samples with a huge rectangle: the custom-ray checks (what these tests are about) pass;
    the sensor route's stochastic check is an inconclusive WARN, because the rectangle's float32 error
    exceeds the spawn offset of Mitsuba's stock integrator on most pixels, so its shadow rays may re-hit
    the rectangle (they did, on the fuzzed scene tests/scenes/campaign/contact_26_0.toml). It used to
    PASS here: this scene's shadow rays happened not to re-hit it, but nothing bounds that."""
    assert b.verdict == "warn" and b.inconclusive, b.reason
    assert all(c.verdict == "pass" for k, c in b.checks.items() if k != "stochastic"), b.reason
    st = b.checks["stochastic"]
    assert st.inconclusive and st.figures["self_shadow_unjudged_pixels"] > 0


@pytest.mark.slow
def test_a_huge_rectangles_error_reaches_the_diffuse_tolerance():
    """A fuzzed scene: Mitsuba's rectangle for a far-reaching plane errs by 0.077 at its hit points,
    which turns the light direction; the diffuse tolerance carries abs_error / |L - p| for planes."""
    sc = check_scene(Path(__file__).parents[1] / "scenes" / "fuzz_huge_rectangle.toml", ["mitsuba"])
    b = sc.backends["mitsuba"]
    _rays_pass_sensor_inconclusive(b)
    assert max(p["abs_error"] for p in b.result.meta["planes"].values()) > 0.01  # the case is still hard
    assert b.checks["shading"].figures["diffuse_rel_err_max"] > 2e-4  # beyond the plane-free tolerance


@pytest.mark.slow
def test_a_grazing_view_of_a_huge_rectangle_errs_by_its_error_over_cos():
    """A fuzzed scene: a ray meets Mitsuba's rectangle at cos 0.188; the interpolated hit point lies 0.495
    off the ray (abs_error 0.092 / 0.188), which turns the light direction 5 times more than abs_error
    alone: the diffuse tolerance carries abs_error / (|cos| |L - p|)."""
    sc = check_scene(Path(__file__).parents[1] / "scenes" / "fuzz_grazing_rectangle.toml", ["mitsuba"])
    b = sc.backends["mitsuba"]
    assert b.verdict == "pass", b.reason
    # beyond the tolerance without the cosine there: 2e-4 + abs_error / |L - p| = 2e-4 + 0.092 / 18.45 = 5.2e-3
    assert b.checks["shading"].figures["diffuse_rel_err_max"] > 6e-3


@pytest.mark.slow
def test_a_plane_never_shadows_itself_in_mitsuba():
    """A fuzzed scene: the stock visibility test let a huge rectangle shadow its own points."""
    sc = check_scene(Path(__file__).parents[1] / "scenes" / "fuzz_plane_self_shadow.toml", ["mitsuba"])
    b = sc.backends["mitsuba"]
    _rays_pass_sensor_inconclusive(b)
    assert b.checks["shading"].figures["lit_mismatch"] == 0


@pytest.mark.slow
def test_shadow_decisions_within_the_oracles_position_error_are_not_judged():
    """A fuzzed scene: Mitsuba's hit point on a huge rectangle errs by more than its shadow ray's distance
    from a ball's silhouette (the reference's aux shadow_margin), so lit/unlit may legitimately differ."""
    sc = check_scene(Path(__file__).parents[1] / "scenes" / "fuzz_shadow_within_position_error.toml", ["mitsuba"])
    b = sc.backends["mitsuba"]
    assert b.verdict == "pass", b.reason
    fig = b.checks["shading"].figures
    assert fig["lit_mismatch"] == 0 and fig["lit_mismatch_within_position_error"] >= 1


# Checks that could not fail, formerly reported as PASS: now an inconclusive WARN, with the figures.
PLANET = _BALL + ball((0.0, -100000001.0, 0.0), 100000000.0)


@pytest.mark.slow
def test_a_planet_sized_ground_is_inconclusive_for_the_float32_oracles(tmp_path):
    """A ground that is a ball of radius 1e8 puts every pixel in the band of the single-precision oracles
    (relative silhouette margins ~1e-8 against float32 / tessellation precision): hit/miss is judged
    nowhere, inconclusive. POV-Ray decides it in double precision, and its band is per shape: the camera
    starts 1 above the ground, 1e-8 of its radius, against its origin test's 2^-53 |f|^2 / r^2 -- so
    POV-Ray judges nearly every pixel, and agrees."""
    path = write_scene(tmp_path, "planet", _edge_scene("24x24", PLANET))
    sc = check_scene(path, ["reference", *oracle_names()])
    for name, b in sc.backends.items():
        fig = b.checks["geometry"].figures["inconclusive"]
        # POV-Ray decides in double precision; a certified oracle's band is the reference's own float64 one
        if name == "povray" or getattr(backends.get(name), "certified", False):
            assert b.verdict == "pass" and not b.inconclusive, b.reason
            assert fig["band_fraction"] < 0.1 and fig["judged_pixels"] > 0.9 * fig["hit_pixels"]
            continue
        assert b.verdict == "warn" and b.inconclusive, (name, b.verdict, b.reason)
        assert b.reason.startswith("inconclusive: this oracle cannot judge this scene (the band holds")
        assert fig["band_fraction"] > 0.5 and fig["limit"] == 0.5


@pytest.mark.slow
@pytest.mark.parametrize("name", ["fuzz_far_plane_shadow", "fuzz_plane_shadow_restart"])
def test_a_shadow_segment_leaves_its_own_rectangles_slab_before_it_counts(name):
    """Fuzzed scenes: a shadow segment from a point on a huge rectangle first hits that rectangle itself
    (float32), and restarting at the self-hit landed within the rectangle's error slab again, until the
    occluder behind (another plane) was never reached: Mitsuba lit, the reference shadowed. Restarted past
    the slab (2 abs_error / |n·s|), the occluder counts."""
    sc = check_scene(Path(__file__).parents[1] / "scenes" / f"{name}.toml", ["mitsuba"])
    b = sc.backends["mitsuba"]
    assert b.verdict == "pass", b.reason
    assert b.checks["shading"].figures["lit_mismatch"] == 0
    assert b.result.meta["shadow_self_hits"] > 0  # the case still exercises the self-hit path
    assert b.result.meta["plane_coverage_complete"] is True


CAMPAIGN = sorted((Path(__file__).parents[1] / "scenes" / "campaign").glob("*.toml"))


@pytest.mark.slow
@pytest.mark.parametrize("path", CAMPAIGN, ids=[p.stem for p in CAMPAIGN])
def test_a_false_alarm_of_the_campaign_stays_fixed(path):
    """Scenes on which a fuzzing campaign (minirt fuzz) once reported FAIL or ERROR against the correct
    reference (each file's first line says what went wrong): every oracle now passes, or says honestly
    that it cannot judge the scene (WARN)."""
    sc = check_scene(path, ["reference", *oracle_names()])
    bad = {n: f"{b.verdict.upper()} {b.reason}" for n, b in sc.backends.items() if b.verdict in ("fail", "error")}
    assert not bad, bad
