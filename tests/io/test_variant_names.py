"""Variant renders are named by what differs from the scene's own model and never overwrite the plain one."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from support.inproc import minirt

from minirt.io.names import MAX_TAG, contact_sheet_name, render_stem, variant_tag
from minirt.model import rules as R
from minirt.model.scene import load_scene

ROOT = Path(__file__).resolve().parents[2]
EXERCISE = ROOT / "scenes" / "exercise.toml"


def tag_for(profile=None, **rules) -> str:
    plain = load_scene(EXERCISE)
    scene = plain.with_overrides(profile=profile)
    return variant_tag(plain, scene, R.resolve(scene, profile, rules))


def test_tags_name_what_differs():
    assert tag_for() == ""
    assert tag_for(clamp=True) == "clamp=true"
    assert tag_for(clamp=False) == ""  # the scene's own value: the plain render
    assert tag_for(clamp=True, offset=1e-3) == "clamp=true+offset=0.001"  # sorted, values as --rule takes them
    assert tag_for(pixel_shift="0.5,0.25") == "pixel_shift=0.5,0.25"
    assert tag_for(profile="exercise") == ""
    conv = tag_for(profile="conventional")
    assert conv == "profile=conventional"  # the profile's own rules are not listed again
    assert tag_for(profile="conventional", clamp=False).startswith("profile=conventional+clamp=false")


def test_tags_are_safe_file_names_and_bounded():
    plain = load_scene(EXERCISE)
    rules = R.resolve(plain)
    weird = replace(rules, shadow_range="../a b/[x]")
    assert variant_tag(plain, plain, weird) == "shadow_range=.._a_b__x_"
    long = replace(rules, shadow_range="x" * 300)
    t = variant_tag(plain, plain, long)
    assert len(t) == MAX_TAG and t != variant_tag(plain, plain, replace(rules, shadow_range="x" * 299))
    assert render_stem(plain, "reference", "clamp=true") == "exercise.reference+clamp=true"
    assert render_stem(plain, "povray") == "exercise.povray"
    assert contact_sheet_name(plain, "clamp=true") == "exercise.contact+clamp=true.png"


def test_a_variant_render_keeps_the_plain_one(tmp_path):
    def render(*extra):
        # the command's entry point in this process (tests/support/inproc.py)
        size = ["--width", "16", "--height", "12"]
        p = minirt("render", EXERCISE, "-o", tmp_path, "-b", "reference,embree", *size, "-q", *extra)
        assert p.returncode == 0, p.stderr
        return {f.name: f.read_bytes() for f in tmp_path.iterdir()}

    plain = render()
    both = render("--rule", "clamp=true")
    for name, data in plain.items():
        assert both[name] == data, name  # untouched
    added = sorted(set(both) - set(plain))
    assert added == [
        "exercise.contact+clamp=true.png",
        "exercise.embree+clamp=true.exr",
        "exercise.embree+clamp=true.json",
        "exercise.reference+clamp=true.exr",
        "exercise.reference+clamp=true.json",
        "exercise.reference+clamp=true.png",
    ]
    assert b'"variant": "clamp=true"' in both["exercise.reference+clamp=true.json"]
    assert b'"clamp": true' in both["exercise.reference+clamp=true.json"]
    assert b'"clamp": false' in plain["exercise.reference.json"]
