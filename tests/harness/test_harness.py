"""The harness tests itself: known defects injected into a reference result must be caught with the
right verdict, and identical inputs, or inputs differing only inside the silhouette band, must pass."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from support.synthetic import SIZE, candidate, reference

from minirt.harness.geometry import check_geometry, preflight
from minirt.harness.shading import check_shading
from minirt.reference.tracer import Tracer


@pytest.fixture(scope="module")
def setup():
    return reference()


def verdicts(scene, rules, ref, cand):
    pre = preflight(ref, cand, need_color=True)
    if pre.verdict != "pass":
        return {"preflight": pre}
    geom = check_geometry(scene, rules, ref, cand)
    return {"preflight": pre, "geometry": geom, "shading": check_shading(scene, ref, cand, geom)}


def test_identical_passes(setup):
    scene, rules, ref = setup
    v = verdicts(scene, rules, ref, candidate(ref))
    assert {k: c.verdict for k, c in v.items()} == {"preflight": "pass", "geometry": "pass", "shading": "pass"}


def test_differences_inside_the_band_pass(setup):
    scene, rules, ref = setup
    cand = candidate(ref, band_eps=2e-2)
    geom = check_geometry(scene, rules, ref, cand)
    band = geom.images["band"] & ref.hit
    assert band.sum() > 10
    cand.hit = ref.hit & ~band  # the oracle misses every ray that grazes a silhouette
    cand.shape_id = np.where(cand.hit, ref.shape_id, -1)
    v = verdicts(scene, rules, ref, cand)
    assert v["geometry"].verdict == "pass"
    assert v["geometry"].figures["mask_mismatch"] == band.sum() > 0
    assert v["geometry"].figures["mask_mismatch_outside_band"] == 0


def _all_buffers(r, f):
    for name in ("hit", "shape_id", "t", "position", "normal", "color"):
        setattr(r, name, f(getattr(r, name)))
    r.terms = {k: f(v) for k, v in r.terms.items()}
    return r


DEFECTS = {
    "one-pixel shift": (lambda r, s: _all_buffers(r, lambda a: np.roll(a, 1, axis=1)), "geometry"),
    "horizontal mirror": (lambda r, s: _all_buffers(r, lambda a: a[:, ::-1].copy()), "geometry"),
    "flipped normals": (lambda r, s: setattr(r, "normal", -r.normal) or r, "geometry"),
    "wrong shape id": (lambda r, s: setattr(r, "shape_id", np.where(r.shape_id == 0, 1, r.shape_id)) or r, "geometry"),
    # (NaN at a hit off the band: row SIZE // 2 is the floor's horizon, in the band, where NaN is not judged)
    "NaN pixel": (lambda r, s: r.color.__setitem__((SIZE // 2 + 6, SIZE // 2, 0), np.nan) or r, "geometry"),
    "NaN position": (lambda r, s: r.position.__setitem__((SIZE // 2 + 6, SIZE // 2, 1), np.nan) or r, "geometry"),
    "wrong image size": (
        lambda r, s: (_all_buffers(r, lambda a: a[:-1]) and setattr(r, "height", SIZE - 1)) or r,
        "preflight",
    ),
    "+5% on one shape": (
        lambda r, s: setattr(r, "color", np.where((r.shape_id == 0)[..., None], r.color * 1.05, r.color)) or r,
        "shading",
    ),
}


@pytest.mark.parametrize("defect", list(DEFECTS))
def test_defect_is_caught(setup, defect):
    scene, rules, ref = setup
    inject, where = DEFECTS[defect]
    cand = inject(candidate(ref), scene)
    v = verdicts(scene, rules, ref, cand)
    assert where in v, f"stopped before {where}: {[(k, c.verdict, c.reason) for k, c in v.items()]}"
    assert v[where].verdict == "fail", (defect, v[where].figures)
    assert v[where].reason


def test_missing_shadow_is_caught(setup):
    scene, rules, ref = setup
    tr = Tracer(scene, rules)
    tr.effects = replace(tr.effects, shadows=False)  # a tracer that forgets shadow rays
    cand = candidate(ref)
    cand.color = tr.render().color
    v = verdicts(scene, rules, ref, cand)
    assert v["geometry"].verdict == "pass"
    assert v["shading"].verdict == "fail"
    assert v["shading"].figures["color8_over_1"] > 10  # the shadowed floor and small ball, lit
