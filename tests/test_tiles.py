"""Tiles: an image traced in tiles of whole rows is bit-identical to one pass, and written tile by tile
it gives the same files. (Tile sizes here are tiny so that the tests are fast; the real size is
tracer.TILE_PIXELS.)"""

from __future__ import annotations

import numpy as np
import pytest

from minirt import camera
from minirt.generate import balls_scene
from minirt.imageio import write_result, write_tiles
from minirt.rules import PROFILES, resolve
from minirt.scene import load_scene, parse_scene
from minirt.tracer import Tracer, tile_rows

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
    from minirt import backends, tracer

    monkeypatch.setattr(tracer, "TILE_PIXELS", 24 * 5)
    scene = load_scene("scenes/shadows.toml").with_overrides(width=24, height=19)
    rules = resolve(scene)
    res_a, a = backends.render_to_files("reference", scene, rules, {}, tmp_path / "a", "x", stream=False)
    res_b, b = backends.render_to_files("reference", scene, rules, {}, tmp_path / "b", "x", stream=True)
    assert res_a.color is not None and res_b.color is None and res_b.ok
    for key in ("png", "exr", "json"):
        assert a[key].read_bytes() == b[key].read_bytes(), key
