"""Candidates traced together (minirt.reference.values.Candidates, VariantCache.prefetch): each ray follows its
own candidate's rules, so a batch gives every candidate the same bits as tracing it alone -- and a rule the
kernel compiles in is never taken from the wrong candidate."""

from __future__ import annotations

from dataclasses import replace

import drjit as dr
import numpy as np
import pytest

from minirt.cli.options import load
from minirt.diagnose.variants import VariantCache
from minirt.model.bundled import find_scene
from minirt.reference.tracer import Tracer
from minirt.reference.values import PER_RAY, SWITCHES, Candidates, Divergent

W, H = 40, 30


def _single(scene, rules, idx, precision: str = "f64") -> np.ndarray:
    """The candidate alone, one rule set in the tracer (opaque run-time values, not a batch's tables)."""
    tr = Tracer(scene, rules, precision=precision, runtime=True)
    o, d = tr.primary_rays(idx)
    with dr.scoped_set_flag(dr.JitFlag.FastMath, False):
        color, _ = tr.trace(o, d, tree=True)
    return tr.to_numpy3(color).copy()


def _moves(rules):
    """One change of every per-ray rule, and some pairs."""
    return [
        rules,
        replace(rules, specular_exponent=16),
        replace(rules, specular_exponent=3),
        replace(rules, two_sided=True),
        replace(rules, clamp=True),
        replace(rules, clamp="specular", specular_exponent=5),
        replace(rules, pixel_sample="center"),
        replace(rules, pixel_shift=(0.5, -1.0)),
        replace(rules, ray_origin="camera"),
        replace(rules, near_root_only=False),
        replace(rules, offset=1e-4, offset_along="ray"),
        replace(rules, offset=0.0),
        replace(rules, t_max=7.5),
        replace(rules, hit_point="origin"),
        replace(rules, ball_normal="inward", two_sided=False),
        replace(rules, light="direction"),
        replace(rules, specular_s="-s", specular_exponent=7),
        replace(rules, raw_normals_ball="shading"),
        replace(rules, raw_normals_plane="both"),
        replace(rules, raw_normals_ball="reflection", pixel_sample="center"),
        replace(rules, shadow_rays=False),
        replace(rules, background="none"),
        replace(rules, background="on-hit", clamp=True),
        replace(rules, shadow_range="to-light"),
        replace(rules, shadow_range="to-light", two_sided=True, shadow_rays=False),
        replace(rules, offset="error-bound", offset_along="normal"),
        replace(rules, offset="error-bound", offset_along="normal", near_root_only=False, shadow_range="to-light"),
    ]


@pytest.mark.parametrize("name", ["rules", "three_balls", "exercise"])
def test_a_batch_gives_each_candidate_its_own_bits(name):
    scene, rules = load(find_scene(name), W, H, None, None, [])
    idx = np.arange(0, W * H, 3)
    cands = _moves(rules)
    vc = VariantCache(share=False)
    batch = vc._trace_many(scene, cands, idx)
    for c, v in zip(cands, batch, strict=True):
        alone = _single(scene, c, idx)
        assert np.array_equal(v.color.view(np.uint64), alone.view(np.uint64)), c.differs(rules)


@pytest.mark.parametrize("name", ["rules", "three_balls"])
def test_a_float32_batch_gives_each_candidate_its_own_bits(name):
    """A search step's float32 twins are traced together (``prefetch32``): each as alone in float32."""
    scene, rules = load(find_scene(name), W, H, None, None, [])
    idx = np.arange(0, W * H, 3)
    cands = list(dict.fromkeys(c.traced() for c in _moves(rules)))
    vc = VariantCache(share=False)
    calls, many = [], vc._trace_many
    vc._trace_many = lambda *a, **k: calls.append(len(a[1])) or many(*a, **k)
    vc.prefetch32(scene, cands, idx)
    assert calls == [len(cands)]  # one kernel for them all
    for c in cands:
        got = vc.subset32(scene, c, idx).color
        assert np.array_equal(got.view(np.uint64), _single(scene, c, idx, "f32").view(np.uint64)), c.differs(rules)
    assert calls == [len(cands)]  # and each read from the batch, none traced again


def test_whole_renders_made_together_are_what_get_makes_alone():
    """A joint diagnosis' renders traced together (``prefetch_whole``, float32 twins too) and kept: each the
    bits ``get(f32=True)`` gives it alone -- colour, shadow flags, float32 image and its flips."""
    scene, rules = load(find_scene("three_balls"), W, H, None, None, [])
    cands = list(dict.fromkeys(c.traced() for c in _moves(rules)))[:10]
    vc = VariantCache(share=False)
    calls, many = [], vc._trace_many
    vc._trace_many = lambda *a, **k: calls.append((len(a[1]), a[3] if len(a) > 3 else "f64")) or many(*a, **k)
    vc.prefetch_whole(scene, cands, f32=True)
    assert calls == [(len(cands), "f64"), (len(cands), "f32")]  # two kernels for them all
    before = set(vc.requested)
    for c in cands:
        got, alone = vc.get(scene, c, f32=True), VariantCache(share=False).get(scene, c, f32=True)
        for a, b in ((got.color, alone.color), (got.f32_stored, alone.f32_stored)):
            assert a.dtype == b.dtype and np.array_equal(a.view(f"u{a.itemsize}"), b.view(f"u{b.itemsize}")), c.differs(
                rules
            )
        assert np.array_equal(got.shadow_ill, alone.shadow_ill) and np.array_equal(got.f32_flips, alone.f32_flips)
    assert len(calls) == 2 and not before  # read from the cache; the prefetch itself asked for nothing


def test_every_per_ray_rule_is_moved_by_the_batch_test():
    """The test above changes every rule a batch reads per ray (a new one must join it)."""
    _, rules = load(find_scene("rules"), W, H, None, None, [])
    each = {n: fn for n, (fn, _) in PER_RAY.items()} | SWITCHES
    moved = {n for n, fn in each.items() if any(fn(c) != fn(rules) for c in _moves(rules))}
    assert moved == set(each)


def test_a_rule_the_kernel_compiles_in_cannot_be_read_from_a_mixed_batch():
    a = load(find_scene("rules"), W, H, None, None, [])[1]
    with pytest.raises(Divergent):  # a batch's code reading a rule its candidates differ in, as one value
        Candidates([a, replace(a, offset="error-bound")]).offset  # noqa: B018 (the read is the test)
    assert Candidates([a, replace(a, two_sided=True)]).shadow_range == "any"


def test_the_shadow_range_and_shadow_rays_are_read_per_ray_in_one_batch():
    scene, rules = load(find_scene("rules"), W, H, None, None, [])  # (it tells every pair of values apart)
    a, b = rules, replace(rules, shadow_range="to-light")
    idx = np.arange(0, W * H, 2)
    vc = VariantCache(share=False)
    cands = [a, b, replace(b, specular_exponent=4), replace(a, shadow_rays=False)]
    calls, many = [], vc._trace_many
    vc._trace_many = lambda *a, **k: calls.append(len(a[1])) or many(*a, **k)
    vc.prefetch(scene, cands, idx, probe=True)  # on the pixels: a probe's, not kept whole
    assert calls == [4] and not any(vc.has(scene, r) for r in cands)  # one kernel for the four
    for r in cands:
        got = vc.subset(scene, r, idx, probe=True)
        assert np.array_equal(got.color.view(np.uint64), _single(scene, r, idx).view(np.uint64))
    # and the rule sets differ here: a batch that took one's shadows from another would be caught
    assert not np.array_equal(_single(scene, a, idx), _single(scene, b, idx))
    assert not np.array_equal(_single(scene, a, idx), _single(scene, cands[3], idx))


def test_error_bound_and_numeric_offsets_share_a_batch():
    scene, rules = load(find_scene("three_balls"), W, H, None, None, [])
    cands = [replace(rules, offset="error-bound"), replace(rules, offset=1e-3), replace(rules, offset=1e-6)]
    idx = np.arange(0, W * H, 2)
    vc = VariantCache(share=False)
    calls, many = [], vc._trace_many
    vc._trace_many = lambda *a, **k: calls.append(len(a[1])) or many(*a, **k)
    got = vc._trace_batch(scene, [c.traced() for c in cands], idx)
    assert calls == [3]  # one kernel: each ray its candidate's offset, the bound's or a number
    by_rules = {v.rules: v for v in got}
    for c in cands:
        assert np.array_equal(by_rules[c.traced()].color.view(np.uint64), _single(scene, c, idx).view(np.uint64))


def test_a_small_images_batch_is_kept_whole_with_the_bits_of_a_render_alone():
    scene, rules = load(find_scene("rules"), W, H, None, None, [])
    cands = _moves(rules)[:8]
    idx = np.arange(0, W * H, 5)
    vc = VariantCache(share=False)
    vc.prefetch(scene, cands, idx)  # a small image: its candidates rendered whole, together, and kept
    assert all(vc.has(scene, c) for c in cands)
    for c in cands:
        alone = VariantCache(share=False).get(scene, c)  # traced by itself, every pixel
        got = vc.get(scene, c)
        assert np.array_equal(got.color.view(np.uint64), alone.color.view(np.uint64)), c.differs(rules)
        assert np.array_equal(got.shadow_ill, alone.shadow_ill)
    # a probe's values (one of many a one-number search tries) are traced on the pixels asked for, not kept
    probes = [replace(rules, specular_exponent=e) for e in (20, 21, 22)]
    vc.prefetch(scene, probes, idx, probe=True)
    assert not any(vc.has(scene, p) for p in probes)
    for p in probes:
        got = vc.subset(scene, p, idx, probe=True)
        assert np.array_equal(got.color.view(np.uint64), _single(scene, p, idx).view(np.uint64))


@pytest.mark.parametrize("accel", ["bvh", "loop"])
def test_a_batch_through_the_shape_table_gives_each_candidate_its_own_bits(accel):
    """The table's paths (planes in a loop, balls through the BVH or a loop) read the batch's shadow range
    and offset per ray as well: each ray its own test, its own distance beyond which the BVH skips boxes,
    its own start."""
    scene, rules = load(find_scene("rules"), W, H, None, None, [])  # a ball beyond the light blocks it
    cands = [
        rules,
        replace(rules, shadow_range="to-light"),
        replace(rules, shadow_rays=False, two_sided=True),
        replace(rules, offset="error-bound", offset_along="normal"),
    ]
    idx = np.arange(0, W * H, 2)

    def trace(rs):
        tr = Tracer(scene, rs, runtime=True, accel=accel)
        o, d = tr.primary_rays(idx)
        with dr.scoped_set_flag(dr.JitFlag.FastMath, False):
            color, _ = tr.trace(o, d, tree=True)
        return tr.to_numpy3(color).copy()

    batch = trace(cands)
    for k, c in enumerate(cands):
        alone = trace(c)
        part = batch[k * idx.size : (k + 1) * idx.size]
        assert np.array_equal(part.view(np.uint64), alone.view(np.uint64)), c.differs(rules)
    assert not np.array_equal(trace(cands[0]), trace(cands[1]))  # the shadow range shows here


def test_float32_flips_encoded_only_where_colours_are_a_level_apart_are_every_pixels():
    """``VariantCache._f32_twin`` encodes only pixels whose float64 and float32 colours are ~a level apart:
    the same flags as encoding every pixel, on values on and beside every rounding step, out of range,
    NaN and infinities, moved by less, about and more than a level (both ways round)."""
    from minirt.diagnose.target import LEVEL_TOL
    from minirt.diagnose.variants import Variant
    from minirt.model import bitmap
    from minirt.model.rules import Rules

    rng = np.random.default_rng(3)
    steps = np.concatenate([np.arange(257.0) / 255.0, (np.arange(257.0) + 0.5) / 255.0])
    values = np.concatenate([steps, np.nextafter(steps, 2), np.nextafter(steps, -2), rng.uniform(-0.2, 1.2, 3000),
                             [np.nan, np.inf, -np.inf, 0.0, -0.0]])  # fmt: skip
    a = rng.choice(values, (300, 200, 3))
    moves = [0.0, 1e-7, 0.5 / 255, 0.99 / 255, 1 / 255, 1.01 / 255, 2 / 255, 2.001 / 255, 3 / 255, np.nan, np.inf]
    with np.errstate(invalid="ignore"):
        b = (a + rng.choice(moves, a.shape) * rng.choice([-1.0, 1.0], a.shape)).astype(np.float32).astype(np.float64)
    for x, y in ((a, b), (b, a)):
        _, got = VariantCache._f32_twin(Variant(Rules(), x, np.zeros(x.shape[:2], dtype=bool)), y)
        with np.errstate(invalid="ignore"):
            want = bitmap.channel_any(np.abs(bitmap.encode(x).astype(np.int16) - bitmap.encode(y)) > LEVEL_TOL)
        assert want.any() and not want.all()
        assert np.array_equal(got, want)
