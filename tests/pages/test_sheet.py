"""The contact sheet (minirt.pages.sheet): titles inside the image, and a difference row against the reference."""

from __future__ import annotations

import copy

import numpy as np
from conftest import ROOT

from minirt.io.images import read_image_u8
from minirt.model.rules import resolve
from minirt.model.scene import load_scene
from minirt.pages import sheet
from minirt.reference import tracer


def test_contact_sheet_has_a_difference_row_and_unclipped_titles(tmp_path):
    scene = load_scene(ROOT / "scenes" / "exercise.toml").with_overrides(width=16, height=16)
    ref = tracer.render(scene, resolve(scene))
    other = copy.deepcopy(ref)
    other.backend = "povray"
    other.color = np.clip(ref.color + 3 / 255, 0, None)  # three levels brighter everywhere
    geometry = copy.deepcopy(ref)
    geometry.backend = "embree"
    geometry.color = None  # geometry only: shown (and compared) as normals
    diff, vs = sheet._difference(other, ref)
    assert vs == "colour" and diff.min() >= 2 and diff.max() == 3
    gd, gvs = sheet._difference(geometry, ref)
    assert gvs == "normals" and gd.max() == 0
    one = read_image_u8(sheet.contact_sheet([other, geometry], tmp_path / "one.png"))
    two = read_image_u8(sheet.contact_sheet([ref, other, geometry], tmp_path / "two.png"))[..., :3]
    assert two.shape[0] > 1.8 * one.shape[0]  # a second row: the differences
    # titles are inside the figure: the top and left margins are background, not cut-off text
    assert (two[:3] > 240).all() and (two[:, :3] > 240).all()
