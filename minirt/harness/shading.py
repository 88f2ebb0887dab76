"""Shading, deterministic per pixel where the oracle shades the same rays (POV-Ray: the whole model in
8 bits, ``shading_exercise``; Mitsuba: the diffuse term with its physical factors divided out,
``_shading_physical``), colour differences as CIEDE2000 and FLIP summaries (``color_differences``); pixels on
silhouettes, shadow edges and terminators are classified (``edge_classes``) and reported apart.
"""

from __future__ import annotations

import sys
import threading
import types
from typing import Any

import numpy as np

from minirt.harness import backends
from minirt.harness.results import Check
from minirt.harness.tolerances import THRESHOLDS
from minirt.model import bitmap
from minirt.model.result import RenderResult, edge_classes
from minirt.model.scene import Scene


def edge_pixels(classes: dict[str, np.ndarray], band_px: np.ndarray) -> np.ndarray:
    """The pixels a per-pixel colour comparison leaves out: the geometry's band and every edge class."""
    out = band_px.copy()
    for mask in classes.values():
        out |= mask
    return out


_COLOUR_LOCK = threading.Lock()


def _colour() -> Any:
    """colour-science, its plotting package loaded lazily. ``colour/__init__`` imports ``colour.plotting``
    first, which imports matplotlib.pyplot and the plotting styles: about half of the ~1 s the import
    costs every process that checks shading (a one-scene `minirt check` took 3.6 s). minirt uses three
    colorimetry functions and never colour's plots, so during the import ``colour.plotting`` is a stand-in
    module, taken out of ``sys.modules`` afterwards; the first attribute read from it (or an ``import
    colour.plotting``) loads the real package, so a user's code in the same process sees no difference."""
    with _COLOUR_LOCK:
        if "colour" in sys.modules:  # (importing colour.plotting imports colour first)
            return sys.modules["colour"]
        stub = types.ModuleType("colour.plotting")

        def real(name: str) -> Any:
            import importlib

            return getattr(importlib.import_module("colour.plotting"), name)

        stub.__getattr__ = real  # PEP 562: a module's __getattr__ answers the names it lacks
        sys.modules["colour.plotting"] = stub
        try:
            import colour
        finally:
            if sys.modules.get("colour.plotting") is stub:
                del sys.modules["colour.plotting"]
        return colour


def color_differences(a8: np.ndarray, b8: np.ndarray, traced: np.ndarray | None = None) -> dict[str, float]:
    """CIEDE2000 (colour-science) and FLIP (flip-evaluator) on 8-bit images read as sRGB display values.
    ``traced``: where ``b8`` holds data (None: everywhere); the figures are of those pixels, and FLIP's
    filters see ``a8`` in the others, so a pixel not traced adds no difference to its neighbours'."""
    if traced is not None:
        b8 = np.where(traced[..., None], b8, a8)
    if np.array_equal(a8, b8):
        # The same bitmap: every difference is exactly 0 (CIEDE2000's terms of equal Lab values, FLIP's
        # filtered equal images: +0.0 everywhere, measured), so the ~0.15 s of the two metrics -- a check of the
        # bundled scenes asks this for twelve of its sixteen comparisons -- is not spent.
        h, w = a8.shape[:2]
        zero = {"delta_e_mean": 0.0, "delta_e_p95": 0.0, "delta_e_max": 0.0, "flip_mean": 0.0}
        return {**zero, "_delta_e": np.zeros((h, w)), "_flip": np.zeros((h, w), np.float32)}
    import flip_evaluator

    colour = _colour()

    fa, fb = a8.astype(np.float64) / 255.0, b8.astype(np.float64) / 255.0
    lab_a = colour.XYZ_to_Lab(colour.sRGB_to_XYZ(fa))
    lab_b = colour.XYZ_to_Lab(colour.sRGB_to_XYZ(fb))
    de = colour.delta_E(lab_a, lab_b, method="CIE 2000")
    flip_map, flip_mean, _ = flip_evaluator.evaluate(
        fa.astype(np.float32), fb.astype(np.float32), "LDR", applyMagma=False
    )
    flip_map = np.asarray(flip_map).reshape(a8.shape[:2])
    sel = de if traced is None else de[traced]
    if traced is not None:
        flip_mean = float(flip_map[traced].mean()) if traced.any() else 0.0
    return {
        "delta_e_mean": float(sel.mean()) if sel.size else 0.0,
        "delta_e_p95": float(np.percentile(sel, 95)) if sel.size else 0.0,
        "delta_e_max": float(sel.max()) if sel.size else 0.0,
        "flip_mean": float(flip_mean),
        "_delta_e": de,
        "_flip": flip_map,
    }


def check_shading(scene: Scene, ref: RenderResult, res: RenderResult, geom: Check) -> Check:
    model = backends.shading_model(res.backend, res.color is not None)
    if model is None or res.color is None:
        return Check("skip", reason=f"{res.backend} is a geometry-only oracle: it does not shade")
    classes = edge_classes(ref)
    band_px = geom.images.get("band", np.zeros_like(ref.hit))
    edges = edge_pixels(classes, band_px)
    if model == "exercise":
        return shading_exercise(ref, res, classes, edges)
    return _shading_physical(scene, ref, res, classes, edges)


def shading_exercise(ref, res, classes, edges) -> Check:
    """An oracle of the exercise's model: its 8-bit image against the reference's, per pixel off ``edges``
    (also the averaged image of the reference's own samples, minirt.harness.compare's ``_samples_run``)."""
    a8, b8 = ref.color8().astype(int), res.color8().astype(int)
    dch = np.abs(a8 - b8)
    d8 = bitmap.channel_max(dch)
    traced = res.traced  # a render of chosen pixels is judged where it traced
    if traced is not None:
        edges = edges | ~traced
    judged = ~edges
    over = judged & (d8 > THRESHOLDS["color8_levels"].value)
    # A 1-level difference in a channel sitting on a rounding tie is rounding, not shading.
    x = np.clip(np.nan_to_num(ref.color), 0.0, 1.0) * 255 + 0.5
    tie = np.abs(x - np.rint(x)) <= THRESHOLDS["color8_tie_rel"].value * x
    one_any = judged & (d8 == 1)
    one = one_any & bitmap.channel_any((dch == 1) & ~tie)
    frac_one = float(one.sum() / max(judged.sum(), 1))
    cd = color_differences(ref.color8(), res.color8(), traced)
    rel = np.abs(ref.color - res.color) / np.maximum(np.abs(ref.color), 1e-3)
    figures = {
        "compared_pixels": int(judged.sum()),
        "edge_pixels": {k: int(v.sum()) for k, v in classes.items()},
        "color8_max_diff": int(d8[judged].max()) if judged.any() else 0,
        "color8_over_1": int(over.sum()),
        "color8_off_by_one": int(one.sum()),
        "color8_off_by_one_at_ties": int((one_any & ~one).sum()),
        "color8_diff_on_edges": int((edges & (d8 > 0)).sum()),
        "color_rel_err_max": float(rel[judged].max()) if judged.any() else 0.0,
        **{k: v for k, v in cd.items() if not k.startswith("_")},
    }
    verdict, reason = "pass", ""
    if over.any():
        verdict, reason = "fail", f"{int(over.sum())} pixel(s) differ by more than 1 level off edges"
    elif frac_one > THRESHOLDS["color8_off_by_one_fraction"].value:
        verdict, reason = "warn", f"{frac_one:.2%} of pixels differ by 1 level"
    elif figures["delta_e_p95"] > THRESHOLDS["delta_e_p95"].value:
        verdict, reason = "warn", f"CIEDE2000 p95 {figures['delta_e_p95']:.2f}"
    images = {"color8_diff": d8, "delta_e": cd["_delta_e"], "flip": cd["_flip"], "edges": edges, "not_judged": edges}
    thresholds = {
        k: f"{THRESHOLDS[k].value}: {THRESHOLDS[k].why}"
        for k in ("color8_levels", "color8_off_by_one_fraction", "color8_tie_rel", "delta_e_p95")
    }
    return Check(verdict, figures, reason, thresholds, images)


def _shading_physical(scene, ref, res, classes, edges) -> Check:
    if "diffuse_exercise" not in res.aux:
        return Check("skip", reason="no per-ray diffuse buffer (a sensor render is compared statistically)")
    a = ref.terms.get("diffuse", np.zeros_like(ref.color))
    b = res.aux["diffuse_exercise"]
    both_hit = ref.hit & res.hit & (ref.shape_id == res.shape_id)
    lc_dc = np.zeros_like(a)
    for k, s in enumerate(scene.shapes):
        lc_dc[ref.shape_id == k] = np.asarray(scene.light.color) * np.asarray(s.material.diffuse)
    lit_a, lit_b = (a > 0).any(-1), (b > 0).any(-1)
    judged = both_hit & ~edges
    err = np.abs(a - b)
    # A plane's hit point errs by the oracle's recorded absolute error (Mitsuba's rectangles: meta planes)
    # divided by the view ray's |cos| against the plane: the error of where the ray meets the plane moves
    # the interpolated point along the plane by 1/cos of it (fuzz scene random_3_2, a ray at cos 0.188:
    # the point 0.495 off the ray, abs_error 0.092 / 0.188 = 0.489). That turns the direction to the
    # light by up to shift / |L - p|, and n·s with it.
    turn = np.zeros(ref.hit.shape)
    shift = np.zeros(ref.hit.shape)  # the oracle's hit-point error
    dist = np.linalg.norm(ref.position - np.asarray(scene.light.position), axis=-1)
    view = ref.position - np.asarray(scene.camera.position)  # every primary ray's line passes the camera
    cos = np.abs(np.sum(view * ref.normal, axis=-1)) / np.maximum(np.linalg.norm(view, axis=-1), 1e-300)
    for key, plane in (res.meta.get("planes") or {}).items():
        k = int(key.removeprefix("shape"))
        on = ref.shape_id == k
        shift[on] = plane.get("abs_error", 0.0) / np.maximum(cos[on], 1e-12)
        turn[on] = shift[on] / np.maximum(dist[on], 1e-300)
    # A shadow decision can flip when the hit point's error reaches the shadow ray's distance from an
    # occluder's silhouette (the reference's aux shadow_margin): such pixels are not judged on lit/unlit.
    margin = ref.aux.get("shadow_margin")
    unsure = both_hit & (shift > 0) & (margin < 2 * shift) if margin is not None else np.zeros_like(both_hit)
    # The oracle's finite stand-ins for planes did not cover every point a shadow ray crosses (Mitsuba's
    # rectangles after their last growth, meta plane_coverage_complete): no shadow decision is its to make.
    uncovered = res.meta.get("plane_coverage_complete") is False
    if uncovered:
        unsure = both_hit.copy()
    flips = lit_a != lit_b
    lit_flip = judged & flips & ~unsure
    allowed = (THRESHOLDS["diffuse_rel"].value + turn[..., None]) * np.maximum(lc_dc, 1e-12)
    over = (judged & ~(unsure & flips))[..., None] & (err > allowed)
    rel = np.where(lc_dc > 0, err / np.maximum(lc_dc, 1e-12), 0.0)
    figures = {
        "compared_pixels": int(judged.sum()),
        "edge_pixels": {k: int(v.sum()) for k, v in classes.items()},
        "diffuse_rel_err_max": float(rel[judged].max()) if judged.any() else 0.0,
        "diffuse_over_tolerance": int(over.any(-1).sum()),
        "lit_mismatch": int(lit_flip.sum()),
        "lit_mismatch_on_edges": int((both_hit & edges & (lit_a != lit_b)).sum()),
        "lit_mismatch_within_position_error": int((judged & flips & unsure).sum()),
        "plane_coverage_complete": not uncovered,
        "not_compared_terms": res.meta.get("unsupported_terms", []),
    }
    bad = []
    if lit_flip.any():
        bad.append(f"{int(lit_flip.sum())} pixel(s) lit on one side and shadowed on the other, off edges")
    if over.any():
        bad.append(f"{int(over.any(-1).sum())} diffuse value(s) above tolerance")
    not_judged = both_hit & (edges | (unsure & flips))  # edges; shadow decisions within the hit point's error
    images = {"diffuse_rel_err": rel.max(axis=-1), "lit_mismatch": lit_flip, "edges": edges, "not_judged": not_judged}
    thresholds = {
        "diffuse_rel": f"{THRESHOLDS['diffuse_rel'].value}: {THRESHOLDS['diffuse_rel'].why} On a plane, plus "
        "abs_error / (|cos| |L - p|) (the hit point's error, grazing rays' larger, turning the light direction); "
        "largest here "
        f"{float(turn.max()):.3g}."
    }
    return Check("fail" if bad else "pass", figures, "; ".join(bad), thresholds, images)
