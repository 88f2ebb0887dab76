"""Golden images of the reference tracer's own output (64x64, every profile, every bundled scene).

A golden that differs fails with the command that refreshes the goldens on purpose:
    make goldens
(that is: MINIRT_UPDATE_GOLDENS=1 .venv/bin/pytest tests/reference/test_goldens.py). The new image and the
difference are written under tests/_evidence/goldens/.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from support.evidence import EVIDENCE

from minirt.io.images import read_image_u8, write_image
from minirt.model.rules import PROFILES
from minirt.model.scene import load_scene
from minirt.reference.tracer import Tracer

GOLDENS = Path(__file__).resolve().parents[1] / "goldens"
UPDATE = os.environ.get("MINIRT_UPDATE_GOLDENS") == "1"


@pytest.mark.parametrize("profile", list(PROFILES))
def test_golden(scene_path, profile):
    scene = load_scene(scene_path).with_overrides(width=64, height=64, samples=1)
    img = Tracer(scene, PROFILES[profile]).render().color8()
    path = GOLDENS / f"{scene.name}.{profile}.png"
    if UPDATE or not path.exists():
        if not UPDATE:
            pytest.fail(f"no golden {path.name}; create the goldens on purpose with: make goldens")
        write_image(path, img)
        return
    gold = read_image_u8(path)
    if not np.array_equal(gold, img):
        ev = EVIDENCE / "goldens"
        write_image(ev / f"{path.stem}.new.png", img)
        diff = (np.abs(gold.astype(int) - img.astype(int)).max(-1) > 0).astype(np.uint8) * 255
        write_image(ev / f"{path.stem}.diff.png", diff)
        n = int((gold != img).any(-1).sum())
        pytest.fail(f"{path.name}: {n} pixel(s) differ (evidence in {ev}); if intended, refresh with: make goldens")
