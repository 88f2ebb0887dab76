"""The fast tracer against the plain, recursive transcription of the pseudo-code.

float64, every bundled scene, every profile, and every trace rule flipped singly from each profile
(tests/model/test_rules_more.py: every candidate value of the newer rules).
Tolerance 1e-9 per channel: both sides compute the same formulas in float64, but in a different
order in places (the plain (r·s)**8 vs repeated squaring, numpy's vs Python's rounding of the ray
setup is identical); observed differences are ~1e-15, so 1e-9 leaves six orders of headroom while
still catching any real shading difference (the smallest term that matters, 1/255 of a level, is 4e-3).
Pixels where a decision is within rounding of flipping (tests/support/plain.py FRAGILE) are excluded, and
must be rare.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from support.versus_plain import SIZE, _compare

from minirt.model.rules import PROFILES, TRACE_RULES, flipped
from minirt.model.scene import load_scene
from minirt.reference.tracer import Tracer


@pytest.mark.parametrize("profile", list(PROFILES))
def test_profiles_agree(scene_path, profile):
    scene = load_scene(scene_path).with_overrides(width=SIZE, height=SIZE, samples=1)  # ray for ray
    _compare(scene, PROFILES[profile])


@pytest.mark.parametrize("profile", list(PROFILES))
@pytest.mark.parametrize("rule", TRACE_RULES)  # output rules do not change the traced colour
def test_each_rule_flipped(scene_path, profile, rule):
    scene = load_scene(scene_path).with_overrides(width=SIZE, height=SIZE, samples=1)  # ray for ray
    _compare(scene, flipped(PROFILES[profile], rule))


# Rules that cannot change the rules scene, and why: its planes are written with unit normals; under the
# exercise's unclamped highlight (r·s)^8 = (r·(-s))^8, an even power; under two_sided (conventional) every
# normal is turned to face the ray, whichever way the ball's pointed.
SAME_IN_RULES = {"raw_normals_plane": "every profile", "ball_normal": "conventional", "specular_s": "exercise"}


def test_rules_matter():
    """The comparison is not vacuous: in the rules scene, flipping any rule changes the image (but for
    SAME_IN_RULES, which colored_specular, with a plane's normal written [0, 2, 0], and an odd exponent show)."""
    scene = load_scene("scenes/rules.toml").with_overrides(width=48, height=48)
    for profile, rules in PROFILES.items():
        base = Tracer(scene, rules).render().color
        same = [r for r in TRACE_RULES if np.array_equal(base, Tracer(scene, flipped(rules, r)).render().color)]
        expected = [r for r, where in SAME_IN_RULES.items() if where in ("every profile", profile)]
        assert sorted(same) == sorted(expected), profile
    other = load_scene("scenes/colored_specular.toml").with_overrides(width=48, height=48)
    ex = PROFILES["exercise"]
    base = Tracer(other, ex).render().color
    assert not np.array_equal(base, Tracer(other, flipped(ex, "raw_normals_plane")).render().color)
    odd = replace(ex, specular_exponent=7)
    assert not np.array_equal(
        Tracer(other, odd).render().color, Tracer(other, flipped(odd, "specular_s")).render().color
    )
