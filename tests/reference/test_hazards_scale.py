"""The offset-hazard warnings at scale (minirt.reference.hazards): the grid that finds the balls near each
secondary ray's start gives the same per-pixel findings, and so the same warning lines, as the
definition -- every ray against every shape, each ray kind on its own -- on every bundled scene and
on scenes of every fuzz family, under the rules that change the segments tested."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from minirt.campaign.families import FAMILIES, scene_text
from minirt.model.rules import resolve
from minirt.model.scene import Ball, load_scene, parse_scene
from minirt.reference import hazards
from minirt.reference.tracer import render

ROOT = Path(__file__).resolve().parents[2]
BUNDLED = sorted((ROOT / "scenes").glob("*.toml"))
# The scene's own rules; offsets along the new ray (two segments per hit); an offset large enough to jump
# into neighbours (near contacts then cover many pixels), with back faces lit.
RULES = ({}, {"offset_along": "ray", "offset": 1e-4}, {"two_sided": True, "offset": 0.05})


def judge_by_definition(scene, rules, g, precision, balls=None):
    """What hazards._judge computed before the grid: each ray kind in turn over every hit, every shape
    but the hit's own tested for a sign change of its implicit function between p and p + offset v."""
    off = float(rules.offset)
    rounding = hazards.UNIT_ROUNDOFF[precision] * np.abs(g["p"]).sum(axis=1)
    below = np.zeros(len(g["p"]), dtype=bool)
    jumped = np.zeros(len(g["p"]), dtype=bool)
    for kind in ("shadow", "reflection"):
        if kind not in g:
            continue
        spawn = g.get("reflects", np.ones(len(g["p"]), dtype=bool)) if kind == "reflection" else True
        v = g[kind] if rules.offset_along == "ray" else g["n"]
        below |= spawn & (off * np.abs(np.einsum("ij,ij->i", v, g["n"])) < rounding)
        q = g["p"] + off * v
        crossed = np.zeros(len(g["p"]), dtype=bool)
        with np.errstate(invalid="ignore"):
            for k, shape in enumerate(scene.shapes):
                f_p, f_q = hazards._surface(shape, g["p"]), hazards._surface(shape, q)
                crossed |= (g["id"] != k) & (np.sign(f_p) != np.sign(f_q))
        jumped |= spawn & crossed
    return {"below": below, "jumped": jumped, "rounding": rounding}


def warnings_by_definition(scene, rules, res, precision):
    """hazards.offset_warnings as it was before the grid: every hit at once, judged by the definition."""
    if rules.offset == "error-bound" or res.hit is None or not res.hit.any():
        return []
    g = hazards._secondary(scene, rules, res)
    if "shadow" not in g and "reflection" not in g:
        return []
    j = judge_by_definition(scene, rules, g, precision)
    off, lines = float(rules.offset), []
    name = "float32" if precision == "f32" else "float64"
    along = "along the new ray" if rules.offset_along == "ray" else "along the normal"
    if j["below"].any():
        worst = float(j["rounding"][j["below"]].max())
        lines.append(
            f"offset {off:g} ({along}) is below the hit point's {name} rounding (up to {worst:.3g}) on "
            f"{int(j['below'].sum())} pixel(s): their shadow or reflection rays may start behind the surface "
            '(acne); the scene\'s scale, not its content, then decides the image (offset = "error-bound" does not)'
        )
    if j["jumped"].any():
        lines.append(
            f"offset {off:g} ({along}) jumps over another shape's surface on {int(j['jumped'].sum())} pixel(s) "
            "(a near contact closer than the offset): their shadow or reflection rays start beyond it and miss it"
        )
    return lines


def compare(scene, rules, precision="f64") -> tuple[int, int]:
    """Asserts the per-pixel findings and the warning lines equal the definition's; (pixels jumped, hits)."""
    res = render(scene, rules, precision=precision)
    if rules.offset == "error-bound" or not res.hit.any():
        return 0, 0
    g = hazards._secondary(scene, rules, res)
    if "shadow" not in g and "reflection" not in g:
        return 0, 0
    got = hazards._judge(scene, rules, g, precision)
    want = judge_by_definition(scene, rules, g, precision)
    for key in ("below", "jumped"):
        np.testing.assert_array_equal(got[key], want[key], err_msg=f"{scene.name}: {key}")
    assert hazards.offset_warnings(scene, rules, res, precision) == warnings_by_definition(scene, rules, res, precision)
    return int(want["jumped"].sum()), len(g["p"])


@pytest.mark.parametrize("path", BUNDLED, ids=[p.stem for p in BUNDLED])
@pytest.mark.parametrize("overrides", RULES, ids=["default", "along-ray", "two-sided-0.05"])
def test_bundled_scenes_warn_as_the_definition_does(path, overrides):
    scene = load_scene(path)
    compare(scene, resolve(scene, None, dict(overrides)))


@pytest.mark.parametrize("family", list(FAMILIES))
def test_every_fuzz_family_warns_as_the_definition_does(family):
    jumped = 0
    for index in range(8):
        scene = parse_scene(scene_text(family, 37, index, 32, 32))
        for overrides in RULES:
            precision = "f32" if family == "f32" and not overrides else "f64"
            rules = resolve(scene, None, dict(overrides))
            jumped += compare(scene, rules, precision)[0]
    if family == "contact":  # near contacts closer than the offset: the case is there to be found
        assert jumped > 0


def _jump_inputs(scene, offset=0.05):
    """The rules (a numeric offset large enough to jump into neighbours), the secondary rays' starts of a
    render, the balls, and each start before and after the offset; asserts the grid (not its fallback, the
    tree) answers the scene."""
    rules = resolve(scene, None, {"offset": offset})
    g = hazards._secondary(scene, rules, render(scene, rules))
    balls = hazards._Balls.of(scene)
    p = g["p"]
    q = p + offset * g["n"]
    assert hazards._grid_pairs(balls, p, q) is not None
    return rules, g, balls, p, q


def test_the_grid_answers_and_can_disagree_with_a_wrong_answer():
    """The grid (not its fallback, the tree) answers a scene of touching balls, and a candidate list that
    misses one ball makes the answer differ: the comparison above can fail."""
    scene = parse_scene(scene_text("contact", 37, 3, 64, 64))
    rules, g, balls, p, q = _jump_inputs(scene)
    right = hazards._jumped(scene, p, q, g["id"], balls)
    want = judge_by_definition(scene, rules, g, "f64")["jumped"]
    np.testing.assert_array_equal(right, want)
    assert right.any()
    crossed_ball = next(k for k in np.unique(g["id"]) if isinstance(scene.shapes[k], Ball))
    original = hazards._grid_pairs

    def missing_one(b, p_, q_):
        pp, bb = original(b, p_, q_)
        keep = np.asarray(b.ids)[bb] != crossed_ball
        return pp[keep], bb[keep]

    hazards._grid_pairs = missing_one
    try:
        wrong = hazards._jumped(scene, p, q, g["id"], balls)
    finally:
        hazards._grid_pairs = original
    assert (wrong != want).any()


def test_many_balls_on_the_grid_match_the_tree():
    """200 random balls over a floor (the benchmark's layout, small): grid and tree find the same jumps."""
    from minirt.campaign.generate import balls_scene

    scene = parse_scene(balls_scene(200, seed=3, width=96, height=96))
    _, g, balls, p, q = _jump_inputs(scene)
    grid = hazards._jumped(scene, p, q, g["id"], balls)
    tree = hazards._jumped_tree(balls, p, q, g["id"])
    with np.errstate(invalid="ignore"):
        planes = np.zeros(len(p), dtype=bool)
        for k, s in enumerate(scene.shapes):
            if not isinstance(s, Ball):
                planes |= (g["id"] != k) & (np.sign(hazards._surface(s, p)) != np.sign(hazards._surface(s, q)))
    np.testing.assert_array_equal(grid, tree | planes)
    assert 0 < grid.sum() < len(p)


def test_hits_judged_chunk_by_chunk_give_the_same_lines(monkeypatch):
    """offset_warnings takes the hits HAZARD_CHUNK at a time; chunks of 7 hits give the lines of one."""
    scene = parse_scene(scene_text("contact", 37, 3, 48, 48))
    rules = resolve(scene, None, {"offset": 0.05})
    res = render(scene, rules)
    lines = hazards.offset_warnings(scene, rules, res)
    assert lines and lines == warnings_by_definition(scene, rules, res, "f64")
    monkeypatch.setattr(hazards, "HAZARD_CHUNK", 7)
    assert hazards.offset_warnings(scene, rules, res) == lines
