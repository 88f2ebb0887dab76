"""The harness tests itself: known defects injected into a reference result must be caught with the
right verdict, and identical inputs, or inputs differing only inside the silhouette band, must pass."""

from __future__ import annotations

import copy
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest

from minirt.harness import compare as harness
from minirt.model.rules import PROFILES
from minirt.model.scene import load_scene
from minirt.reference.tracer import Tracer

SIZE = 48


@pytest.fixture(scope="module")
def setup():
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


def verdicts(scene, rules, ref, cand):
    pre = harness.preflight(ref, cand, need_color=True)
    if pre.verdict != "pass":
        return {"preflight": pre}
    geom = harness.check_geometry(scene, rules, ref, cand)
    return {"preflight": pre, "geometry": geom, "shading": harness.check_shading(scene, ref, cand, geom)}


def test_identical_passes(setup):
    scene, rules, ref = setup
    v = verdicts(scene, rules, ref, candidate(ref))
    assert {k: c.verdict for k, c in v.items()} == {"preflight": "pass", "geometry": "pass", "shading": "pass"}


def test_differences_inside_the_band_pass(setup):
    scene, rules, ref = setup
    cand = candidate(ref, band_eps=2e-2)
    geom = harness.check_geometry(scene, rules, ref, cand)
    band = geom.images["band"] & ref.hit
    assert band.sum() > 10
    cand.hit = ref.hit & ~band  # the oracle misses every ray that grazes a silhouette
    cand.shape_id = np.where(cand.hit, ref.shape_id, -1)
    v = verdicts(scene, rules, ref, cand)
    assert v["geometry"].verdict == "pass"
    assert v["geometry"].figures["mask_mismatch"] == band.sum() > 0
    assert v["geometry"].figures["mask_mismatch_outside_band"] == 0


def _all_buffers(r, f):
    for name in ("hit", "shape_id", "t", "position", "normal", "color"):
        setattr(r, name, f(getattr(r, name)))
    r.terms = {k: f(v) for k, v in r.terms.items()}
    return r


DEFECTS = {
    "one-pixel shift": (lambda r, s: _all_buffers(r, lambda a: np.roll(a, 1, axis=1)), "geometry"),
    "horizontal mirror": (lambda r, s: _all_buffers(r, lambda a: a[:, ::-1].copy()), "geometry"),
    "flipped normals": (lambda r, s: setattr(r, "normal", -r.normal) or r, "geometry"),
    "wrong shape id": (lambda r, s: setattr(r, "shape_id", np.where(r.shape_id == 0, 1, r.shape_id)) or r, "geometry"),
    # (NaN at a hit off the band: row SIZE // 2 is the floor's horizon, in the band, where NaN is not judged)
    "NaN pixel": (lambda r, s: r.color.__setitem__((SIZE // 2 + 6, SIZE // 2, 0), np.nan) or r, "geometry"),
    "NaN position": (lambda r, s: r.position.__setitem__((SIZE // 2 + 6, SIZE // 2, 1), np.nan) or r, "geometry"),
    "wrong image size": (
        lambda r, s: (_all_buffers(r, lambda a: a[:-1]) and setattr(r, "height", SIZE - 1)) or r,
        "preflight",
    ),
    "+5% on one shape": (
        lambda r, s: setattr(r, "color", np.where((r.shape_id == 0)[..., None], r.color * 1.05, r.color)) or r,
        "shading",
    ),
}


@pytest.mark.parametrize("defect", list(DEFECTS))
def test_defect_is_caught(setup, defect):
    scene, rules, ref = setup
    inject, where = DEFECTS[defect]
    cand = inject(candidate(ref), scene)
    v = verdicts(scene, rules, ref, cand)
    assert where in v, f"stopped before {where}: {[(k, c.verdict, c.reason) for k, c in v.items()]}"
    assert v[where].verdict == "fail", (defect, v[where].figures)
    assert v[where].reason


def test_missing_shadow_is_caught(setup):
    scene, rules, ref = setup
    tr = Tracer(scene, rules)
    tr.effects = replace(tr.effects, shadows=False)  # a tracer that forgets shadow rays
    cand = candidate(ref)
    cand.color = tr.render().color
    v = verdicts(scene, rules, ref, cand)
    assert v["geometry"].verdict == "pass"
    assert v["shading"].verdict == "fail"
    assert v["shading"].figures["color8_over_1"] > 10  # the shadowed floor and small ball, lit


def test_z_test_catches_a_bias_and_passes_noise():
    rng = np.random.default_rng(1)
    n = 64
    truth = rng.random((32, 32, 3))
    var = np.full_like(truth, 0.01)
    a = truth + rng.normal(0, np.sqrt(var / n))
    b = truth + rng.normal(0, np.sqrt(var / n))
    mask = np.ones_like(truth, bool)
    _, _, frac = harness.z_test(a, var, n, b, var, n, mask)
    assert frac >= 0.9975
    _, _, frac = harness.z_test(a, var, n, b * 1.2, var, n, mask)
    assert frac < 0.5


@pytest.mark.parametrize("seed", range(5))
def test_z_test_with_estimated_variances_of_few_samples(seed):
    """Variances estimated from 4 samples per pixel (what a 4-spp render reports): the statistic is
    t-distributed with few degrees of freedom; judged as normal, a correct render fails (measured: a
    fuzzed 4-sample scene, 99.74% < 99.75%). Equal means must pass; a doubled image must not."""
    rng = np.random.default_rng(seed)
    n = 4
    truth = rng.random((48, 48, 3))
    sa = truth[..., None] + rng.normal(0, 0.2, (*truth.shape, n))
    sb = truth[..., None] + rng.normal(0, 0.2, (*truth.shape, n))
    a, va = sa.mean(-1), sa.var(-1, ddof=1)
    b, vb = sb.mean(-1), sb.var(-1, ddof=1)
    mask = np.ones_like(truth, bool)
    _, _, frac = harness.z_test(a, va, n, b, vb, n, mask)
    assert frac >= 0.9975
    sc = truth[..., None] * 2 + 1 + rng.normal(0, 0.2, (*truth.shape, 64))
    sd = truth[..., None] + rng.normal(0, 0.2, (*truth.shape, 64))
    _, _, frac = harness.z_test(sc.mean(-1), sc.var(-1, ddof=1), 64, sd.mean(-1), sd.var(-1, ddof=1), 64, mask)
    assert frac < 0.5


def _z_test_before(a, var_a, n_a, b, var_b, n_b, mask):
    """The hand-written Welch test the harness used before it called SciPy (kept to pin the numbers)."""
    from scipy.stats import t as student_t

    floor = harness.THRESHOLDS["z_var_floor"].value
    ea, eb = var_a / n_a, var_b / n_b
    z = np.abs(a - b) / np.sqrt(ea + eb + floor)
    with np.errstate(divide="ignore", invalid="ignore"):
        den = (ea * ea / (n_a - 1) if n_a > 1 else 0.0) + (eb * eb / (n_b - 1) if n_b > 1 else 0.0)
        dof = np.where(den > 0, (ea + eb) ** 2 / den, np.inf)
    dof = np.clip(np.nan_to_num(dof, nan=np.inf), 1.0, 1e9)
    p = 2 * student_t.sf(z, dof)
    vals = p[mask]
    alpha = 1 - (1 - harness.THRESHOLDS["z_significance"].value) ** (1 / max(vals.size, 1))
    return p, alpha, float((vals > alpha).mean()) if vals.size else 1.0


@pytest.mark.parametrize(("n_a", "n_b"), [(4, 4), (2, 64), (64, 1024), (16, 3)])
def test_z_test_p_values_unchanged_by_scipy(n_a, n_b):
    """SciPy's Welch test (with the floor folded into the variances) gives the former p-values to 1e-12,
    including zero-variance pixels (one side or both) and variances far below the floor."""
    rng = np.random.default_rng(n_a * 1000 + n_b)
    a = rng.random((20, 20, 3))
    b = a + rng.normal(0, 0.05, a.shape)
    va, vb = rng.random(a.shape) * 0.1, rng.random(a.shape) * 0.1
    va[0], vb[0], va[1], vb[2, :5] = 0.0, 0.0, 0.0, 1e-12
    b[3] = a[3]  # equal means: p = 1
    mask = rng.random(a.shape) < 0.8
    p_new, alpha_new, frac_new = harness.z_test(a, va, n_a, b, vb, n_b, mask)
    p_old, alpha_old, frac_old = _z_test_before(a, va, n_a, b, vb, n_b, mask)
    assert np.abs(p_new - p_old).max() <= 1e-12
    assert abs(alpha_new - alpha_old) <= 1e-12 * alpha_old and frac_new == frac_old
    assert 0 < frac_new < 1  # the inputs exercise both outcomes


def test_z_test_is_scipys_welch_test_without_the_floor(monkeypatch):
    """With the floor at 0 the p-values are scipy.stats.ttest_ind's Welch test on the samples themselves."""
    from scipy.stats import ttest_ind

    monkeypatch.setitem(harness.THRESHOLDS, "z_var_floor", replace(harness.THRESHOLDS["z_var_floor"], value=0.0))
    rng = np.random.default_rng(3)
    sa, sb = rng.normal(0.5, 0.2, (50, 5)), rng.normal(0.55, 0.1, (50, 9))
    ref = ttest_ind(sa, sb, axis=1, equal_var=False)
    p, _, _ = harness.z_test(sa.mean(1), sa.var(1, ddof=1), 5, sb.mean(1), sb.var(1, ddof=1), 9, np.ones(50, bool))
    assert np.abs(p - ref.pvalue).max() <= 1e-12 and ref.pvalue.min() < 0.05


def test_sidak_alpha():
    assert harness.sidak_alpha(0.01, 1) == pytest.approx(0.01, rel=1e-15)
    m = 3 * 64 * 64
    alpha = harness.sidak_alpha(0.01, m)
    assert (1 - alpha) ** m == pytest.approx(0.99, rel=1e-12)  # family-wise 1 %
    assert 0.01 / m < alpha < 0.01 / m * 1.01  # just above Bonferroni's


def test_verdict_order():
    assert harness.worst(["pass", "skip", "warn"]) == "warn"
    assert harness.worst(["pass", "fail", "error"]) == "error"
    assert harness.worst(["skip", "skip"]) == "skip"
    assert harness.CheckResult("fail", []).exit_code() == 1
    assert harness.CheckResult("error", []).exit_code() == 2
    assert harness.CheckResult("warn", []).exit_code() == 0


# ---------------------------------------------------------------------------------------------
# Honest verdicts: a check that cannot fail is not PASS


def test_a_check_whose_t_tolerance_is_infinite_cannot_pass(setup):
    scene, rules, ref = setup
    cand = candidate(ref, t_abs=np.inf)
    cand.t = np.where(ref.hit, ref.t * 3.0, np.inf)  # every depth wrong by a factor 3: nothing can catch it
    geom = harness.check_geometry(scene, rules, ref, cand)
    assert geom.verdict == "warn" and geom.inconclusive
    assert geom.reason.startswith("inconclusive: this oracle cannot judge this scene (")
    assert "t tolerance" in geom.reason
    fig = geom.figures["inconclusive"]
    assert fig["t_wide_fraction"] == 1.0 and fig["normal_wide_fraction"] == 0.0 and fig["band_fraction"] < 0.5
    assert fig["judged_pixels"] > 0.5 * fig["hit_pixels"]


def test_a_t_tolerance_wider_than_the_depth_range_cannot_pass(setup):
    scene, rules, ref = setup
    depth_range = float(np.ptp(ref.t[ref.hit]))
    wide = harness.check_geometry(scene, rules, ref, candidate(ref, t_abs=1.01 * depth_range))
    narrow = harness.check_geometry(scene, rules, ref, candidate(ref, t_abs=0.99 * depth_range))
    assert wide.verdict == "warn" and wide.inconclusive
    assert narrow.verdict == "pass" and not narrow.figures["inconclusive"]["reasons"]


def test_a_normal_tolerance_of_90_degrees_cannot_pass(setup):
    scene, rules, ref = setup
    geom = harness.check_geometry(scene, rules, ref, candidate(ref, normal_deg=90.0))
    assert geom.verdict == "warn" and "normal tolerance" in geom.reason
    assert harness.check_geometry(scene, rules, ref, candidate(ref, normal_deg=89.0)).verdict == "pass"


def test_a_band_holding_most_hit_pixels_cannot_pass(setup):
    scene, rules, ref = setup
    geom = harness.check_geometry(scene, rules, ref, candidate(ref, band_eps=10.0))  # every margin is < 10
    assert geom.verdict == "warn" and geom.inconclusive
    assert geom.figures["inconclusive"]["band_fraction"] == 1.0 and "the band holds 100%" in geom.reason


def test_an_inconclusive_check_still_fails_on_what_it_can_judge(setup):
    """A wrong shape id is a defect whatever the t tolerance: FAIL, not an inconclusive WARN."""
    scene, rules, ref = setup
    cand = candidate(ref, t_abs=np.inf)
    cand.shape_id = np.where(ref.shape_id == 0, 1, ref.shape_id)
    geom = harness.check_geometry(scene, rules, ref, cand)
    assert geom.verdict == "fail" and "shape id" in geom.reason
    assert geom.figures["inconclusive"]["reasons"]  # the figures still say what could not be judged


def test_a_backend_is_inconclusive_only_when_all_its_warnings_are():
    checks = {
        "geometry": harness.Check("warn", reason="inconclusive: this oracle cannot judge this scene (x)"),
        "shading": harness.Check("warn", reason="CIEDE2000 p95 1.50"),
    }
    b = harness.BackendCheck("synthetic", "warn", checks=checks)
    assert not b.inconclusive  # the shading warning is a finding of its own
    b.checks.pop("shading")
    assert b.inconclusive and b.as_dict()["inconclusive"] is True


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
    geom = harness.check_geometry(scene, rules, ref, cand)  # as a precise oracle's: tiny band
    cand.backend = "mitsuba"  # shading: the physical model's diffuse buffer
    for complete, verdict in ((True, "fail"), (False, "pass")):
        cand.meta["plane_coverage_complete"] = complete
        shading = harness.check_shading(scene, ref, cand, geom)
        assert shading.verdict == verdict, (complete, shading.reason, shading.figures)
        assert shading.figures["plane_coverage_complete"] is complete


def test_nan_inside_the_band_is_counted_not_judged(setup):
    """An oracle's NaN where its own precision cannot decide the pixel (a float32 normal of a ball 1e8 away)
    is not a defect of the reference: counted in the figures, not judged; off the band it FAILs (above)."""
    scene, rules, ref = setup
    cand = candidate(ref)
    cand.normal[SIZE // 2, SIZE // 2] = np.nan  # row SIZE // 2: the floor's horizon, in the band
    geom = harness.check_geometry(scene, rules, ref, cand)
    assert geom.images["band"][SIZE // 2, SIZE // 2]
    assert geom.verdict == "pass", geom.reason
    assert geom.figures["nonfinite"] == {"normal": 1} and geom.figures["nonfinite_outside_band"] == 0


def test_colour_is_imported_without_its_plots_and_they_still_load():
    """color_differences imports colour-science without matplotlib.pyplot (half the import's time, paid by
    every process that checks shading); colour.plotting then loads on first use, as if nothing happened."""
    code = """
import sys
import numpy as np
from minirt.harness.compare import color_differences
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
