"""The judge of last resort (minirt.harness.judge): a float oracle's disagreement settled against it, a
known-wrong reference caught, and no correct reference ever blamed.

grazing_4242_3 (``minirt fuzz --count 24 --seed 4242 --size 32x32``) is the campaign's one false alarm
before the judge: POV-Ray lights 10 pixels of row 16 that the reference leaves in shadow. Exact arithmetic
says the reference is right -- the shadow ray from the wall (plane 1) crosses the nearly horizontal plane 0
between 2.4e-4 and 9.9e-4 from its origin, inside POV-Ray's own shadow tolerance of 1e-3 -- so the FAIL is
POV-Ray's imprecision.
"""

from __future__ import annotations

import numpy as np
import pytest
from support.exact_cases import FLOOR, TANGENT_BALL, exact_case

from minirt.campaign.campaign import DEFECTS, _DefectiveReference, scenes
from minirt.harness import backends, judge
from minirt.harness.compare import check_backend
from minirt.harness.references import ReferenceCache
from minirt.model.bundled import find_scene
from minirt.model.rules import resolve
from minirt.model.scene import load_scene, parse_scene
from minirt.oracles.exact.render import PRECISIONS, PixelTracer

CERTIFIED = judge.certified_oracle()


def _grazing():
    (_, _, text), *_ = [s for s in scenes(24, 4242, ["random", "start", "grazing", "contact", "far", "scaled", "f32"],
                                          (32, 32)) if s[0] == "grazing_4242_3"]  # fmt: skip
    return parse_scene(text, "grazing_4242_3.toml")


def test_the_certified_oracle_is_found_by_capability():
    assert CERTIFIED is not None and getattr(backends.get(CERTIFIED), "certified", False)


def test_povrays_disagreement_on_grazing_4242_3_is_its_imprecision():
    scene = _grazing()
    rules = resolve(scene)
    bc = check_backend(scene, rules, "povray", ReferenceCache(scene), explain=False)
    assert bc.verdict == "fail" and "10 pixel(s) differ" in bc.reason  # the false alarm, as it was
    bc = judge.review(bc, scene, rules)
    assert bc.verdict == "warn" and "povray's imprecision" in bc.reason
    fig = bc.checks["judge"].figures
    assert fig["reference_wrong"] == 0 and fig["oracle_imprecise"] == 10 and fig["unsettled"] == 0
    assert fig["oracle_imprecise_first"][0] == [0, 16]
    # the cause: the shadow ray meets plane 0 within POV-Ray's 1e-3 shadow tolerance of its origin
    followed = backends.rules_for("povray", rules)
    tracer = PixelTracer(scene, followed)
    m, levels, _ = tracer.levels(16 * 32, 0.5, 0.5, PRECISIONS[0])
    assert levels[0].hit.shape == 1 and levels[0].lit is False
    n0, a0 = m.planes[0][0], m.planes[0][1]
    p = levels[0].p
    below = a0 - sum(n0[i] * p[i] for i in range(3))
    assert 1e-4 < float(below.mid()) < 1e-3


def test_a_float_oracles_fail_stands_where_the_reference_is_certified_wrong():
    scene = load_scene(find_scene("shadows")).with_overrides(width=24, height=24)
    rules = resolve(scene)
    bad = _DefectiveReference(scene, DEFECTS["light-moved"])
    bc = judge.review(check_backend(scene, rules, "povray", bad, explain=False), scene, rules)
    assert bc.verdict == "fail" and bc.checks["judge"].verdict == "fail"
    assert bc.checks["judge"].figures["reference_wrong"] > 0


@pytest.mark.parametrize("defect", ["no-shadows", "normal-flipped", "ids-swapped", "specular-exponent"])
def test_the_certified_oracles_check_fails_exactly_where_the_reference_is_wrong(defect):
    scene = load_scene(find_scene("three_balls")).with_overrides(width=24, height=24)
    rules = resolve(scene)
    clean = judge.certify(check_backend(scene, rules, CERTIFIED, ReferenceCache(scene), explain=False))
    assert clean.verdict == "pass" and clean.checks["judge"].figures["reference_wrong"] == 0
    bad = _DefectiveReference(scene, DEFECTS[defect])
    bc = judge.certify(check_backend(scene, rules, CERTIFIED, bad, rendered=clean.result, explain=False))
    assert bc.verdict == "fail" and bc.checks["judge"].figures["reference_wrong"] > 0, bc.reason


def test_no_correct_reference_is_blamed():
    """Generated hard scenes of every family, under the scene's rules and each float oracle's: the reference
    is never certified wrong (the robust bounds hold its float64 answers), and most pixels are settled."""
    fams = ["random", "start", "grazing", "contact", "far", "scaled", "f32"]
    settled = total = 0
    for _, _, text in scenes(14, 1717, fams, (16, 16)):
        scene = parse_scene(text, "s.toml")
        rules = resolve(scene)
        for rr in {rules} | {backends.rules_for(n, rules) for n in ("povray", "mitsuba", "embree")}:
            exact = judge.render_certified(scene, rr)
            r = judge.rule(ReferenceCache(scene).get(rr, samples=1), exact)
            assert not r.reference_wrong.any(), (scene.name, rr, r.figures())
            settled, total = settled + int(r.settled.sum()), total + r.settled.size
    assert settled > 0.9 * total


def test_a_pixel_within_the_widening_is_not_settled():
    # the shadow ray's tangent ball (test_oracle_exact): an exact tie, and so never settled
    scene = exact_case(f"{FLOOR}\n{TANGENT_BALL}")
    rules = resolve(scene)
    exact = judge.render_certified(scene, rules)
    r = judge.rule(ReferenceCache(scene).get(rules, samples=1), exact)
    assert not r.settled[3, 2] and r.settled[0, 0]
    assert np.array_equal(r.reference_wrong, np.zeros_like(r.reference_wrong))


def test_a_change_inside_a_float_oracles_tolerance_fails_where_the_judge_certifies_it():
    # light-moved on grazing_31337_0 changes only Mitsuba's diffuse term (its rules, its model), within
    # Mitsuba's own tolerance: its check passes; the judge, under Mitsuba's rules, certifies the moved light's
    # colours wrong -- a FAIL
    ((_, _, text),) = [s for s in scenes(3, 31337, ["random", "start", "grazing"], (24, 24)) if s[1] == "grazing"]
    scene = parse_scene(text, "grazing_31337_0.toml")
    rules = resolve(scene)
    bad = _DefectiveReference(scene, DEFECTS["light-moved"])
    bc = check_backend(scene, rules, "mitsuba", bad, explain=False)
    assert bc.verdict != "fail"
    bc = judge.review(bc, scene, rules)
    assert bc.verdict == "fail" and bc.reason.startswith("judge: the reference certified wrong")
    assert bc.checks["judge"].figures["reference_wrong_by_kind"]["color"] > 0


def test_probe_shows_the_certified_values_beside_the_references():
    from support.inproc import minirt

    p = minirt("probe", "exercise", "100", "140", "--width", "256", "--height", "256", "--certified", "--json")
    assert p.returncode == 0, p.stderr
    import json

    d = json.loads(p.stdout)
    c = d["certified"]
    assert c["backend"] == CERTIFIED and c["bits"] == PRECISIONS[0] and c["robust"] and c["tie"] is None
    assert [lvl["hit"]["id"] for lvl in c["levels"] if lvl["hit"]] == [0, 1]
    assert max(abs(a - b) for a, b in zip(c["color"], d["color"], strict=True)) < 1e-12
    text = minirt("probe", "exercise", "100", "140", "--certified").stdout
    assert f"certified ({CERTIFIED}, certified at 128 bits):" in text and "robust" in text
