"""The shading check (minirt.harness.shading): a physical oracle's shadow decisions where its planes did not
cover the shadow rays, and colour-science imported without its plots."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from support.synthetic import candidate, reference

from minirt.harness.geometry import check_geometry
from minirt.harness.shading import check_shading


@pytest.fixture(scope="module")
def setup():
    return reference()


def test_shadow_decisions_are_not_judged_where_an_oracles_planes_did_not_cover_the_segments(setup):
    """A physical oracle whose finite stand-ins for planes still missed points after their last growth
    (Mitsuba's meta plane_coverage_complete False) cannot decide shadows: lit flips are not counted."""
    scene, rules, ref = setup
    cand = candidate(ref)
    diffuse = ref.terms["diffuse"].copy()
    lit = (diffuse > 0).all(-1)
    inner = lit.copy()  # lit pixels whose 7x7 neighbourhood is lit: far from terminators and shadow edges
    for dy in range(-3, 4):
        for dx in range(-3, 4):
            inner &= np.roll(np.roll(lit, dy, 0), dx, 1)
    ys, xs = np.nonzero(inner)
    y, x = ys[len(ys) // 2], xs[len(xs) // 2]
    diffuse[y - 1 : y + 2, x - 1 : x + 2] = 0.0  # a 3x3 patch shadowed in the oracle only
    cand.aux = {"diffuse_exercise": diffuse}
    geom = check_geometry(scene, rules, ref, cand)  # as a precise oracle's: tiny band
    cand.backend = "mitsuba"  # shading: the physical model's diffuse buffer
    for complete, verdict in ((True, "fail"), (False, "pass")):
        cand.meta["plane_coverage_complete"] = complete
        shading = check_shading(scene, ref, cand, geom)
        assert shading.verdict == verdict, (complete, shading.reason, shading.figures)
        assert shading.figures["plane_coverage_complete"] is complete


def test_colour_is_imported_without_its_plots_and_they_still_load():
    """color_differences imports colour-science without matplotlib.pyplot (half the import's time, paid by
    every process that checks shading); colour.plotting then loads on first use, as if nothing happened."""
    code = """
import sys
import numpy as np
from minirt.harness.shading import color_differences
a = np.zeros((4, 4, 3), np.uint8)
d = color_differences(a, a + 10)
assert d["delta_e_mean"] > 0, d
assert "matplotlib.pyplot" not in sys.modules and "colour.plotting" not in sys.modules
import colour
assert callable(colour.plotting.plot_single_colour_swatch)  # loads the real package
import colour.plotting as cp
assert cp is sys.modules["colour.plotting"] is colour.plotting and "matplotlib.pyplot" in sys.modules
"""
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr


def test_equal_bitmaps_are_zero_without_computing_the_metrics(monkeypatch):
    """Two equal bitmaps (on the pixels traced) differ by exactly 0 in both metrics -- the same figures and
    maps the metrics give, without computing them; one level apart, they are computed."""
    import flip_evaluator

    from minirt.harness.shading import color_differences

    rng = np.random.default_rng(5)
    a = rng.integers(0, 256, (12, 10, 3), dtype=np.uint8)
    b = a.copy()
    b[3, 4, 1] ^= 1
    traced = np.ones((12, 10), dtype=bool)
    traced[3, 4] = False
    with monkeypatch.context() as m:  # the metrics computed, as they were before the shortcut
        m.setattr(np, "array_equal", lambda *x, **k: False)
        computed = [color_differences(a, a.copy()), color_differences(a, b, traced)]
    calls = []
    real = flip_evaluator.evaluate
    monkeypatch.setattr(flip_evaluator, "evaluate", lambda *x, **k: calls.append(1) or real(*x, **k))
    for equal in (color_differences(a, a.copy()), color_differences(a, b, traced)):
        for was in computed:
            assert {k: v for k, v in equal.items() if not k.startswith("_")} == {
                k: v for k, v in was.items() if not k.startswith("_")
            }
            for k in ("_delta_e", "_flip"):
                assert equal[k].dtype == was[k].dtype and equal[k].tobytes() == was[k].tobytes()
    assert calls == []
    assert color_differences(a, b)["delta_e_max"] > 0 and calls == [1]
