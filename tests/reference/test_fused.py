"""The one-kernel trace (``integrator.trace_fused``: every reflection level in a Dr.Jit loop) against the
wavefront (one kernel per level, rays compacted between them): the same buffers, bit for bit, wherever the
two can differ -- every rule profile, both precisions, runtime rules, the shape table and its BVH, the
diagnostics (ray-tree hashes, shadow margins), the supersampled path, and a first level read lazily after
the colour."""

from __future__ import annotations

from functools import partialmethod
from pathlib import Path

import drjit as dr
import numpy as np
import pytest

from minirt.campaign.generate import balls_scene
from minirt.model.result import Planes
from minirt.model.rules import PROFILES, resolve
from minirt.model.scene import load_scene, parse_scene
from minirt.reference import film, integrator, sampling
from minirt.reference.tracer import Tracer

THREE_BALLS = Path(__file__).resolve().parents[2] / "scenes" / "three_balls.toml"


def _buffers(tr: Tracer, path: str, tree: bool) -> dict[str, bytes]:
    o, d = tr.primary_rays()
    bufs: dict = {}
    _, levels = tr.trace(o, d, out=bufs, path=path, tree=tree)
    dr.sync_thread()
    w, h = tr.scene.camera.width, tr.scene.camera.height
    # Each buffer as (h, w, 3) float64, whichever layout the path wrote (film.read): the looped first
    # level's 4-packets and the straight-line one's planes hold the same bits.
    got = {k: _image(film.read(v, h, w)).tobytes() if k != "t" else np.asarray(v).tobytes() for k, v in bufs.items()}
    got["shape_id"] = np.asarray(levels[0].shape_id).tobytes()
    if tree:  # the diagnostics: every decision of the ray tree, hashed, and the shadow rays' margins
        got["tree"] = np.asarray(levels[0].record["tree"]).tobytes()
        if "shadow_margin" in levels[0].record:  # scenes with shadows
            got["shadow_margin"] = np.asarray(levels[0].record["shadow_margin"]).tobytes()
    return got


def _image(v) -> np.ndarray:
    a = v.stack() if isinstance(v, Planes) else np.ascontiguousarray(v)
    assert a.dtype == np.float64 and a.shape[2] == 3
    return a


def _differs(tr: Tracer) -> list[str]:
    """What differs from the wavefront's buffers in either form of the one kernel: the first level in the
    loop (below ``LOOP_FIRST_LEVEL_BELOW`` rays) or before it in straight-line code."""
    bad = []
    for tree in (False, True):
        wave = _buffers(tr, "wavefront", tree)
        for form, below in (("looped", 1 << 62), ("straight", 0)):
            with pytest.MonkeyPatch.context() as mp:
                mp.setattr(integrator, "LOOP_FIRST_LEVEL_BELOW", below)
                fused = _buffers(tr, "fused", tree)
            assert set(fused) == set(wave)
            assert len(fused["color"]) == 3 * 8 * tr.scene.camera.width * tr.scene.camera.height
            bad += [f"{k} ({form}, tree {tree})" for k in sorted(fused) if fused[k] != wave[k]]
    return bad


@pytest.mark.parametrize("profile", list(PROFILES))
def test_bundled_scenes_same_bits(scene_path, profile):
    scene = load_scene(scene_path).with_overrides(width=40, height=40, samples=1)
    rules = resolve(scene, profile)
    for precision in ("f64", "f32") if profile == "exercise" else ("f64",):
        assert _differs(Tracer(scene, rules, precision, runtime=False)) == [], precision  # compiled in


@pytest.mark.parametrize("profile", list(PROFILES))
def test_runtime_rules_same_bits(profile):
    scene = load_scene(THREE_BALLS).with_overrides(width=40, height=40)
    assert _differs(Tracer(scene, PROFILES[profile], runtime=True)) == []


@pytest.mark.parametrize(("n", "accel"), [(1, "unrolled"), (40, "bvh"), (300, "bvh"), (300, "loop")])
def test_random_scenes_same_bits(n, accel):
    """Balls that reflect each other up to max_depth 3, through the table and the tree (nested loops)."""
    scene = parse_scene(balls_scene(n, seed=7 + n, width=48, height=48))
    for profile in ("exercise", "conventional"):
        tr = Tracer(scene, PROFILES[profile], accel=accel)
        assert tr.effects.reflection_depth == 3
        assert _differs(tr) == [], profile


FORMS = pytest.mark.parametrize("below", [1 << 62, 0], ids=["looped", "straight"])


@FORMS
def test_supersampled_same_bits(monkeypatch, below):
    monkeypatch.setattr(integrator, "LOOP_FIRST_LEVEL_BELOW", below)
    scene = load_scene(THREE_BALLS).with_overrides(width=24, height=24, samples=4)
    rules = resolve(scene)
    fused = Tracer(scene, rules).render(diagnostics=False)
    monkeypatch.setattr(Tracer, "trace", partialmethod(Tracer.trace, path="wavefront"))
    monkeypatch.setattr(sampling, "SAMPLE_BATCH_BYTES", 0)  # a kernel per sample: the wavefront's levels are kernels
    wave = Tracer(scene, rules).render(diagnostics=False)
    assert fused.color.tobytes() == wave.color.tobytes()
    assert {k: v.tobytes() for k, v in fused.terms.items()} == {k: v.tobytes() for k, v in wave.terms.items()}
    assert {k: v.tobytes() for k, v in fused.aux.items()} == {k: v.tobytes() for k, v in wave.aux.items()}


@FORMS
def test_first_level_read_after_the_colour(monkeypatch, below):
    """Without ``out`` the fused trace is lazy: the first level's arrays evaluated later (a kernel of
    their own) carry the wavefront's bits."""
    monkeypatch.setattr(integrator, "LOOP_FIRST_LEVEL_BELOW", below)
    scene = load_scene(THREE_BALLS).with_overrides(width=32, height=32)
    tr = Tracer(scene, resolve(scene))
    o, d = tr.primary_rays()
    c, levels = tr.trace(o, d)
    dr.eval(c)
    late = [np.asarray(levels[0].t), np.asarray(levels[0].n[1]), np.asarray(levels[0].terms["reflection"][0])]
    o, d = tr.primary_rays()
    cw, wave = tr.trace(o, d, path="wavefront")
    assert np.asarray(c[0]).tobytes() == np.asarray(cw[0]).tobytes()
    ref = [np.asarray(wave[0].t), np.asarray(wave[0].n[1]), np.asarray(wave[0].terms["reflection"][0])]
    assert [a.tobytes() for a in late] == [b.tobytes() for b in ref]
    assert (np.asarray(wave[0].terms["reflection"][0]) != 0).any()  # the reflections are there to compare


def test_auto_picks_the_wavefront_for_many_balls():
    """From WAVEFRONT_MIN_BALLS balls a trace is a wavefront (a level per kernel: its levels are returned),
    below it one kernel (the first level only); record always needs the wavefront."""
    from minirt.reference.integrator import WAVEFRONT_MIN_BALLS

    levels = {}
    for n in (WAVEFRONT_MIN_BALLS - 1, WAVEFRONT_MIN_BALLS):
        tr = Tracer(parse_scene(balls_scene(n, seed=3, width=16, height=16)), PROFILES["exercise"])
        o, d = tr.primary_rays()
        levels[n] = len(tr.trace(o, d)[1])
    assert levels == {WAVEFRONT_MIN_BALLS - 1: 1, WAVEFRONT_MIN_BALLS: 4}
    # with each pixel's decision tree (a check's reference, the rule diagnosis) one kernel, the same bits
    o, d = tr.primary_rays()
    tree_auto, tree_levels = tr.trace(o, d, tree=True)
    assert len(tree_levels) == 1
    tree_wave, _ = tr.trace(o, d, tree=True, path="wavefront")
    assert np.array_equal(tr.to_numpy3(tree_auto), tr.to_numpy3(tree_wave))
    with pytest.raises(ValueError, match="record"):
        tr.trace(*tr.primary_rays(), record=True, path="fused")


def test_the_looped_form_holds_the_shading_once(monkeypatch):
    """Below LOOP_FIRST_LEVEL_BELOW rays the first level is the loop's first iteration, so the kernel holds
    the intersection and shading code once, not twice: measured in Dr.Jit operations (what LLVM compiles),
    a render's kernel has well under the straight-line form's (three_balls: ~910 against ~1,380)."""
    assert 256 < integrator.LOOP_FIRST_LEVEL_BELOW <= 1024 * 1024  # tests' images loop; 1024^2 runs straight
    scene = load_scene(THREE_BALLS).with_overrides(width=16, height=16)
    ops = {}
    for form, below in (("looped", 1 << 62), ("straight", 0)):
        monkeypatch.setattr(integrator, "LOOP_FIRST_LEVEL_BELOW", below)
        with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
            dr.kernel_history()
            Tracer(scene, resolve(scene), runtime=False).render()  # the rules compiled in both times:
            kernels = [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]  # the forms alone differ
        ops[form] = max(k["operation_count"] for k in kernels)
    assert ops["looped"] < 0.75 * ops["straight"], ops


def test_a_looped_tracer_traces_whole_images_in_its_subsets_kernel():
    """``Tracer(looped=True)`` (the rule diagnosis' traces): an image of at least LOOP_FIRST_LEVEL_BELOW rays
    runs the looped form, so it launches the very kernel a subset of its pixels compiled -- and its colours
    are the straight-line form's bits (what the tracer runs by default at that size)."""
    from minirt.diagnose.variants import VariantCache

    w, h = 520, 512
    assert w * h >= integrator.LOOP_FIRST_LEVEL_BELOW
    scene = load_scene(THREE_BALLS).with_overrides(width=w, height=h)
    rules = resolve(scene)
    cache = VariantCache()
    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        dr.kernel_history()
        part = cache._trace(scene, rules, np.arange(0, w * h, 7))
        sub = {k["hash"] for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT}
        whole = cache._trace(scene, rules, None)
        launched = {k["hash"] for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT}
    assert launched <= sub, "the whole image compiled a kernel of its own"
    tr = Tracer(scene, rules, runtime=True)  # not looped: the straight-line first level at this size
    o, d = tr.primary_rays()
    straight = tr.to_numpy3(tr.trace(o, d, tree=True, path="fused")[0])
    assert whole.color.reshape(-1, 3).tobytes() == straight.tobytes()
    assert part.color.tobytes() == straight[::7].tobytes()
