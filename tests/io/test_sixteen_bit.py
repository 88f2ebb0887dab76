"""A 16-bit image whose every value is a multiple of 257 holds an 8-bit image (level k stored as 257 k,
the usual widening): it is graded as those 8-bit levels, and the grade says so. Issue 51: such a PNG of
the reference's own render was read as floats and graded DIFFERS (514 of 1,024 pixels)."""

from __future__ import annotations

import json

import numpy as np
from support.inproc import minirt

from minirt.io.images import read_image_u8, read_student_image, write_image

NOTE = "the image is 16-bit, every value a multiple of 257"


def _rendered(tmp_path):
    p = minirt("render", "exercise", "--width", "32", "--height", "32", "-o", tmp_path / "r", "-q")
    assert p.returncode == 0, p.stderr
    return read_image_u8(tmp_path / "r" / "exercise.reference.png")


def _grade(image) -> dict:
    p = minirt("grade", "exercise", image, "--size", "32x32", "--json", "-")
    assert p.returncode in (0, 1), p.stderr
    return json.loads(p.stdout)


def test_a_16_bit_image_of_8_bit_levels_is_graded_as_them(tmp_path):
    levels = _rendered(tmp_path)
    wide = tmp_path / "wide.png"
    write_image(wide, levels.astype(np.uint16) * 257)
    notes: list[str] = []
    colour, is_float = read_student_image(wide, notes=notes)
    assert not is_float and colour.dtype == np.uint8
    np.testing.assert_array_equal(colour, levels)
    assert len(notes) == 1 and notes[0].startswith(NOTE)
    doc, own = _grade(wide), _grade(tmp_path / "r" / "exercise.reference.png")
    assert doc["verdict"] == own["verdict"] == "match", doc["verdict"]
    assert any(n.startswith(NOTE) for n in doc["notes"]), doc["notes"]
    assert not any(n.startswith(NOTE) for n in own["notes"])


def test_a_16_bit_image_of_other_values_stays_float(tmp_path):
    levels = _rendered(tmp_path)
    wide = levels.astype(np.uint16) * 257
    wide[0, 0, 0] += 1  # one value not a multiple of 257: a true 16-bit image
    path = tmp_path / "wide.png"
    write_image(path, wide)
    notes: list[str] = []
    colour, is_float = read_student_image(path, notes=notes)
    assert is_float and colour.dtype == np.float32 and notes == []
    assert not any(n.startswith(NOTE) for n in _grade(path)["notes"])
