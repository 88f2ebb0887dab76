"""A synthetic oracle for the harness's tests: a reference render of scenes/shadows.toml at SIZE x SIZE under
the conventional rules (``reference``), and ``candidate``, a copy of it posing as a backend as precise as
float64, for a test to inject a defect into."""

from __future__ import annotations

import copy

from minirt.model.rules import PROFILES
from minirt.model.scene import load_scene
from minirt.reference.tracer import Tracer

SIZE = 48


def reference():
    """(scene, rules, reference render), its shape count in meta as the harness's reference cache sets it."""
    scene = load_scene("scenes/shadows.toml").with_overrides(width=SIZE, height=SIZE)
    rules = PROFILES["conventional"]
    ref = Tracer(scene, rules).render()
    ref.meta["shapes"] = len(scene.shapes)
    return scene, rules, ref


def candidate(ref, **precision):
    c = copy.deepcopy(ref)
    c.backend = "synthetic"
    # A backend as precise as float64: tiny band and tolerances, so any real change shows.
    c.meta["precision"] = {"band_eps": 1e-9, "t_rel": 1e-12, "t_abs": 1e-12, "normal_deg": 1e-9, **precision}
    return c
