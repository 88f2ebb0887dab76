"""Stochastic renders (scene samples > 1), compared statistically (``check_stochastic``): a per-pixel
Z-test -- Welch's t, ``z_test`` -- with a Sidak correction and a pass fraction, and per-shape means with
standard errors (Mitsuba's sensor against the reference at the same samples).
"""

from __future__ import annotations

import math

import numpy as np

from minirt.harness.results import INCONCLUSIVE, Check
from minirt.harness.tolerances import THRESHOLDS
from minirt.model.result import RenderResult
from minirt.model.scene import Scene


def _light_scale(scene: Scene, position: np.ndarray) -> np.ndarray:
    """Per pixel pi r^2: Mitsuba's point light and diffuse BSDF carry I / (pi r^2), and I = lc.

    For a pixel average, r is taken at the pixel's centre ray: the average of f * g over a pixel
    with g = 1/r^2 smooth differs from mean(f) * g(centre) only in second order of the footprint.
    """
    lpos = np.asarray(scene.light.position)
    r2 = np.sum((position - lpos) ** 2, axis=-1)
    return (math.pi * r2)[..., None] * np.ones(3)


def sidak_alpha(alpha: float, m: int) -> float:
    """Šidák's per-test significance for m independent tests at family-wise significance alpha:
    1 - (1 - alpha)^(1/m) (Šidák 1967; Mitsuba's test_renders.py uses it over all pixel-channels).
    Written out because no installed library provides it: SciPy has no family-wise corrections
    (only false_discovery_control), and statsmodels' multipletests(method="sidak") is not a dependency."""
    return 1 - (1 - alpha) ** (1 / max(int(m), 1))


DOF_NORMAL = 1e9  # degrees of freedom standing for the normal law (no variance to estimate)


def z_test(a: np.ndarray, var_a: np.ndarray, n_a: int, b: np.ndarray, var_b: np.ndarray, n_b: int, mask: np.ndarray):
    """Per pixel-channel two-sample test of equal means (Welch's t); Šidák-corrected significance.

    The variances are estimated from the samples themselves (n_a, n_b >= 2), so the statistic follows
    Student's t with Welch-Satterthwaite degrees of freedom, not the normal law: with 4 samples per
    pixel the normal law rejects far too often (a fuzzed 4-sample scene failed a correct render). With
    many samples the t law becomes the Z-test of Mitsuba's own render tests.

    The test is scipy.stats.ttest_ind_from_stats(equal_var=False), with one addition: a floor
    (z_var_floor) on the squared standard error ea + eb (ea = var_a / n_a). SciPy takes no floor, so
    both variances are scaled by (ea + eb + floor) / (ea + eb): the Welch-Satterthwaite degrees of
    freedom, (ea + eb)^2 / (ea^2 / (n_a - 1) + eb^2 / (n_b - 1)), are homogeneous of degree 0 in
    (ea, eb) and do not change, while the standard error becomes sqrt(ea + eb + floor). Where both
    variances are 0 there is nothing to estimate: the normal law (t with DOF_NORMAL) on the floor alone.

    SciPy's test is taken from ``_welch`` below, its own steps on ``scipy.special.stdtr`` (the law
    scipy.stats' t-test and t distribution evaluate), and not from scipy.stats: importing scipy.stats
    costs 0.4 s alone and 0.9 s inside a five-oracle check, on the thread every check waits for, for
    this one call. tests/harness/test_stochastic.py pins the p-values bit for bit to scipy.stats'.

    Returns (p-values, alpha corrected, pass fraction) over the masked pixel-channels.
    """
    from scipy.special import stdtr

    if n_a < 2 or n_b < 2:
        raise ValueError(f"Welch's test needs variances estimated from >= 2 samples per side (got {n_a}, {n_b})")
    floor = THRESHOLDS["z_var_floor"].value
    var_a, var_b = np.asarray(var_a, dtype=np.float64), np.asarray(var_b, dtype=np.float64)
    e = var_a / n_a + var_b / n_b
    some = e > 0
    scale = np.where(some, (e + floor) / np.where(some, e, 1.0), 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):  # the 0/0 of zero-variance pixels, replaced below
        welch = _welch(a, np.sqrt(var_a * scale), n_a, b, np.sqrt(var_b * scale), n_b)
        constant = 2 * stdtr(DOF_NORMAL, -(np.abs(a - b) / np.sqrt(floor)))
    p = np.where(some, welch, constant)
    vals = p[mask]
    alpha = sidak_alpha(THRESHOLDS["z_significance"].value, vals.size)
    frac = float((vals > alpha).mean()) if vals.size else 1.0
    return p, alpha, frac


def _welch(mean1, std1, n1, mean2, std2, n2) -> np.ndarray:
    """Two-sided p-values of scipy.stats.ttest_ind_from_stats(..., equal_var=False), in SciPy's own steps
    (scipy/stats/_stats_py.py: _unequal_var_ttest_denom, _ttest_ind_from_stats, _get_pvalue and
    _SimpleStudentT.sf), so the bits are SciPy's; the caller silences 0/0."""
    from scipy.special import stdtr

    vn1, vn2 = np.asarray(std1) ** 2 / n1, np.asarray(std2) ** 2 / n2
    df = (vn1 + vn2) ** 2 / (vn1**2 / (n1 - 1) + vn2**2 / (n2 - 1))
    df = np.where(np.isnan(df), 1.0, df)  # SciPy's: undefined only where both variances are 0
    t = np.divide(np.asarray(mean1) - np.asarray(mean2), np.sqrt(vn1 + vn2))
    return 2 * stdtr(df, -np.abs(t))


def _scale_bias(f: np.ndarray, g: np.ndarray, shape_id: np.ndarray) -> np.ndarray:
    """Bound on the error of converting a pixel average with the centre value of its factor.

    Mitsuba averages f h over a pixel (h = 1/g = I/(pi r^2)); we multiply its average by g(centre).
    For smooth f and h over a unit pixel, mean(f h) = f(c) h(c) + (f lap h + h lap f + 2 grad f . grad h)/24
    + O(4th order), and the reference's own average already holds the h lap f part; the remaining
    g (f lap h + 2 grad f . grad h) / 24 is the conversion's bias. Central differences in pixel units;
    pixels with a neighbour on another shape get none (they are edge pixels, excluded anyway).
    """
    h = 1.0 / g
    out = np.zeros_like(f)
    for axis in (0, 1):
        fp, fm = np.roll(f, -1, axis), np.roll(f, 1, axis)
        hp, hm = np.roll(h, -1, axis), np.roll(h, 1, axis)
        out += np.abs(f * (hp + hm - 2 * h) + 2 * (fp - fm) * (hp - hm) / 4) / 24
    same = np.ones(shape_id.shape, bool)
    for axis in (0, 1):
        same &= (np.roll(shape_id, 1, axis) == shape_id) & (np.roll(shape_id, -1, axis) == shape_id)
    return np.where(same[..., None], out * g, 0.0)


def check_stochastic(scene, ref, res, classes, edges, centre: RenderResult) -> Check:
    """Mitsuba's sensor at n spp against the reference at n samples: Z-test and per-shape means.

    `centre` is the reference's one-ray render through pixel centres (for the pi r^2 factor).
    """
    n_ref = int(ref.meta.get("settings", {}).get("samples", 1))
    n_res = int(res.meta.get("options", {}).get("spp", res.meta.get("settings", {}).get("spp", 1)))
    if n_ref < 2 or "variance" not in res.aux or "variance_diffuse" not in ref.aux:
        return Check("skip", reason="statistical comparison needs samples > 1 on both sides")
    scale = _light_scale(scene, centre.position)
    b = res.color * scale
    var_b = res.aux["variance"] * scale**2
    if "diffuse_r2" in ref.aux:
        # like with like: the reference's own samples of diffuse / r^2 (what Mitsuba's point light averages),
        # scaled by the same pi r_c^2. The centre-value conversion below assumed r smooth over the pixel; on
        # a plane seen far and grazing at 16x16 it was 4 % off (fuzz random_7_5, 21 sigma on its shape mean).
        r2c = scale / math.pi
        a, var_a = ref.aux["diffuse_r2"] * r2c, ref.aux["variance_diffuse_r2"] * r2c**2
        bias = np.zeros_like(a)
    else:
        bias = _scale_bias(ref.terms["diffuse"], scale, centre.shape_id)
        a, var_a = ref.terms["diffuse"], ref.aux["variance_diffuse"]
    cover = res.aux.get("coverage", np.ones(ref.hit.shape))
    interior = ref.hit & ~edges & (cover >= 1 - 1e-6)
    # Where a plane's rectangle errs by more than the oracle's spawn offset (meta ray_epsilon (1 + max|p|)),
    # its stock shadow ray may re-hit the rectangle itself: those shadow decisions are not the oracle's to
    # make (a fuzzed floor reaching the horizon, contact_26_0: abs_error 0.04 against an offset of 4e-4).
    self_shadow = _self_shadow(res, centre, ref.hit.shape)
    interior &= ~self_shadow
    mask = np.repeat(interior[..., None], 3, axis=-1)
    p, alpha, frac = z_test(a, var_a, n_ref, b, var_b, n_res, mask)
    shapes, bad_shapes = _shape_means(scene, ref, interior, a, var_a, n_ref, b, var_b, n_res, bias)
    figures = {
        "samples": n_ref,
        "spp": n_res,
        "compared_pixel_channels": int(mask.sum()),
        "self_shadow_unjudged_pixels": int((self_shadow & ref.hit).sum()),
        "alpha_sidak": alpha,
        "pass_fraction": frac,
        "shape_means": shapes,
    }
    bad = []
    if frac < THRESHOLDS["z_pass_fraction"].value:
        bad.append(f"Z-test: {frac:.4%} of pixel-channels pass, {THRESHOLDS['z_pass_fraction'].value:.2%} required")
    if bad_shapes:
        bad.append(f"mean shading differs on shape(s) {bad_shapes}")
    thresholds = {
        k: f"{THRESHOLDS[k].value}: {THRESHOLDS[k].why}"
        for k in ("z_significance", "z_pass_fraction", "z_var_floor", "shape_mean_sigma")
    }
    images = {"p_value": np.where(mask, p, 1.0).min(axis=-1), "edges": edges, "not_judged": ref.hit & ~interior}
    hits = int(ref.hit.sum())
    unsure = int((self_shadow & ref.hit).sum())
    limit = THRESHOLDS["inconclusive_fraction"].value
    if not bad and hits and unsure > limit * hits:
        share = f"{unsure / hits:.0%} of the hit pixels"
        reason = (f"{INCONCLUSIVE}this oracle cannot judge this scene (its shadow decisions on {share} lie "
                  f"within its own rectangles' float32 error, more than {limit:.0%})")  # fmt: skip
        return Check("warn", figures, reason, thresholds, images)
    return Check("fail" if bad else "pass", figures, "; ".join(bad), thresholds, images)


def _self_shadow(res: RenderResult, centre: RenderResult, shape: tuple[int, ...]) -> np.ndarray:
    """The pixels whose stock shadow ray may re-hit the oracle's own plane rectangle (its error there is
    above its spawn offset): bool, of ``shape``."""
    self_shadow = np.zeros(shape, bool)
    eps = res.meta.get("ray_epsilon")
    if eps:
        offset = eps * (1 + np.abs(centre.position).max(axis=-1))
        for key, plane in (res.meta.get("planes") or {}).items():
            on = centre.shape_id == int(key.removeprefix("shape"))
            self_shadow |= on & (plane.get("abs_error", 0.0) >= offset)
    return self_shadow


def _shape_means(scene, ref: RenderResult, interior, a, var_a, n_ref: int, b, var_b, n_res: int, bias):
    """Per shape of at least 4 interior pixels: the two sides' mean diffuse and how many standard errors
    apart they are beyond the known bias; and the shapes too far apart (``shape_mean_sigma``)."""
    shapes = {}
    bad_shapes = []
    for k in range(len(scene.shapes)):
        m = interior & (ref.shape_id == k)
        if m.sum() < 4:
            continue
        ma, mb = a[m].mean(0), b[m].mean(0)
        se = np.sqrt(var_a[m].sum(0) / n_ref + var_b[m].sum(0) / n_res) / m.sum()
        known = bias[m].mean(0) + 1e-6 * np.abs(ma)  # the pi r^2 approximation, and float32 rounding
        dev = np.maximum(np.abs(ma - mb) - known, 0) / np.maximum(se, 1e-12)
        shapes[str(k)] = {
            "pixels": int(m.sum()),
            "reference": ma.tolist(),
            "oracle": mb.tolist(),
            "known_bias": known.tolist(),
            "sigma": dev.max().item(),
        }
        if dev.max() > THRESHOLDS["shape_mean_sigma"].value:
            bad_shapes.append(k)
    return shapes, bad_shapes
