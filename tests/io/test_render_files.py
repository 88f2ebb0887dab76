"""A render's files as minirt.io.images writes them: the EXR a block of rows at a time (the same bytes as
the whole-image conversion), files written by a background thread (the same bytes again), PNGs byte for
byte the committed goldens, errors and interruptions that leave no half-written file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from minirt.errors import MinirtError
from minirt.io import images
from minirt.model import bitmap
from minirt.model.rules import PROFILES, resolve
from minirt.model.scene import load_scene
from minirt.reference.tracer import Tracer

ROOT = Path(__file__).resolve().parents[2]
GOLDENS = ROOT / "tests" / "goldens"
SCENES = sorted((ROOT / "scenes").glob("*.toml"))


@pytest.fixture(scope="module")
def result():
    """An odd-sized render with every buffer, diagnostics too (27 + 2 channels)."""
    scene = load_scene(ROOT / "scenes" / "three_balls.toml").with_overrides(width=37, height=23)
    return Tracer(scene, resolve(scene)).render(diagnostics=True)


@pytest.mark.parametrize("rows", [1, 5, 16, 64])
def test_the_exr_written_by_blocks_of_rows_is_the_whole_image_conversion(result, tmp_path, monkeypatch, rows):
    monkeypatch.setattr(images, "EXR_BLOCK_ROWS", rows)
    images.write_exr(tmp_path / "blocks.exr", result)
    images.write_image(tmp_path / "whole.exr", *images.exr_channels(result))
    assert (tmp_path / "blocks.exr").read_bytes() == (tmp_path / "whole.exr").read_bytes()
    back, names = images.read_image(tmp_path / "blocks.exr")
    data, want = images.exr_channels(result)
    for i, name in enumerate(want):  # every channel its float64 buffer rounded once, bit for bit
        assert np.array_equal(back[..., names.index(name)].view(np.uint32), data[..., i].view(np.uint32)), name
    assert np.array_equal(data[..., want.index("P.Y")], result.position[..., 1].astype(np.float32))


def test_background_writes_give_the_same_files(result, tmp_path):
    plain = images.write_result(result, tmp_path / "a", "x")
    with images.background_writes():
        later = images.write_result(result, tmp_path / "b", "x")
        assert later == {k: tmp_path / "b" / p.name for k, p in plain.items()}
    for key, path in plain.items():
        assert later[key].read_bytes() == path.read_bytes(), key
    assert not [p for p in (tmp_path / "b").iterdir() if p.name.startswith(".")]  # no temporary file left


@pytest.mark.parametrize("path", SCENES, ids=[p.stem for p in SCENES])
def test_pngs_are_byte_for_byte_the_goldens(path, tmp_path):
    """The goldens (tests/goldens, written before the EXR and background writes changed) are the PNG
    files `minirt render` writes at 64x64 under the profiles with the default bitmap; the others are
    the bytes write_image gives their bitmap."""
    for profile, rules in PROFILES.items():
        scene = load_scene(path).with_overrides(width=64, height=64, samples=1)
        res = Tracer(scene, rules).render()
        with images.background_writes():
            png = images.write_result(res, tmp_path / profile, scene.name, rules=rules)["png"]
        if bitmap.is_default(rules):
            assert png.read_bytes() == (GOLDENS / f"{scene.name}.{profile}.png").read_bytes(), profile
        else:
            images.write_image(tmp_path / "direct.png", bitmap.bitmap(res.color, rules))
            assert png.read_bytes() == (tmp_path / "direct.png").read_bytes(), profile


def test_a_failed_background_write_is_raised_when_the_block_ends(result, tmp_path, monkeypatch):
    def broken(path, res, stop=None):
        raise MinirtError(f"{path}: cannot write image: disk full")

    monkeypatch.setattr(images, "write_exr", broken)
    with pytest.raises(MinirtError, match="disk full"), images.background_writes():
        images.write_result(result, tmp_path, "x")
    assert (tmp_path / "x.png").exists() and not (tmp_path / "x.exr").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_an_error_in_the_block_abandons_the_writes_and_is_the_one_raised(result, tmp_path, monkeypatch):
    monkeypatch.setattr(images, "EXR_BLOCK_ROWS", 1)
    with pytest.raises(KeyboardInterrupt), images.background_writes():
        for k in range(50):
            images.write_result(result, tmp_path, f"x{k}")
        raise KeyboardInterrupt
    # What was written is whole; what was not started or was abandoned left nothing behind.
    exrs = sorted(tmp_path.glob("*.exr"))
    assert len(exrs) < 50
    for p in exrs:
        assert images.read_image(p)[0].shape == (23, 37, 29)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
