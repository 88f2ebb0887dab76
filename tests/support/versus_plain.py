"""The fast tracer against the plain transcription (tests/support/plain.py), ray for ray: shared by the
tests of every rule."""

from __future__ import annotations

import numpy as np

from minirt.model import camera
from minirt.reference.tracer import Tracer
from support.plain import render_plain

SIZE = 20
TOL = 1e-9


def _compare(scene, rules):
    fast = Tracer(scene, rules).render()
    o, d = camera.primary_rays(scene, rules)
    colors, fragile = render_plain(scene, rules, o, d)
    plain = np.array(colors).reshape(SIZE, SIZE, 3)
    fragile = np.array(fragile).reshape(SIZE, SIZE)
    diff = np.abs(fast.color - plain).max(axis=-1)
    bad = (diff > TOL) & ~fragile
    assert fragile.mean() < 0.02, f"{fragile.sum()} fragile pixels"
    assert not bad.any(), f"{bad.sum()} pixels differ, max {diff[bad].max():.3g} at {np.argwhere(bad)[0]}"
    return diff
