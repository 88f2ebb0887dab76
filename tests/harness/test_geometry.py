"""The geometry check (minirt.harness.geometry) on a synthetic oracle. Honest verdicts: a check that cannot
fail is not PASS -- tolerances as wide as the scene or a band holding most pixels make it an inconclusive
WARN -- yet it still fails on what it can judge; NaN where the oracle's own precision cannot decide the
pixel is counted, not judged."""

from __future__ import annotations

import numpy as np
import pytest
from support.synthetic import SIZE, candidate, reference

from minirt.harness.geometry import check_geometry


@pytest.fixture(scope="module")
def setup():
    return reference()


def test_a_check_whose_t_tolerance_is_infinite_cannot_pass(setup):
    scene, rules, ref = setup
    cand = candidate(ref, t_abs=np.inf)
    cand.t = np.where(ref.hit, ref.t * 3.0, np.inf)  # every depth wrong by a factor 3: nothing can catch it
    geom = check_geometry(scene, rules, ref, cand)
    assert geom.verdict == "warn" and geom.inconclusive
    assert geom.reason.startswith("inconclusive: this oracle cannot judge this scene (")
    assert "t tolerance" in geom.reason
    fig = geom.figures["inconclusive"]
    assert fig["t_wide_fraction"] == 1.0 and fig["normal_wide_fraction"] == 0.0 and fig["band_fraction"] < 0.5
    assert fig["judged_pixels"] > 0.5 * fig["hit_pixels"]


def test_a_t_tolerance_wider_than_the_depth_range_cannot_pass(setup):
    scene, rules, ref = setup
    depth_range = float(np.ptp(ref.t[ref.hit]))
    wide = check_geometry(scene, rules, ref, candidate(ref, t_abs=1.01 * depth_range))
    narrow = check_geometry(scene, rules, ref, candidate(ref, t_abs=0.99 * depth_range))
    assert wide.verdict == "warn" and wide.inconclusive
    assert narrow.verdict == "pass" and not narrow.figures["inconclusive"]["reasons"]


def test_a_normal_tolerance_of_90_degrees_cannot_pass(setup):
    scene, rules, ref = setup
    geom = check_geometry(scene, rules, ref, candidate(ref, normal_deg=90.0))
    assert geom.verdict == "warn" and "normal tolerance" in geom.reason
    assert check_geometry(scene, rules, ref, candidate(ref, normal_deg=89.0)).verdict == "pass"


def test_a_band_holding_most_hit_pixels_cannot_pass(setup):
    scene, rules, ref = setup
    geom = check_geometry(scene, rules, ref, candidate(ref, band_eps=10.0))  # every margin is < 10
    assert geom.verdict == "warn" and geom.inconclusive
    assert geom.figures["inconclusive"]["band_fraction"] == 1.0 and "the band holds 100%" in geom.reason


def test_an_inconclusive_check_still_fails_on_what_it_can_judge(setup):
    """A wrong shape id is a defect whatever the t tolerance: FAIL, not an inconclusive WARN."""
    scene, rules, ref = setup
    cand = candidate(ref, t_abs=np.inf)
    cand.shape_id = np.where(ref.shape_id == 0, 1, ref.shape_id)
    geom = check_geometry(scene, rules, ref, cand)
    assert geom.verdict == "fail" and "shape id" in geom.reason
    assert geom.figures["inconclusive"]["reasons"]  # the figures still say what could not be judged


def test_nan_inside_the_band_is_counted_not_judged(setup):
    """An oracle's NaN where its own precision cannot decide the pixel (a float32 normal of a ball 1e8 away)
    is not a defect of the reference: counted in the figures, not judged; off the band it FAILs (above)."""
    scene, rules, ref = setup
    cand = candidate(ref)
    cand.normal[SIZE // 2, SIZE // 2] = np.nan  # row SIZE // 2: the floor's horizon, in the band
    geom = check_geometry(scene, rules, ref, cand)
    assert geom.images["band"][SIZE // 2, SIZE // 2]
    assert geom.verdict == "pass", geom.reason
    assert geom.figures["nonfinite"] == {"normal": 1} and geom.figures["nonfinite_outside_band"] == 0
