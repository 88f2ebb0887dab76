"""check's rule diagnosis: which rule settings explain an oracle's image (minirt.diagnose.search), beside the rule
effects (what each rule the oracle cannot follow changes in the reference). On scenes/rules.toml, where
every rule shows, POV-Ray's diagnosis must name the rules it declares (``adapt``) that differ from the
exercise's -- those this scene shows -- with their declared values, and leave few pixels unexplained; the
block is in check's JSON and its sentence on the report page; Mitsuba (a physical model) and Embree (no
colour) keep the rule effects only."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from minirt.harness import backends
from minirt.harness.results import CheckResult
from minirt.harness.run import check_scene
from minirt.model import bitmap
from minirt.model.rules import format_rule_value, resolve
from minirt.model.scene import load_scene
from minirt.pages import report
from minirt.reference.tracer import render

ROOT = Path(__file__).resolve().parents[2]
SCENE = ROOT / "scenes" / "rules.toml"
SIZE = (48, 48)


@pytest.fixture(scope="module")
def checked():
    return check_scene(SCENE, ["povray", "mitsuba", "embree"], SIZE)


def shown_by_scene(rules, followed) -> set[str]:
    """The rules POV-Ray follows differently from the scene's that change, taken back singly from POV-Ray's
    rules, more than a handful of pixels by more than one level: those its image can show."""
    sc = load_scene(SCENE).with_overrides(width=SIZE[0], height=SIZE[1], samples=1)
    base = bitmap.encode(render(sc, followed).color).astype(int)
    out = set()
    for name in rules.differs(followed):
        alt = bitmap.encode(render(sc, replace(followed, **{name: getattr(rules, name)})).color).astype(int)
        if (np.abs(alt - base).max(-1) > 1).sum() >= 10:
            out.add(name)
    return out


def test_povray_diagnosis_names_the_rules_it_follows(checked):
    b = checked.backends["povray"]
    assert b.verdict == "pass", b.reason
    d = b.rule_diagnosis
    assert d.ran
    sc = load_scene(SCENE).with_overrides(width=SIZE[0], height=SIZE[1])
    rules = resolve(sc)
    followed = backends.get("povray").adapt(rules)
    declared = {n: format_rule_value(n, getattr(followed, n)) for n in rules.differs(followed)}
    assert d.declared == declared
    shown = shown_by_scene(rules, followed)
    assert len(shown) >= 3, shown  # the scene is made to show the rules
    assert shown <= set(d.rules_explaining), (shown, d.rules_explaining)
    # every setting named is one POV-Ray declares, with its value: nothing undeclared
    assert d.rules_explaining.items() <= declared.items() and not d.undeclared
    assert all(d.explained[k] > 0 for k in d.rules_explaining)
    assert d.as_given_pixels > 0.3 * d.pixels  # POV-Ray's image is far from the exercise's ...
    assert d.mismatch_pixels <= 0.005 * d.pixels  # ... and the diagnosis explains nearly all of it
    assert d.unexplained_mask.sum() == d.mismatch_pixels
    # the rule effects are kept as they were: per rule POV-Ray cannot follow, pixels it changes singly
    assert set(b.rule_effects) == set(declared) and b.rule_effects is b.rules


def test_physical_and_geometry_oracles_keep_the_rule_effects_only(checked):
    for name, why in (("mitsuba", "physical model"), ("embree", "does not shade")):
        b = checked.backends[name]
        assert not b.rule_diagnosis.ran and why in b.rule_diagnosis.reason
        assert b.as_dict()["rule_diagnosis"] == {"ran": False, "reason": b.rule_diagnosis.reason}
        assert b.as_dict()["rule_effects"] == b.rules


def test_report_shows_the_diagnosis_line(checked, tmp_path):
    result = CheckResult(verdict=checked.verdict, scenes=[checked])
    html = report.write_report(result, tmp_path, command="x", date="d").read_text()
    d = checked.backends["povray"].rule_diagnosis
    first = max(d.explained, key=lambda k: (d.explained[k], k))
    assert "POV-Ray&#39;s image is explained by: " in html and f"{first}={d.rules_explaining[first]}" in html
    n = d.mismatch_pixels
    assert f"({n} pixel{'s' if n != 1 else ''} unexplained)" in html
    assert "Rule effects" in html and "Rule diagnosis" in html
    data = json.loads((tmp_path / "report.json").read_text())
    assert data["scenes"][0]["backends"]["povray"]["rule_diagnosis"]["rules_explaining"] == d.rules_explaining


def test_check_json_has_the_diagnosis_block(tmp_path):
    j = tmp_path / "r.json"
    p = subprocess.run(
        [sys.executable, "-m", "minirt", "check", "scenes/rules.toml", "-b", "povray", "--size", "32x32",
         "--json", str(j), "-q"],
        capture_output=True, text=True, cwd=ROOT, timeout=300,
    )  # fmt: skip
    assert p.returncode == 0, p.stderr
    b = json.loads(j.read_text())["scenes"][0]["backends"]["povray"]
    d = b["rule_diagnosis"]
    keys = {"ran", "rules_explaining", "explained", "mismatch_pixels", "as_given_pixels", "declared", "undeclared"}
    assert keys <= set(d) and d["ran"] is True
    assert d["rules_explaining"] and set(d["explained"]) == set(d["rules_explaining"])
    assert set(b["rule_effects"]) == set(d["declared"])


def test_no_search_when_the_oracle_draws_the_scene_rules(tmp_path):
    """An oracle image equal to the scene's rules' within a level: nothing to explain, one render."""
    sc = check_scene(ROOT / "scenes" / "soft.toml", ["povray"], (24, 24))
    d = sc.backends["povray"].rule_diagnosis
    assert d.ran and not d.rules_explaining and d.mismatch_pixels == 0 and d.as_given_pixels == 0
    assert "no search needed" in d.reason and d.renders <= 1


def test_settings_no_pixel_shows_are_not_findings():
    """shadows.toml (black background) shows only shadow_range and clamp: a whole-profile step may carry
    rules this image cannot tell (the background rule over black); they are set apart, never undeclared."""
    sc = check_scene(ROOT / "scenes" / "shadows.toml", ["povray"], SIZE)
    d = sc.backends["povray"].rule_diagnosis
    assert d.ran and d.rules_explaining.get("shadow_range") == "to-light"
    assert not d.undeclared and "background" not in d.rules_explaining
    assert all(n > 0 for n in d.explained.values()) and set(d.explained) == set(d.rules_explaining)
    assert not set(d.cannot_tell) & set(d.rules_explaining)


@pytest.mark.parametrize(("busy", "max_balls", "threads"), [(True, 16, 1), (False, 16, 2), (True, 1, 2), (None, 16, 2)])
def test_the_diagnosis_runs_on_one_jit_thread_beside_other_renders_on_few_balls(monkeypatch, busy, max_balls, threads):
    """While other renders of a run are still going (``busy``) and the scene's candidate kernels are short (at
    most FULL_RENDER_BALLS balls), the rule diagnosis runs on one Dr.Jit thread, and the pool is as it was
    after; alone, or on many balls, on the pool as it is."""
    import drjit as dr

    from minirt.diagnose import variants as variants_mod
    from minirt.harness import compare
    from minirt.harness.references import ReferenceCache

    scene = load_scene(SCENE).with_overrides(width=SIZE[0], height=SIZE[1])
    rules = resolve(scene)
    followed = replace(rules, clamp=True)  # an image the scene's rules do not draw: a search runs
    drawn = render(scene, followed)
    seen = []
    real = compare.diagnose_oracle
    monkeypatch.setattr(compare, "diagnose_oracle", lambda *a: seen.append(dr.thread_count()) or real(*a))
    monkeypatch.setattr(variants_mod, "FULL_RENDER_BALLS", max_balls)
    before = dr.thread_count()
    dr.set_thread_count(2)
    try:
        flag = None if busy is None else (lambda: busy)
        bc = compare.check_backend(scene, rules, "povray", ReferenceCache(scene), rendered=drawn, busy=flag)
        after = dr.thread_count()
    finally:
        dr.set_thread_count(before)
    assert seen == [threads] and after == 2
    assert bc.rule_diagnosis.ran and "clamp" in bc.rule_diagnosis.rules_explaining


@pytest.mark.parametrize(
    ("names", "max_balls", "threads"), [(["povray"], 16, 1), (["povray"], 1, 2), (["embree"], 16, 2)]
)
def test_a_run_checks_few_balls_on_one_jit_thread_beside_other_processes(monkeypatch, names, max_balls, threads):
    """A run whose renders started ahead share the cores (POV-Ray's) checks a scene of short kernels (at most
    FULL_RENDER_BALLS balls) -- its references, its oracles' checks -- on one Dr.Jit thread, and leaves the
    pool as it was; on many balls, or with no render of another process, on the pool as it is."""
    import drjit as dr

    from minirt.diagnose import variants as variants_mod
    from minirt.harness import run as run_module

    seen = []
    real = run_module.check_backend
    monkeypatch.setattr(run_module, "check_backend", lambda *a, **k: seen.append(dr.thread_count()) or real(*a, **k))
    monkeypatch.setattr(variants_mod, "FULL_RENDER_BALLS", max_balls)
    before = dr.thread_count()
    dr.set_thread_count(2)
    try:
        res = run_module.run([SCENE, ROOT / "scenes" / "three_balls.toml"], ["reference", *names], SIZE)
        after = dr.thread_count()
    finally:
        dr.set_thread_count(before)
    assert seen == [threads, threads] and after == 2 and res.verdict == "pass"
