"""The regression suite: every bundled scene against every oracle, through the harness.

Each backend must PASS, or SKIP for a stated, expected reason. A failure leaves the evidence
(reference, oracle, mask and error images, the figures) under tests/_evidence/<scene>/<backend>/.
"""

from __future__ import annotations

import pytest
from evidence import dump_check

from minirt import harness
from oracles import names as oracle_names

SIZE = (64, 64)
# (scene, backend) -> a phrase the SKIP reason must contain
EXPECTED_SKIPS: dict[tuple[str, str], str] = {}  # none: every oracle renders every bundled scene


@pytest.mark.slow
def test_scene_against_every_oracle(scene_path):
    sc = harness.check_scene(scene_path, ["reference", *oracle_names()], SIZE)
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
    sc = harness.check_scene("scenes/shadows.toml", ["povray"], (48, 48))
    b = sc.backends["povray"]
    assert b.verdict == "pass"
    assert set(b.rules) == {"shadow_range", "near_root_only", "two_sided", "clamp", "offset"}
    assert b.rules["shadow_range"] > 100  # the ball beyond the light darkens the big ball
    assert b.rule_masks["shadow_range"].sum() == b.rules["shadow_range"]
