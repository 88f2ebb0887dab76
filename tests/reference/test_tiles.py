"""Tiles: an image traced in tiles of whole rows is bit-identical to one pass, and written tile by tile
it gives the same files. (Tile sizes here are tiny so that the tests are fast; the real size is
tracer.TILE_PIXELS.)"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import drjit as dr
import numpy as np
import pytest

from minirt.campaign.generate import balls_scene
from minirt.io.images import write_result, write_tiles
from minirt.model import camera
from minirt.model.rules import PROFILES, resolve
from minirt.model.scene import load_scene, parse_scene
from minirt.reference.tracer import Tracer, tile_rows

FIELDS = ("color", "hit", "shape_id", "t", "position", "normal")


def _same(a, b) -> list[str]:
    bad = [f for f in FIELDS if getattr(a, f).tobytes() != getattr(b, f).tobytes()]
    bad += ["term." + k for k in a.terms if a.terms[k].tobytes() != b.terms[k].tobytes()]
    bad += ["aux." + k for k in a.aux if a.aux[k].tobytes() != b.aux[k].tobytes()]
    return bad + ([] if (a.width, a.height) == (b.width, b.height) else ["size"])


@pytest.mark.parametrize("precision", ["f64", "f32"])
@pytest.mark.parametrize(("name", "samples"), [("three_balls", 1), ("rules", 1), ("soft", 4), ("shadows", 1)])
def test_tiles_same_bits_as_one_pass(name, samples, precision):
    scene = load_scene(f"scenes/{name}.toml").with_overrides(width=36, height=29, samples=samples)
    tr = Tracer(scene, resolve(scene), precision)
    whole = tr.render(diagnostics=True)
    tiled = tr.render(diagnostics=True, tile_pixels=36 * 4)  # 4 rows a tile, the last one 1 row
    assert tile_rows(36, 36 * 4) == 4
    assert _same(whole, tiled) == []


@pytest.mark.parametrize("precision", ["f64", "f32"])
@pytest.mark.parametrize("name", ["three_balls", "rules", "exercise", "shadows"])
def test_buffers_written_by_the_kernel_are_the_traced_values(name, precision):
    """render() has the first level's kernels write the interleaved float64 buffers themselves; they
    hold exactly what the wavefront computes per component (trace(record=True)), position and normal
    0 on a miss, and no negative zero (a skipped term and a computed 0 * negative share their bits)."""
    scene = load_scene(f"scenes/{name}.toml").with_overrides(width=31, height=17, samples=1)
    tr = Tracer(scene, resolve(scene), precision)
    res = tr.render()
    o, d = tr.primary_rays()
    color, levels = tr.trace(o, d, record=True)
    lvl = levels[0]
    hit = np.asarray(lvl.shape_id) >= 0

    def flat(v, masked=False):
        a = tr.to_numpy3(v)
        return np.where(hit[:, None], a, 0.0) if masked else a

    want = {"color": flat(color), "position": flat(lvl.p, True), "normal": flat(lvl.n, True)}
    want |= {"term." + k: flat(v) for k, v in lvl.terms.items()}
    got = {"color": res.color, "position": res.position, "normal": res.normal}
    got |= {"term." + k: res.terms[k] for k in lvl.terms}
    assert set(lvl.terms) >= {"ambient", "diffuse"}
    for k, a in want.items():
        assert got[k].tobytes() == a.reshape(17, 31, 3).tobytes(), k
        assert not (np.signbit(got[k]) & (got[k] == 0)).any(), k
    assert np.asarray(dr.llvm.Float64(lvl.t)).tobytes() == res.t.reshape(-1).tobytes()


@pytest.mark.parametrize("precision", ["f64", "f32"])
@pytest.mark.parametrize(
    ("name", "samples", "tile"), [("three_balls", 1, None), ("soft", 4, None), ("rules", 1, 31 * 5)]
)
def test_only_the_terms_asked_for(name, samples, tile, precision):
    """render(terms=...) keeps only those terms (the check's reference renders write two of five), and
    everything it keeps is the same bits as the render of every term: the skipped terms still add to
    the colour."""
    from minirt.harness.references import CHECKED_TERMS

    scene = load_scene(f"scenes/{name}.toml").with_overrides(width=31, height=17, samples=samples)
    tr = Tracer(scene, resolve(scene), precision)
    every = tr.render(diagnostics=True, tile_pixels=tile)
    some = tr.render(diagnostics=True, tile_pixels=tile, terms=CHECKED_TERMS)
    assert set(every.terms) == {"ambient", "diffuse", "specular", "reflection", "background"}
    assert set(some.terms) == set(CHECKED_TERMS)
    assert (some.terms["diffuse"] > 0).any()  # a term really computed, not zeros
    assert _same(some, every) == []  # every field, every kept term, every aux buffer
    with pytest.raises(ValueError, match=r"unknown term.*difuse"):
        tr.render(terms=("difuse",))


def test_tiles_with_the_tree():
    scene = parse_scene(balls_scene(300, seed=4, width=40, height=33))
    tr = Tracer(scene, PROFILES["conventional"], accel="bvh")
    assert _same(tr.render(diagnostics=True), tr.render(diagnostics=True, tile_pixels=40 * 7)) == []


def test_sample_offsets_from_a_start():
    u, v = camera.sample_offsets(16, 5, 1000)
    us, vs = camera.sample_offsets(16, 5, 300, start=437)
    assert np.array_equal(u[437:737], us) and np.array_equal(v[437:737], vs)


def test_written_tile_by_tile_same_files(tmp_path):
    scene = load_scene("scenes/three_balls.toml").with_overrides(width=37, height=23)
    tr = Tracer(scene, resolve(scene))
    a = write_result(tr.render(), tmp_path / "a", "x")
    b, last = write_tiles(tr.tiles(tile_pixels=37 * 5), 37, 23, tmp_path / "b", "x")
    assert last.height == 3  # 23 rows in tiles of 5: the last has 3
    for key in ("png", "exr", "json"):
        assert a[key].read_bytes() == b[key].read_bytes(), key


def test_failed_tiled_write_leaves_nothing(tmp_path):
    scene = load_scene("scenes/exercise.toml").with_overrides(width=16, height=16)
    tr = Tracer(scene, resolve(scene))

    def broken():
        it = tr.tiles(tile_pixels=16 * 4)
        yield next(it)
        raise RuntimeError("interrupted")

    with pytest.raises(RuntimeError):
        write_tiles(broken(), 16, 16, tmp_path, "x")
    assert list(tmp_path.iterdir()) == []


def test_render_to_files_streams_a_large_image(tmp_path, monkeypatch):
    """render_to_files(stream=True) writes an image larger than a tile tile by tile: the same files as
    the in-memory path, and the returned result holds no buffers."""
    from minirt.harness import backends
    from minirt.reference import tracer

    monkeypatch.setattr(tracer, "TILE_PIXELS", 24 * 5)
    scene = load_scene("scenes/shadows.toml").with_overrides(width=24, height=19)
    rules = resolve(scene)
    res_a, a = backends.render_to_files("reference", scene, rules, {}, tmp_path / "a", "x", stream=False)
    res_b, b = backends.render_to_files("reference", scene, rules, {}, tmp_path / "b", "x", stream=True)
    assert res_a.color is not None and res_b.color is None and res_b.ok
    for key in ("png", "exr", "json"):
        assert a[key].read_bytes() == b[key].read_bytes(), key


@pytest.mark.parametrize("precision", ["f64", "f32"])
@pytest.mark.parametrize("tile", [None, 31 * 5])
def test_samples_batched_in_one_kernel_same_bits(monkeypatch, precision, tile):
    """Supersampling sums a batch of samples in one kernel (sampling.SAMPLE_BATCH_BYTES); the same bits as a
    kernel per sample: 7 samples as batches of 3 (the last one 1), with the diagnostics' falloff sums,
    whole and in tiles, and the first sample's offsets where a tile starts (camera.sample_offsets_into)."""
    from minirt.reference import sampling

    scene = load_scene("scenes/soft.toml").with_overrides(width=31, height=17, samples=7)
    rules = resolve(scene)
    monkeypatch.setattr(sampling, "SAMPLE_BATCH_BYTES", 0)  # a kernel per sample
    one = Tracer(scene, rules, precision).render(diagnostics=True, tile_pixels=tile)
    monkeypatch.setattr(sampling, "SAMPLE_BATCH_BYTES", 16 * 31 * 17 * 3)  # 3 samples a kernel
    batched = Tracer(scene, rules, precision).render(diagnostics=True, tile_pixels=tile)
    assert {"variance", "variance_diffuse", "diffuse_r2"} <= set(batched.aux)
    assert _same(one, batched) == []
    assert (batched.aux["variance"] > 0).any()  # the samples differ: there is something to sum


def test_samples_with_runtime_rules_same_bits():
    """A check's reference of a supersampled scene reads its rules at run time (harness.ReferenceCache):
    the same bits as the rules compiled in, every buffer, the samples' statistics too."""
    scene = load_scene("scenes/soft.toml").with_overrides(width=23, height=19, samples=5)
    rules = PROFILES["conventional"]
    a = Tracer(scene, rules, runtime=False).render(diagnostics=True, terms=("diffuse", "specular"))
    b = Tracer(scene, rules, runtime=True).render(diagnostics=True, terms=("diffuse", "specular"))
    assert {"variance", "diffuse_r2"} <= set(b.aux)
    assert _same(a, b) == []


@pytest.mark.parametrize("below", [1 << 62, 0], ids=["run-time width", "compiled width"])
@pytest.mark.parametrize("width", [1, 3, 7, 1000, 16383, 16384])
def test_row_and_column_of_any_pixel(monkeypatch, width, below):
    """Below LOOP_FIRST_LEVEL_BELOW rays the kernel finds a pixel's row as floor(index / width) in float64
    (the width a run-time value: one kernel for every image size), from there by the compiled width:
    either way the NumPy camera's integer divmod, bit for bit, at both ends of every row up to the largest
    image (16384^2 = 2^28 pixels) and at random pixels."""
    from minirt.reference import integrator

    monkeypatch.setattr(integrator, "LOOP_FIRST_LEVEL_BELOW", below)
    height = 16384
    scene = load_scene("scenes/exercise.toml").with_overrides(width=width, height=height)
    n = width * height
    rows = np.array([0, 1, 2, height // 2, height - 2, height - 1], dtype=np.int64)
    ends = np.concatenate([rows * width + k for k in (-1, 0, 1, width - 1)])
    rnd = np.random.default_rng(width).integers(0, n, 2000)
    pixels = np.unique(np.clip(np.concatenate([ends, rnd, [n - 1]]), 0, n - 1)).astype(np.uint32)
    rules = PROFILES["exercise"]
    tr = Tracer(scene, rules)
    o, d = tr.primary_rays(pixels)
    o_np, d_np = camera.primary_rays(scene, rules, pixels)
    assert tr.to_numpy3(d).tobytes() == d_np.tobytes()
    assert tr.to_numpy3(o).tobytes() == np.broadcast_to(o_np, (len(pixels), 3)).tobytes()


def _kernels(run) -> tuple[Any, list[dict]]:
    """What ``run()`` returns, and the JIT kernels it launched (Dr.Jit's kernel history)."""
    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        dr.kernel_history()
        out = run()
        return out, [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]


def _hashes(kernels: list[dict]) -> list[str]:
    return sorted(k["hash"] for k in kernels)


@pytest.mark.parametrize("samples", [1, 3])
def test_another_size_compiles_nothing(samples):
    """The image's size is not compiled into the kernel: a scene rendered at a second size (below
    LOOP_FIRST_LEVEL_BELOW rays, so the same form) runs the very kernel of the first size (the same code,
    so the same hash: a cache hit, whichever cache)."""
    scene = load_scene("scenes/three_balls.toml").with_overrides(samples=samples)
    rules = resolve(scene)
    tracers = [Tracer(scene.with_overrides(width=w, height=h), rules) for w, h in ((21, 17), (40, 31))]
    hashes = [_hashes(_kernels(lambda tr=tr: tr.render(diagnostics=True))[1]) for tr in tracers]
    assert hashes[0] and hashes[0] == hashes[1]


def test_a_search_variant_is_one_trace_kernel():
    """A rule search's render (diagnose.VariantCache._trace: a lazy trace, its colour and shadow margins
    read back) runs the trace once: one kernel for the colour and the margins, one that interleaves.
    Read component by component, the colour's three gathers each evaluated the lazy trace on its own,
    and the margins a fourth time: five kernels, and two and a half times the time."""
    from minirt.diagnose.variants import VariantCache

    scene = load_scene("scenes/rules.toml").with_overrides(width=24, height=16)
    rules = resolve(scene).traced()
    cache = VariantCache()
    cache._trace(scene, rules, None)  # compiled, so that only the runs are counted below
    v, kernels = _kernels(lambda: cache._trace(scene, rules, None))
    assert len(kernels) == 2, [(k["size"], k.get("operation_count")) for k in kernels]
    assert sorted(k["size"] for k in kernels) == [24 * 16, 3 * 24 * 16]  # the trace, then the interleave
    whole = Tracer(scene, rules).render()
    assert np.array_equal(v.color, whole.color)  # the same colour as a plain render's


def test_small_images_read_their_rules_at_run_time():
    """By default (``runtime=None``) an image below LOOP_FIRST_LEVEL_BELOW pixels reads the rules a
    search varies at run time, so a render under another such rule (``--rule clamp=true``, another
    exponent, the camera's rules) runs the very kernels of the first; from there the rules are compiled
    in, as the trace's hot path wants."""
    scene = load_scene("scenes/three_balls.toml").with_overrides(width=24, height=16)
    rules = resolve(scene)
    assert Tracer(scene, rules).runtime is True
    big = scene.with_overrides(width=512, height=512)  # 2^18 pixels: not below the threshold
    assert Tracer(big, rules).runtime is False and Tracer(big, rules, runtime=True).runtime is True
    other = replace(rules, clamp=True, specular_exponent=16, pixel_sample="center", two_sided=True)
    hashes = [_hashes(_kernels(Tracer(scene, r).render)[1]) for r in (rules, other)]
    assert hashes[0] and hashes[0] == hashes[1]


def test_small_images_read_their_scene_values_at_run_time():
    """Below LOOP_FIRST_LEVEL_BELOW pixels the scene's values are read at run time too (``values.Values.k``): a
    scene that differs only in its values -- a ball moved and grown, a colour, the light, the camera's
    distance -- runs the very kernels of the first, and renders as a Tracer with the values compiled in
    does, bit for bit."""
    scene = load_scene("scenes/three_balls.toml").with_overrides(width=24, height=16)
    ball = next(k for k, s in enumerate(scene.shapes) if hasattr(s, "radius"))
    b = scene.shapes[ball]
    moved = replace(b, center=(b.center[0] + 0.1, b.center[1], b.center[2]), radius=b.radius * 1.1,
                    material=replace(b.material, diffuse=(0.3, 0.6, 0.2)))  # fmt: skip
    other = replace(
        scene,
        shapes=(*scene.shapes[:ball], moved, *scene.shapes[ball + 1 :]),
        light=replace(scene.light, position=tuple(1.05 * x for x in scene.light.position)),
        camera=replace(scene.camera, distance=scene.camera.distance * 1.2),
    )
    rules = resolve(scene)
    runs = [_kernels(lambda sc=sc: Tracer(sc, rules).render(diagnostics=True)) for sc in (scene, other)]
    results, hashes = [r for r, _ in runs], [_hashes(k) for _, k in runs]
    assert hashes[0] and hashes[0] == hashes[1]
    assert not np.array_equal(results[0].color, results[1].color)  # the values did change the picture
    compiled = Tracer(other, rules, runtime=False).render(diagnostics=True)
    assert _same(compiled, results[1]) == []
