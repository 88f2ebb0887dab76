"""`minirt probe SCENE X Y --image IMAGE`: another tracer's value at one pixel beside the reference's
step-by-step computation -- for an image of the scene as given, for one made with a rule flipped
(8-bit and float), with --json, for a bundled scene's name, and a one-line exit 2 for a wrong size."""

from __future__ import annotations

import json
import subprocess
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from support.inproc import minirt

from minirt.io.images import read_image_u8, write_image
from minirt.model import bitmap
from minirt.model import rules as R
from minirt.model.scene import load_scene
from minirt.reference.tracer import render

ROOT = Path(__file__).resolve().parents[2]
SCENE = ROOT / "scenes" / "rules.toml"
W, H = 48, 40
SIZE = ["--width", str(W), "--height", str(H)]


def run(*args: str) -> subprocess.CompletedProcess:
    return minirt(*args, cwd=ROOT)  # in this process (tests/support/inproc.py): the command's status and streams


@pytest.fixture(scope="module")
def images(tmp_path_factory):
    """The scene's image as given and with clamp flipped, 8-bit PNGs and a float EXR, and the pixel
    where the flip changes the 8-bit value most."""
    tmp = tmp_path_factory.mktemp("probe")
    sc = load_scene(SCENE).with_overrides(width=W, height=H)
    rules = R.resolve(sc)
    flipped = replace(rules, clamp=not rules.clamp if isinstance(rules.clamp, bool) else True)
    given, other = render(sc, rules.traced()).color, render(sc, flipped.traced()).color
    a, b = bitmap.bitmap(given, rules), bitmap.bitmap(other, flipped)
    write_image(tmp / "given.png", a)
    write_image(tmp / "flipped.png", b)
    write_image(tmp / "flipped.exr", np.clip(other, 0, 1).astype(np.float32), ["R", "G", "B"])
    d = np.abs(a.astype(int) - b).max(-1)
    y, x = np.unravel_index(int(d.argmax()), d.shape)
    assert d[y, x] > 1, "the flip must show in this scene"
    return {"tmp": tmp, "x": int(x), "y": int(y), "given8": a[y, x], "flipped8": b[y, x], "flipped": other[y, x]}


def test_matching_image_shows_the_same_value(images):
    x, y = images["x"], images["y"]
    p = run("probe", str(SCENE), str(x), str(y), *SIZE, "--image", str(images["tmp"] / "given.png"))
    assert p.returncode == 0, p.stderr
    lines = p.stdout.strip().splitlines()
    assert lines[-2].startswith("colour ")  # after the usual step-by-step trace
    v = tuple(int(c) for c in images["given8"])
    assert lines[-1] == f"your image: {v} [8-bit]  reference: {v} -> the same"


def test_flipped_rule_shows_the_difference(images):
    x, y = images["x"], images["y"]
    p = run("probe", "rules", str(x), str(y), *SIZE, "--image", str(images["tmp"] / "flipped.png"))  # a bundled name
    assert p.returncode == 0, p.stderr
    yours, ref = tuple(int(c) for c in images["flipped8"]), tuple(int(c) for c in images["given8"])
    n = max(abs(a - b) for a, b in zip(yours, ref, strict=True))
    lines = p.stdout.strip().splitlines()
    assert lines[-2] == f"your image: {yours} [8-bit]  reference: {ref} -> differs by {n} levels"
    assert lines[-1].startswith("where it departs: ")  # the step of TraceRay where the values part
    assert f"8-bit {ref}" in p.stdout


def test_json_has_the_image_block(images):
    x, y = images["x"], images["y"]
    p = run("probe", str(SCENE), str(x), str(y), *SIZE, "--image", str(images["tmp"] / "flipped.png"), "--json")
    assert p.returncode == 0, p.stderr
    d = json.loads(p.stdout)
    im = d["image"]
    assert im["format"] == "8-bit" and im["unit"] == "levels" and im["notes"] == []
    assert im["value"] == [int(c) for c in images["flipped8"]] and im["reference"] == d["color8"]
    assert im["difference"] == max(abs(a - b) for a, b in zip(im["value"], im["reference"], strict=True)) > 1
    assert d["pixel"] == [x, y] and d["levels"]  # the step-by-step trace is still there


def test_float_image_shows_float_values(images):
    x, y = images["x"], images["y"]
    p = run("probe", str(SCENE), str(x), str(y), *SIZE, "--image", str(images["tmp"] / "flipped.exr"), "--json")
    assert p.returncode == 0, p.stderr
    im = json.loads(p.stdout)["image"]
    assert im["format"] == "float" and im["unit"] == "float"
    assert np.allclose(im["value"], np.clip(images["flipped"], 0, 1), atol=1e-6)
    assert im["difference"] > 2 / 255
    p = run("probe", str(SCENE), str(x), str(y), *SIZE, "--image", str(images["tmp"] / "flipped.exr"))
    lines = p.stdout.strip().splitlines()
    assert "[float]  reference: (" in lines[-2] and "-> differs by 0." in p.stdout
    # clamp flipped at a pixel facing away from the light: the image has no highlight there
    assert lines[-1].startswith("where it departs: your value is the reference's without its specular term")


def test_wrong_size_is_one_line_exit_2(images):
    p = run("probe", str(SCENE), "1", "1", "--image", str(images["tmp"] / "given.png"))  # the scene's own size
    assert p.returncode == 2
    err = p.stderr.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("minirt: error: ") and f"the image is {W}x{H}" in err[0]
    assert f"--width {W} --height {H}" in err[0] and "Traceback" not in p.stderr
    assert p.stdout == ""


def test_transposed_image_is_read_transposed_with_a_note(images):
    x, y = images["x"], images["y"]
    a = np.swapaxes(read_image_u8(images["tmp"] / "given.png"), 0, 1)
    path = images["tmp"] / "transposed.png"
    write_image(path, np.ascontiguousarray(a))
    p = run("probe", str(SCENE), str(x), str(y), *SIZE, "--image", str(path))
    assert p.returncode == 0, p.stderr
    lines = p.stdout.strip().splitlines()
    assert "x and y are swapped (transposed)" in lines[-2]
    assert lines[-1].endswith("-> the same")
