"""The fast tracer against the plain, recursive transcription of the pseudo-code.

float64, every bundled scene, every profile, and every trace rule flipped singly from each profile
(tests/test_rules_more.py: every candidate value of the newer rules).
Tolerance 1e-9 per channel: both sides compute the same formulas in float64, but in a different
order in places (the plain (r·s)**8 vs repeated squaring, numpy's vs Python's rounding of the ray
setup is identical); observed differences are ~1e-15, so 1e-9 leaves six orders of headroom while
still catching any real shading difference (the smallest term that matters, 1/255 of a level, is 4e-3).
Pixels where a decision is within rounding of flipping (tests/plain.py FRAGILE) are excluded, and
must be rare.
"""

from __future__ import annotations

import numpy as np
import pytest
from plain import render_plain

from minirt import camera
from minirt.rules import PROFILES, TRACE_RULES, flipped
from minirt.scene import load_scene
from minirt.tracer import Tracer

SIZE = 20
TOL = 1e-9


def _compare(scene, rules):
    fast = Tracer(scene, rules).render()
    o, d = camera.primary_rays(scene, rules)
    colors, fragile = render_plain(scene, rules, o, d)
    plain = np.array(colors).reshape(SIZE, SIZE, 3)
    fragile = np.array(fragile).reshape(SIZE, SIZE)
    diff = np.abs(fast.color - plain).max(axis=-1)
    bad = (diff > TOL) & ~fragile
    assert fragile.mean() < 0.02, f"{fragile.sum()} fragile pixels"
    assert not bad.any(), f"{bad.sum()} pixels differ, max {diff[bad].max():.3g} at {np.argwhere(bad)[0]}"
    return diff


@pytest.mark.parametrize("profile", list(PROFILES))
def test_profiles_agree(scene_path, profile):
    scene = load_scene(scene_path).with_overrides(width=SIZE, height=SIZE, samples=1)  # ray for ray
    _compare(scene, PROFILES[profile])


@pytest.mark.parametrize("profile", list(PROFILES))
@pytest.mark.parametrize("rule", TRACE_RULES)  # output rules do not change the traced colour
def test_each_rule_flipped(scene_path, profile, rule):
    scene = load_scene(scene_path).with_overrides(width=SIZE, height=SIZE, samples=1)  # ray for ray
    _compare(scene, flipped(PROFILES[profile], rule))


def test_rules_matter():
    """The comparison is not vacuous: in the rules scene, flipping any rule changes the image."""
    scene = load_scene("scenes/rules.toml").with_overrides(width=48, height=48)
    for profile, rules in PROFILES.items():
        base = Tracer(scene, rules).render().color
        same = [r for r in TRACE_RULES if np.array_equal(base, Tracer(scene, flipped(rules, r)).render().color)]
        assert same == [], profile
