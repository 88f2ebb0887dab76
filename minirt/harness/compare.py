"""The harness: compare any backend's RenderResult with the reference, pixel by pixel and statistically.

For each scene and oracle:
1. Pre-flight: same size, required channels present, no NaN or infinity where the other side is
   finite, values in range. (OpenImageIO's compare lets NaN pixels and size mismatches pass: we
   check ourselves, first, and fail loudly.)
2. The reference is rendered under the rules the oracle can follow (``oracle.adapt``), so the
   comparison is like with like.
3. Geometry on the same rays: hit mask, shape id, t, normal, with a per-pixel silhouette band and
   tolerances derived from the oracle's own precision (minirt.harness.tolerances).
4. Shading: deterministic per pixel where the oracle shades the same rays (POV-Ray: the whole
   model in 8 bits; Mitsuba: the diffuse term with its physical factors divided out), colour
   differences as CIEDE2000 and FLIP summaries; pixels on silhouettes, shadow edges and terminators
   are classified and reported apart. For stochastic renders (scene samples > 1): a per-pixel
   Z-test with a Sidak correction and a pass fraction, and per-shape means with standard errors
   (Mitsuba's sensor); and, from an oracle that can shoot the reference's own stratified samples
   (POV-Ray's mesh camera), the averaged image compared per pixel like a one-ray render, with the
   band taken over every sample's ray.
5. Rules, two ways. Rule effects: per rule the oracle cannot follow, the pixels of the scene-rules
   reference image that flipping that rule alone changes (a mask per rule) -- what the rule does in
   the reference, not what the oracle did. Rule diagnosis (oracles that shade the exercise's model,
   shading_model "exercise"): minirt.diagnose.search searches rule space from the scene's rules for the
   settings whose reference render reproduces the oracle's 8-bit image, and reports them, the
   pixels each explains and the pixels (beyond one 8-bit level) that nothing explains.
Verdicts: PASS, WARN, FAIL, ERROR (the backend broke), SKIP (does not apply, with the reason).
"""

from __future__ import annotations

import contextlib
import math
import sys
import threading
import time
import types
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from minirt.errors import MinirtError
from minirt.harness import backends
from minirt.harness.tolerances import THRESHOLDS, geometry_tolerance
from minirt.model import camera
from minirt.model.backend import farthest_hit
from minirt.model.result import RenderResult
from minirt.model.rules import Rules, resolve
from minirt.model.scene import Scene, load_scene
from minirt.reference import band

if TYPE_CHECKING:
    from minirt.jobs.cache import Cache

ORDER = ["skip", "pass", "warn", "fail", "error"]


def worst(verdicts: list[str]) -> str:
    vs = [v for v in verdicts if v]
    if not vs:
        return "skip"
    real = [v for v in vs if v != "skip"]
    return max(real, key=ORDER.index) if real else "skip"


@dataclass
class Check:
    verdict: str
    figures: dict[str, Any] = field(default_factory=dict)
    reason: str = ""
    thresholds: dict[str, str] = field(default_factory=dict)
    images: dict[str, np.ndarray] = field(default_factory=dict)  # evidence for the report

    @property
    def inconclusive(self) -> bool:
        """WARN because the check could not have failed on most of what it judges."""
        return self.verdict == "warn" and self.reason.startswith(INCONCLUSIVE)

    def as_dict(self) -> dict[str, Any]:
        d = {"verdict": self.verdict, **self.figures}
        if self.reason:
            d["reason"] = self.reason
        if self.thresholds:
            d["thresholds"] = self.thresholds
        return d


@dataclass
class RuleDiagnosis:
    """Which rule settings explain an oracle's colour image (minirt.diagnose.search, searched from the scene's
    rules). Counts are pixels beyond one 8-bit level, ill-conditioned pixels left out."""

    ran: bool = False
    reason: str = ""  # why it did not run, or why no search was needed
    # The diagnosis's changed rules that explain pixels (taken back singly, at least one pixel is lost) ...
    rules_explaining: dict[str, str] = field(default_factory=dict)
    explained: dict[str, int] = field(default_factory=dict)  # ... and per rule, the pixels it explains
    # ... and those the best setting changed too (a whole profile is one step) that explain none: this image
    # cannot tell them from the scene's (a background rule over a black background, say).
    cannot_tell: dict[str, str] = field(default_factory=dict)
    mismatch_pixels: int = 0  # still unexplained under rules_explaining
    as_given_pixels: int = 0  # differing from the reference under the scene's rules
    ill_conditioned_pixels: int = 0
    pixels: int = 0
    declared: dict[str, str] = field(default_factory=dict)  # rules the oracle says it follows, where they differ
    renders: float = 0.0
    seconds: float = 0.0
    unexplained_mask: np.ndarray | None = None
    explained_masks: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def undeclared(self) -> dict[str, str]:
        """Settings that explain the image but that the oracle does not declare: a finding about the oracle."""
        return {k: v for k, v in self.rules_explaining.items() if self.declared.get(k) != v}

    @property
    def not_needed(self) -> dict[str, str]:
        """Declared settings the diagnosis did not need: they change nothing this image shows (e.g. the offset
        under clamping, where a point facing away from the light is dark whether it shadows itself or not)."""
        return {k: v for k, v in self.declared.items() if k not in self.rules_explaining}

    def as_dict(self) -> dict[str, Any]:
        if not self.ran:
            return {"ran": False, "reason": self.reason}
        d: dict[str, Any] = {
            "ran": True,
            "rules_explaining": self.rules_explaining,
            "explained": self.explained,
            "cannot_tell": self.cannot_tell,
            "mismatch_pixels": self.mismatch_pixels,
            "as_given_pixels": self.as_given_pixels,
            "ill_conditioned_pixels": self.ill_conditioned_pixels,
            "pixels": self.pixels,
            "tolerance": "1 level per channel (8-bit)",
            "declared": self.declared,
            "undeclared": self.undeclared,
            "not_needed": self.not_needed,
            "renders": self.renders,
            "seconds": round(self.seconds, 3),
        }
        if self.reason:
            d["reason"] = self.reason
        return d


@dataclass
class BackendCheck:
    backend: str
    verdict: str
    reason: str = ""
    checks: dict[str, Check] = field(default_factory=dict)
    # Rule effects (JSON "rule_effects"): per rule the oracle cannot follow, the pixels of the scene-rules
    # reference that flipping that rule alone changes, and their masks (``attribute_rules``).
    rules: dict[str, int] = field(default_factory=dict)
    rule_masks: dict[str, np.ndarray] = field(default_factory=dict)
    rules_followed: dict[str, Any] = field(default_factory=dict)
    seconds: float = 0.0
    result: RenderResult | None = None
    reference: RenderResult | None = None
    # Rule diagnosis (JSON "rule_diagnosis"): the settings that explain the oracle's own image.
    rule_diagnosis: RuleDiagnosis = field(default_factory=lambda: RuleDiagnosis(reason="not run"))

    @property
    def rule_effects(self) -> dict[str, int]:
        return self.rules

    @property
    def inconclusive(self) -> bool:
        """A WARN whose only cause is checks that could not have failed (the report shows it as inconclusive)."""
        warned = [c for c in self.checks.values() if c.verdict == "warn"]
        return self.verdict == "warn" and bool(warned) and all(c.inconclusive for c in warned)

    def as_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"verdict": self.verdict, "inconclusive": self.inconclusive}
        if self.reason:
            d["reason"] = self.reason
        for name, c in self.checks.items():
            d[name] = c.as_dict()
        d["rule_effects"] = self.rules
        d["rule_diagnosis"] = self.rule_diagnosis.as_dict()
        d["rules_followed"] = self.rules_followed
        d["seconds"] = round(self.seconds, 3)
        if self.result is not None:
            d["version"] = self.result.meta.get("version")
        return d


@dataclass
class SceneCheck:
    scene: str
    file: str
    verdict: str
    backends: dict[str, BackendCheck] = field(default_factory=dict)
    reference: RenderResult | None = None
    description: str = ""
    reason: str = ""

    def as_dict(self) -> dict[str, Any]:
        d = {"scene": self.scene, "file": self.file, "verdict": self.verdict, "description": self.description}
        if self.reason:
            d["reason"] = self.reason
        d["backends"] = {k: v.as_dict() for k, v in self.backends.items()}
        return d


@dataclass
class CheckResult:
    verdict: str
    scenes: list[SceneCheck]
    meta: dict[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return {
            "verdict": self.verdict,
            "scenes": [s.as_dict() for s in self.scenes],
            "thresholds": {k: {"value": t.value, "why": t.why} for k, t in THRESHOLDS.items()},
            **self.meta,
        }

    def exit_code(self) -> int:
        if self.verdict == "error":
            return 2
        return 1 if self.verdict == "fail" else 0


# ---------------------------------------------------------------------------------------------
# 1. Pre-flight


def preflight(ref: RenderResult, res: RenderResult, need_color: bool) -> Check:
    problems = []
    if (res.width, res.height) != (ref.width, ref.height):
        problems.append(f"size {res.width}x{res.height}, expected {ref.width}x{ref.height}")
    for name in ("hit", "shape_id", "t", "position", "normal"):
        a = getattr(res, name)
        if a is None:
            problems.append(f"missing {name} buffer")
        elif a.shape[:2] != (ref.height, ref.width):
            problems.append(f"{name} buffer is {a.shape[1]}x{a.shape[0]}, expected {ref.width}x{ref.height}")
    if need_color and res.color is None:
        problems.append("missing colour")
    if problems:
        return Check("fail", {"problems": problems}, reason="; ".join(problems))
    # (NaN or infinity where the reference is finite is judged per pixel, against the band, in check_geometry)
    out_of_range = []
    n_shapes = int(ref.meta.get("shapes", 0)) or int(max(ref.shape_id.max(), res.shape_id.max()) + 1)
    if res.shape_id.min() < -1 or res.shape_id.max() >= max(n_shapes, 1):
        out_of_range.append(f"shape ids outside [-1, {n_shapes - 1}]")
    if not np.array_equal(res.hit, res.shape_id >= 0):
        out_of_range.append("hit mask and shape ids disagree")
    # (normals' length is judged with their direction, per pixel, in check_geometry)
    if res.color is not None and np.nanmin(res.color) < -1e-6:
        out_of_range.append("negative colour")
    if out_of_range:
        return Check("fail", {"problems": out_of_range}, reason="; ".join(out_of_range))
    return Check("pass")


# ---------------------------------------------------------------------------------------------
# 3. Geometry


def angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle between vectors, stable for tiny angles (atan2 of |a x b| and a . b, not acos)."""
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.einsum("...i,...i", a, b)))


def check_geometry(scene: Scene, rules: Rules, ref: RenderResult, res: RenderResult) -> Check:
    o, d = camera.primary_rays(scene, rules)
    margins = band.margins(scene, o, d)
    tol = geometry_tolerance(
        res,
        ref,
        margins,
        start=lambda **kw: band.start_band(scene, o, d, **kw),
        scaled=lambda **scales: band.margins(scene, o, d, **scales),
    )
    mism = ref.hit != res.hit
    inside, outside = mism & tol.band, mism & ~tol.band
    both = ref.hit & res.hit
    # NaN or infinity where the reference is finite: inside the band the oracle's own precision cannot
    # decide the pixel (a float32 normal of a ball 1e8 away, fuzz far_31_0), outside it is a defect.
    nonfinite = res.hit & ~np.isfinite(res.t)
    said = {"t": int(nonfinite.sum())}
    for name in ("position", "normal", "color"):
        a, b = getattr(res, name), getattr(ref, name)
        if a is not None and b is not None:
            bad = (~np.isfinite(a) & np.isfinite(b)).any(axis=-1)
            nonfinite |= bad
            said[name] = int(bad.sum())
    nf_out = nonfinite & ~tol.band
    idm = both & (ref.shape_id != res.shape_id)
    if tol.ties is not None:  # the oracle's per-shape depth ties
        ties = idm & tol.ties
    else:
        tie_eps = tol.summary.get("band_eps", 1e-6)
        ties = idm & (margins["id_tie"].reshape(ref.height, ref.width) < max(tie_eps, 1e-12) * 4)
    id_out = idm & ~tol.band & ~ties
    same = both & ~idm & ~nonfinite
    dt = np.abs(np.where(same, ref.t, 0.0) - np.where(same, res.t, 0.0))  # misses hold inf
    rel = np.where(same, dt / np.maximum(np.abs(np.where(same, ref.t, 1.0)), 1e-300), 0.0)
    ang = np.where(same, angle_deg(ref.normal, res.normal), 0.0)
    judged = same & ~tol.band
    t_viol = judged & (dt > tol.t_abs)
    n_viol = judged & (ang > tol.normal_deg)
    # A normal's length: an oracle's normal (p - C) / r whose hit point p is off by dp is off by up to dp / r
    # in length as in direction (radians), so the per-pixel normal tolerance bounds both; never below 1e-3
    # (an encoding's resolution: POV-Ray's split channels give 4.8e-7). Far from the origin a float32 or a
    # cancelling discriminant makes dp / r large, and its band holds those pixels (fuzz far_7_2: |n| 0.9).
    n_len = np.abs(np.linalg.norm(res.normal, axis=-1) - 1.0)
    len_viol = judged & (n_len > np.maximum(1e-3, np.radians(tol.normal_deg)))
    figures = {
        "pixels": int(ref.hit.size),
        "band_pixels": int(tol.band.sum()),
        "mask_mismatch": int(mism.sum()),
        "mask_mismatch_outside_band": int(outside.sum()),
        "id_mismatch": int(id_out.sum()),
        "ties": int(ties.sum()),
        "nonfinite": {k: v for k, v in said.items() if v},
        "nonfinite_outside_band": int(nf_out.sum()),
        "depth_rel_err_max": float(rel[same].max()) if same.any() else 0.0,
        "depth_rel_err_p99": float(np.percentile(rel[same], 99)) if same.any() else 0.0,
        "depth_violations": int(t_viol.sum()),
        "normal_deg_max": float(ang[same].max()) if same.any() else 0.0,
        "normal_violations": int(n_viol.sum()),
        "normal_length_err_max": float(n_len[judged].max()) if judged.any() else 0.0,
        "normal_length_violations": int(len_viol.sum()),
        "tolerance": tol.summary,
    }
    figures["inconclusive"] = inconclusive(ref, res, tol.band, judged, tol.t_abs, tol.normal_deg)
    bad = []
    if nf_out.any():
        where = ", ".join(f"{k}: {v}" for k, v in said.items() if v)
        bad.append(
            f"NaN or infinity where the reference is finite at {int(nf_out.sum())} pixel(s) outside the band ({where})"
        )
    if outside.any():
        bad.append(f"{int(outside.sum())} hit-mask mismatch(es) outside the silhouette band")
    if id_out.any():
        bad.append(f"{int(id_out.sum())} shape id mismatch(es)")
    if t_viol.any():
        bad.append(f"{int(t_viol.sum())} t error(s) above tolerance")
    if n_viol.any():
        bad.append(f"{int(n_viol.sum())} normal error(s) above tolerance")
    if len_viol.any():
        bad.append(f"{int(len_viol.sum())} normal(s) not unit length beyond tolerance (|n| - 1 up to "
                   f"{float(n_len[len_viol].max()):.3g})")  # fmt: skip
    images = {
        "mask_inside_band": inside,
        "mask_outside_band": outside,
        "id_mismatch": id_out,
        "ties": ties,  # id mismatches at depth ties: not judged
        "depth_rel_err": rel,
        "normal_deg": ang,
        "band": tol.band,
        "not_judged": same & tol.band,  # t and normals compared but not judged: the silhouette band
        "t_tolerance": tol.t_abs,  # per pixel, what a t may differ by (the campaign's "changes judged")
        "normal_tolerance": tol.normal_deg,
    }
    thresholds = {
        "mask_outside_band": f"0: {THRESHOLDS['mask_outside_band'].why}",
        "band": tol.why["band"],
        "t": tol.why["t"],
        "normal": tol.why["normal"],
    }
    limit = THRESHOLDS["inconclusive_fraction"]
    thresholds["inconclusive"] = f"{limit.value}: {limit.why}"
    if bad:
        return Check("fail", figures, reason="; ".join(bad), thresholds=thresholds, images=images)
    why = figures["inconclusive"]["reasons"]
    if why:  # nothing failed, but the check could not have failed on most of what it judges
        reason = f"{INCONCLUSIVE}this oracle cannot judge this scene ({'; '.join(why)})"
        return Check("warn", figures, reason=reason, thresholds=thresholds, images=images)
    return Check("pass", figures, thresholds=thresholds, images=images)


# The reason of a check that could not fail on most of what it judges starts with this (WARN, not PASS).
INCONCLUSIVE = "inconclusive: "


def inconclusive(
    ref: RenderResult,
    res: RenderResult,
    band_px: np.ndarray,
    judged: np.ndarray,
    t_abs: np.ndarray,
    normal_deg: np.ndarray,
) -> dict[str, Any]:
    """Whether the geometry check could have failed on most of what it judges (THRESHOLDS
    "inconclusive_fraction"): the fractions measured, and the reasons it could not (empty: conclusive)."""
    limit = THRESHOLDS["inconclusive_fraction"].value
    hits = ref.hit | res.hit
    n_hits, n_judged = int(hits.sum()), int(judged.sum())
    band_frac = float((band_px & hits).sum() / n_hits) if n_hits else 0.0
    depth_range = float(np.ptp(ref.t[ref.hit])) if ref.hit.any() else 0.0
    with np.errstate(invalid="ignore"):
        t_wide = judged & ~(t_abs < depth_range)  # NaN or inf tolerances count as wide
        n_wide = judged & ~(normal_deg < 90.0)
    t_frac = float(t_wide.sum() / n_judged) if n_judged else 0.0
    n_frac = float(n_wide.sum() / n_judged) if n_judged else 0.0
    reasons = []
    if band_frac > limit:
        reasons.append(
            f"the band holds {band_frac:.0%} of the {n_hits} hit pixels, more than {limit:.0%}: "
            "hit/miss and ids are not judged there"
        )
    if t_frac > limit:
        reasons.append(
            f"the t tolerance is at least the depth range {depth_range:.3g} on {t_frac:.0%} of the judged pixels"
        )
    if n_frac > limit:
        reasons.append(f"the normal tolerance is 90 degrees or more on {n_frac:.0%} of the judged pixels")
    return {
        "reasons": reasons,
        "hit_pixels": n_hits,
        "judged_pixels": n_judged,
        "band_fraction": band_frac,
        "depth_range": depth_range,
        "t_wide_fraction": t_frac,
        "normal_wide_fraction": n_frac,
        "limit": limit,
    }


# ---------------------------------------------------------------------------------------------
# 4. Shading


def edge_classes(ref: RenderResult) -> dict[str, np.ndarray]:
    """Pixels whose 3x3 neighbourhood crosses a silhouette, a shadow edge or a terminator -- seen
    directly, or further down the ray tree (in a reflection: the reference's aux ray_tree labels each
    pixel by every decision its colour rests on)."""
    from scipy import ndimage

    def changes(labels: np.ndarray) -> np.ndarray:
        mx = ndimage.maximum_filter(labels, size=3, mode="nearest")
        mn = ndimage.minimum_filter(labels, size=3, mode="nearest")
        return mx != mn

    sil = changes(ref.shape_id)
    lit = (ref.terms.get("diffuse", np.zeros((ref.height, ref.width, 3))) > 0).any(-1) | (
        ref.terms.get("specular", np.zeros((ref.height, ref.width, 3))) > 0
    ).any(-1)
    light_edge = changes(lit.astype(np.int8)) & ~sil
    out = {"silhouette": sil, "shadow_or_terminator": light_edge}
    if "ray_tree" in ref.aux:
        out["in_reflection"] = changes(ref.aux["ray_tree"]) & ~sil & ~light_edge
    return out


def _edges(classes: dict[str, np.ndarray], band_px: np.ndarray) -> np.ndarray:
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


def color_differences(a8: np.ndarray, b8: np.ndarray) -> dict[str, float]:
    """CIEDE2000 (colour-science) and FLIP (flip-evaluator) on 8-bit images read as sRGB display values."""
    import flip_evaluator

    colour = _colour()

    fa, fb = a8.astype(np.float64) / 255.0, b8.astype(np.float64) / 255.0
    lab_a = colour.XYZ_to_Lab(colour.sRGB_to_XYZ(fa))
    lab_b = colour.XYZ_to_Lab(colour.sRGB_to_XYZ(fb))
    de = colour.delta_E(lab_a, lab_b, method="CIE 2000")
    flip_map, flip_mean, _ = flip_evaluator.evaluate(
        fa.astype(np.float32), fb.astype(np.float32), "LDR", applyMagma=False
    )
    return {
        "delta_e_mean": float(de.mean()),
        "delta_e_p95": float(np.percentile(de, 95)),
        "delta_e_max": float(de.max()),
        "flip_mean": float(flip_mean),
        "_delta_e": de,
        "_flip": np.asarray(flip_map).reshape(a8.shape[:2]),
    }


def check_shading(scene: Scene, ref: RenderResult, res: RenderResult, geom: Check) -> Check:
    model = backends.shading_model(res.backend, res.color is not None)
    if model is None or res.color is None:
        return Check("skip", reason=f"{res.backend} is a geometry-only oracle: it does not shade")
    classes = edge_classes(ref)
    band_px = geom.images.get("band", np.zeros_like(ref.hit))
    edges = _edges(classes, band_px)
    if model == "exercise":
        return _shading_exercise(ref, res, classes, edges)
    return _shading_physical(scene, ref, res, classes, edges)


def _shading_exercise(ref, res, classes, edges) -> Check:
    a8, b8 = ref.color8().astype(int), res.color8().astype(int)
    dch = np.abs(a8 - b8)
    d8 = dch.max(axis=-1)
    judged = ~edges
    over = judged & (d8 > THRESHOLDS["color8_levels"].value)
    # A 1-level difference in a channel sitting on a rounding tie is rounding, not shading.
    x = np.clip(np.nan_to_num(ref.color), 0.0, 1.0) * 255 + 0.5
    tie = np.abs(x - np.rint(x)) <= THRESHOLDS["color8_tie_rel"].value * x
    one_any = judged & (d8 == 1)
    one = one_any & ((dch == 1) & ~tie).any(axis=-1)
    frac_one = float(one.sum() / max(judged.sum(), 1))
    cd = color_differences(ref.color8(), res.color8())
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


def _light_scale(scene: Scene, position: np.ndarray) -> np.ndarray:
    """Per pixel pi r^2: Mitsuba's point light and diffuse BSDF carry I / (pi r^2), and I = lc.

    For a pixel average, r is taken at the pixel's centre ray: the average of f * g over a pixel
    with g = 1/r^2 smooth differs from mean(f) * g(centre) only in second order of the footprint.
    """
    lpos = np.asarray(scene.light.position)
    r2 = np.sum((position - lpos) ** 2, axis=-1)
    return (math.pi * r2)[..., None] * np.ones(3)


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


def sidak_alpha(alpha: float, m: int) -> float:
    """Šidák's per-test significance for m independent tests at family-wise significance alpha:
    1 - (1 - alpha)^(1/m) (Šidák 1967; Mitsuba's test_renders.py uses it over all pixel-channels).
    Written out because no installed library provides it: SciPy has no family-wise corrections
    (only false_discovery_control), and statsmodels' multipletests(method="sidak") is not a dependency."""
    return 1 - (1 - alpha) ** (1 / max(int(m), 1))


DOF_NORMAL = 1e9  # degrees of freedom standing for the normal law (no variance to estimate)


def z_test(a: np.ndarray, var_a: np.ndarray, n_a: int, b: np.ndarray, var_b: np.ndarray, n_b: int, mask: np.ndarray):
    """Per pixel-channel two-sample test of equal means (Welch's t, SciPy); Šidák-corrected significance.

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

    Returns (p-values, alpha corrected, pass fraction) over the masked pixel-channels.
    """
    from scipy.stats import t as student_t
    from scipy.stats import ttest_ind_from_stats

    if n_a < 2 or n_b < 2:
        raise ValueError(f"Welch's test needs variances estimated from >= 2 samples per side (got {n_a}, {n_b})")
    floor = THRESHOLDS["z_var_floor"].value
    var_a, var_b = np.asarray(var_a, dtype=np.float64), np.asarray(var_b, dtype=np.float64)
    e = var_a / n_a + var_b / n_b
    some = e > 0
    scale = np.where(some, (e + floor) / np.where(some, e, 1.0), 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):  # the 0/0 of zero-variance pixels, replaced below
        welch = ttest_ind_from_stats(a, np.sqrt(var_a * scale), n_a, b, np.sqrt(var_b * scale), n_b, equal_var=False)
        constant = 2 * student_t.sf(np.abs(a - b) / np.sqrt(floor), DOF_NORMAL)
    p = np.where(some, welch.pvalue, constant)
    vals = p[mask]
    alpha = sidak_alpha(THRESHOLDS["z_significance"].value, vals.size)
    frac = float((vals > alpha).mean()) if vals.size else 1.0
    return p, alpha, frac


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
    self_shadow = np.zeros(ref.hit.shape, bool)
    eps = res.meta.get("ray_epsilon")
    if eps:
        offset = eps * (1 + np.abs(centre.position).max(axis=-1))
        for key, plane in (res.meta.get("planes") or {}).items():
            on = centre.shape_id == int(key.removeprefix("shape"))
            self_shadow |= on & (plane.get("abs_error", 0.0) >= offset)
    interior &= ~self_shadow
    mask = np.repeat(interior[..., None], 3, axis=-1)
    p, alpha, frac = z_test(a, var_a, n_ref, b, var_b, n_res, mask)
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


# ---------------------------------------------------------------------------------------------
# Whole scenes


# The reference terms the checks read (the lit mask, the shading comparison, the report's diffuse
# preview): a reference render for a check writes only these (each term is 24 bytes a pixel of kernel
# writes; tracer.Tracer.render).
CHECKED_TERMS = ("diffuse", "specular")


class ReferenceCache:
    """Reference renders of one scene, keyed by rules (many oracles share the same adapted rules)."""

    def __init__(self, scene: Scene):
        self.scene, self.cache = scene, {}

    def get(self, rules: Rules, samples: int | None = None) -> RenderResult:
        key = (rules, samples)
        if key not in self.cache:
            sc = self.scene if samples is None else self.scene.with_overrides(samples=samples)
            # diagnostics: the ray-tree labels and shadow margins the edge classes and shading checks use.
            # runtime: the rules an oracle's variants differ in are values the kernel reads, so the scene's
            # renders under its oracles' rules share one compiled kernel (the same bits: Tracer, tested).
            opts = {"diagnostics": True, "terms": CHECKED_TERMS, "runtime": True}
            r = backends.render(backends.REFERENCE, sc, rules, opts)
            if not r.ok:
                raise MinirtError(f"{self.scene.source}: the reference tracer failed: {r.reason}")
            r.meta["shapes"] = len(self.scene.shapes)
            self.cache[key] = r
        return self.cache[key]


def attribute_rules(
    refs: ReferenceCache, rules: Rules, followed: Rules
) -> tuple[dict[str, int], dict[str, np.ndarray]]:
    """Rule effects: pixels of the scene-rules image that each rule the oracle cannot follow changes,
    singly (what the rule does in the reference; ``diagnose_oracle`` says what explains the oracle)."""
    base = refs.get(rules)
    counts, masks = {}, {}
    for name in rules.differs(followed):
        alt = refs.get(replace(rules, **{name: getattr(followed, name)}))
        m = (alt.color8() != base.color8()).any(-1) | (alt.hit != base.hit)
        counts[name], masks[name] = int(m.sum()), m
    return counts, masks


# One render cache for the diagnoses of a check run (a process runs one check; harness.run and the
# sample report pass their own). Bounded: the diagnosis keeps full renders, least recently used out.
VARIANT_CACHE_BYTES = 1 << 30
_variants: Any = None


def shared_variants():
    """The process's VariantCache for check's diagnoses, made on first use."""
    global _variants
    if _variants is None:
        from minirt.diagnose.variants import VariantCache

        _variants = VariantCache(VARIANT_CACHE_BYTES)
    return _variants


def diagnose_oracle(scene: Scene, rules: Rules, followed: Rules, res: RenderResult, variants=None) -> RuleDiagnosis:
    """Which rule settings explain the oracle's 8-bit colour image, searched from the scene's rules.

    The search starts from the scene's traced rules with the output rules at their defaults -- the
    oracle's image is ``color8()``, written as floor(c·255 + 0.5) in the scene's layout whatever the
    scene's own output rules say -- on one ray per pixel, the rays the oracle cast. Where the oracle's
    image is the scene's rules' image within one level on every pixel, nothing needs explaining and
    no search runs (one render)."""
    from minirt import diagnose as dg
    from minirt.model import bitmap
    from minirt.model import rules as rules_mod

    t0 = time.perf_counter()
    variants = variants if variants is not None else shared_variants()
    one = scene.with_overrides(samples=1)
    given = rules.traced()
    declared = {n: rules_mod.format_rule_value(n, getattr(followed, n)) for n in rules.differs(followed)}
    img = res.color8()
    h, w = scene.camera.height, scene.camera.width
    out = RuleDiagnosis(ran=True, declared=declared, pixels=h * w)
    before = variants.renders
    base = variants.get(one, given)
    d8 = np.abs(bitmap.encode(base.color).astype(np.int16) - img.astype(np.int16)).max(-1)
    if not (d8 > dg.LEVEL_TOL).any():
        out.reason = "no search needed: the image is the scene's rules' within one 8-bit level on every pixel"
        out.unexplained_mask = np.zeros((h, w), dtype=bool)
    else:
        # the oracle's image is color8(): written floor(c·255 + 0.5) in the scene's layout, output rules known
        d = dg.diagnose(
            one, given, dg.Target(img, False, name=res.backend), variants, alternatives=False, outputs=False
        )
        pixels = {e.rule: e.pixels for e in d.explained}
        out.rules_explaining = {k: v for k, v in d.changed.items() if pixels.get(k, 0) > 0}
        out.cannot_tell = {k: v for k, v in d.changed.items() if pixels.get(k, 0) == 0}
        out.explained = {k: pixels[k] for k in out.rules_explaining}
        out.explained_masks = {e.rule: e.mask for e in d.explained if e.rule in out.rules_explaining}
        out.mismatch_pixels = d.mismatch_pixels
        out.as_given_pixels = d.as_given_pixels
        out.ill_conditioned_pixels = int(d.ill.sum())
        out.unexplained_mask = d.best_mask
    out.renders = round(variants.renders - before, 2)
    out.seconds = time.perf_counter() - t0
    return out


def check_backend(
    scene: Scene,
    rules: Rules,
    name: str,
    refs: ReferenceCache,
    options: dict | None = None,
    variants=None,
    rendered=None,
    explain: bool = True,
) -> BackendCheck:
    """``rendered``: the backend's render of (scene, rules, options) when it was started earlier (a
    concurrent.futures.Future or a RenderResult), else it is rendered here. ``explain=False`` leaves out
    what only explains the verdict -- the rule effects and the rule diagnosis, renders of their own --
    for runs that want verdicts alone (a fuzzing campaign)."""
    t0 = time.perf_counter()
    followed = backends.rules_for(name, rules) if backends.info(name).available else rules
    bc = BackendCheck(backend=name, verdict="skip", rules_followed=followed.as_dict())
    if rendered is None:
        with ThreadPoolExecutor(max_workers=1) as pool:
            started = _start_ahead(pool, [name], scene, rules, options)
            if started:  # it renders while the reference it is compared with does
                with contextlib.suppress(MinirtError):  # raised again below, where it always was
                    refs.get(followed, samples=1)
            res = started[name].result() if started else backends.render(name, scene, rules, options)
    else:
        res = rendered.result() if hasattr(rendered, "result") else rendered
    bc.result = res
    if not res.ok:
        bc.verdict, bc.reason = res.status, res.reason
        bc.seconds = time.perf_counter() - t0
        return bc
    ref = refs.get(followed, samples=1)  # deterministic checks: the one-ray-per-pixel rays the oracle cast
    bc.reference = ref
    pre = preflight(ref, res, need_color=False)
    bc.checks["preflight"] = pre
    if pre.verdict == "fail":
        bc.verdict, bc.reason = "fail", f"pre-flight: {pre.reason}"
    else:
        geom = check_geometry(scene, followed, ref, res)
        bc.checks["geometry"] = geom
        bc.checks["shading"] = check_shading(scene, ref, res, geom)
        known = backends.find(name)  # a result no backend made (a test's) has no sample checks
        model = known.shading_model if known else None
        if scene.samples > 1 and model == "physical":
            bc.checks["stochastic"] = _stochastic_run(scene, followed, name, refs, geom)
        if scene.samples > 1 and model == "exercise":
            bc.checks["samples"] = _samples_run(scene, followed, name, refs)
        bc.verdict = worst([c.verdict for c in bc.checks.values()])
        # worst first; an inconclusive check's reason as it is ("inconclusive: ..."), ahead of other warnings
        said = [(k, c) for k, c in bc.checks.items() if c.verdict in ("fail", "warn", "error")]
        said.sort(key=lambda kc: (-ORDER.index(kc[1].verdict), not kc[1].inconclusive))
        bc.reason = "; ".join(c.reason if c.inconclusive else f"{k}: {c.reason}" for k, c in said)
    if not explain:
        bc.rule_diagnosis = RuleDiagnosis(reason="not asked for")
        bc.seconds = time.perf_counter() - t0
        return bc
    bc.rules, bc.rule_masks = attribute_rules(refs, rules, followed)
    model = backends.shading_model(name, res.color is not None)
    if model != "exercise" or res.color is None:
        why = "does not shade" if model is None or res.color is None else f"shades a {model} model, not the exercise's"
        bc.rule_diagnosis = RuleDiagnosis(reason=f"{name} {why}: no rule setting can explain its colour")
    elif pre.verdict == "fail":
        bc.rule_diagnosis = RuleDiagnosis(reason=f"{name}'s image failed pre-flight")
    else:
        bc.rule_diagnosis = diagnose_oracle(scene, rules, followed, res, variants)
    bc.seconds = time.perf_counter() - t0
    return bc


def _stochastic_run(scene: Scene, rules: Rules, name: str, refs: ReferenceCache, geom: Check) -> Check:
    res = backends.render(name, scene, rules, {"mode": "sensor", "spp": scene.samples})
    if not res.ok:
        return Check("skip" if res.status == "skip" else "error", reason=res.reason)
    ref = refs.get(rules)
    centre = refs.get(replace(rules, pixel_sample="center"), samples=1)
    classes = edge_classes(ref)
    edges = _edges(classes, geom.images["band"])
    return check_stochastic(scene, ref, res, classes, edges, centre)


def _samples_run(scene: Scene, rules: Rules, name: str, refs: ReferenceCache) -> Check:
    """An oracle of the exercise's model rendering the reference's own stratified samples (option
    ``samples``): the averaged colour is compared per pixel like a one-ray render, with the band taken
    over every sample's ray."""
    n = scene.samples
    res = backends.render(name, scene, rules, {"samples": n})
    if not res.ok:
        return Check("skip" if res.status == "skip" else "error", reason=res.reason)
    ref = refs.get(rules)
    p = res.meta.get("precision") or {}
    band_px = band.sample_band(
        scene,
        rules,
        n,
        p.get("band_threshold", 0.0),
        p.get("min_distance", 0.0),
        p.get("start_err", 0.0),
        p.get("band_scale"),
        p.get("band_origin_scale"),
        farthest_hit(p),
        p.get("band_inside_scale"),
    )
    classes = edge_classes(ref)
    edges = _edges(classes, band_px)
    check = _shading_exercise(ref, res, classes, edges)
    check.figures = {"samples": n, "sample_band_pixels": int(band_px.sum()), **check.figures}
    return check


def _scene_and_rules(path: str | Path, size: tuple[int, int] | None) -> tuple[Scene, Rules]:
    scene = load_scene(path)
    if size:
        scene = scene.with_overrides(width=size[0], height=size[1])
    return scene, resolve(scene)


def check_scene(
    path: str | Path,
    names: list[str],
    size: tuple[int, int] | None = None,
    progress=None,
    variants=None,
    rendered: dict | None = None,
    loaded: tuple[Scene, Rules] | None = None,
) -> SceneCheck:
    """Check one scene file against the given backends (the reference itself is always rendered).
    ``variants``: the run's minirt.diagnose.variants.VariantCache (default: the process's, ``shared_variants``);
    ``rendered``: backend name -> its render started earlier, ``loaded``: the file's scene and rules
    already parsed (both from ``run``)."""
    scene, rules = loaded or _scene_and_rules(path, size)
    if rendered is None:
        # POV-Ray's render, a child process that mostly waits, starts now on a thread of its own and
        # overlaps the reference's and the other oracles' work here (as ``run`` does): the same results
        with ThreadPoolExecutor(max_workers=1) as pool:
            started = _start_ahead(pool, names, scene, rules)
            if started:
                return check_scene(path, names, size, progress, variants, started, (scene, rules))
    sc = SceneCheck(scene=scene.name, file=str(path), verdict="skip", description=scene.description)
    refs = ReferenceCache(scene)
    sc.reference = refs.get(rules)
    oracle_names = backends.oracles_among(names)
    for i, name in enumerate(oracle_names):
        if progress:
            progress(scene.name, name, i, len(oracle_names))
        got = (rendered or {}).get(name)
        sc.backends[name] = check_backend(scene, rules, name, refs, variants=variants, rendered=got)
    sc.verdict = worst([b.verdict for b in sc.backends.values()])  # no oracle: skip, nothing was compared
    return sc


def run(
    paths: list[Path],
    names: list[str],
    size: tuple[int, int] | None = None,
    progress=None,
    workers: int = 1,
    scheduler: str | None = None,
    cache: Path | None = None,
) -> CheckResult:
    """Check every scene file against the backends. ``progress(i, scene, backend, j, n)``: scene i's
    backend j of n is starting (in this process) or has finished (on workers).

    ``workers`` > 1 or a Dask ``scheduler``: each (scene, oracle) is one job of minirt.jobs.batch, run on that
    many local worker processes or on the cluster's workers; the job carries the scene file's text, so
    workers need minirt and the renderers, not the files. The verdicts and figures are the same.
    ``cache``: a folder of job results (minirt.jobs.cache) keyed by the scene's text and name, the size, the
    oracle and the versions; a job it holds is not run again (jobs run one by one here then, without
    POV-Ray's renders started ahead)."""
    loaded = [_scene_and_rules(p, size) for p in paths]  # each file parsed once, for every use below
    _fits_in_memory([s for s, _ in loaded], names, 0 if scheduler else workers if workers > 1 else 0)
    if workers > 1 or scheduler is not None or cache is not None:
        return _run_jobs(paths, loaded, names, size, progress, workers, scheduler, cache)
    from minirt.diagnose.variants import VariantCache

    variants = VariantCache(VARIANT_CACHE_BYTES)
    # POV-Ray runs as a separate process: its renders of every scene start now, one after the other on
    # a thread of their own, and overlap the reference's, Mitsuba's and Embree's work in this process
    # (the cores are otherwise idle while Python waits for POV-Ray). The same results, in less time.
    with ThreadPoolExecutor(max_workers=1) as pool:
        rendered = [_start_ahead(pool, names, *sr) for sr in loaded]
        scenes = []
        for i, (p, r, sr) in enumerate(zip(paths, rendered, loaded, strict=True)):
            tick = None if progress is None else (lambda *a, i=i: progress(i, *a))
            scenes.append(check_scene(p, names, size, tick, variants, r, sr))
    return CheckResult(verdict=worst([s.verdict for s in scenes]), scenes=scenes)


def _fits_in_memory(scenes: list[Scene], names, local_workers: int) -> None:
    """Bad input before any work: a check this machine cannot hold (minirt.jobs.memory), as one line."""
    from minirt.jobs import memory

    pixels = [s.camera.width * s.camera.height for s in scenes]
    oracles = backends.oracles_among(names)
    big = max(scenes, key=lambda s: s.camera.width * s.camera.height)
    what = f"{len(scenes)} scenes, the largest" if len(scenes) > 1 else "the scene"
    memory.require(
        backends.check_bytes(pixels, oracles, local_workers),
        f"checking {what} at {big.camera.width}x{big.camera.height} against {len(oracles)} oracle(s)",
        "check at a smaller --size, or fewer scenes at a time",
    )


@dataclass(frozen=True)
class CheckJob:
    """One (scene, oracle) check of ``run`` on a worker: the scene file's text and name, the size override."""

    source: str
    text: str
    size: tuple[int, int] | None
    backend: str


def check_text(
    text: str, source: str, backend: str, size: tuple[int, int] | None = None, explain: bool = True
) -> tuple[Scene, Rules, ReferenceCache, BackendCheck]:
    """One oracle's check of a scene given as text (what a job carries to a worker): the scene, its
    rules, the reference renders made for the check (to reuse) and the check itself."""
    from minirt.model.scene import parse_scene

    scene = parse_scene(text, source=source)
    if size:
        scene = scene.with_overrides(width=size[0], height=size[1])
    rules = resolve(scene)
    refs = ReferenceCache(scene)
    return scene, rules, refs, check_backend(scene, rules, backend, refs, explain=explain)


def check_job(job: CheckJob) -> tuple[BackendCheck, RenderResult]:
    """A job of ``_run_jobs``: the oracle's check and the reference at the scene's samples."""
    _, rules, refs, bc = check_text(job.text, job.source, job.backend, job.size)
    return bc, refs.get(rules)


def check_cache(folder: Path, oracles: list[str]) -> Cache:
    """The cache of ``run``'s jobs in ``folder``: results with arrays, so pickled (see minirt.jobs.cache)."""
    from minirt.harness.backends import versions
    from minirt.jobs.cache import Cache, digest, pickle_codec

    v = versions(oracles)

    def key(job: CheckJob) -> str:
        return digest({"kind": "check", "source": job.source, "text": job.text, "size": job.size,
                       "backend": job.backend, "minirt": v["minirt"], "drjit": v["drjit"],
                       "oracle": v.get(job.backend, "")})  # fmt: skip

    # an error may be passing (a dead worker, a crashed renderer): never stored, redone next time
    return Cache(folder, key, pickle_codec, keep=lambda got: got[0].verdict != "error")


def _run_jobs(paths, loaded, names, size, progress, workers, scheduler, cache: Path | None = None) -> CheckResult:
    """``run``'s scene files as jobs; ``loaded``: their (scene, rules), parsed before any job starts."""
    from minirt.jobs import batch as jobs

    oracles = backends.oracles_among(names)
    todo = [
        CheckJob(str(p), Path(p).read_text(encoding="utf-8"), size, n) for p in paths for n in oracles
    ]  # fmt: skip
    index = {id(j): (k // max(len(oracles), 1), k % max(len(oracles), 1)) for k, j in enumerate(todo)}

    def done(job: CheckJob, _result) -> None:
        if progress:
            i, j = index[id(job)]
            progress(i, loaded[i][0].name, job.backend, j + 1, len(oracles))

    def failed(job: CheckJob, message: str):
        return BackendCheck(backend=job.backend, verdict="error", reason=message), None

    store = None if cache is None else check_cache(cache, oracles)
    got = jobs.run(check_job, todo, workers=workers, scheduler=scheduler, on_done=done, on_error=failed, cache=store)
    scenes = []
    for i, (p, (scene, rules)) in enumerate(zip(paths, loaded, strict=True)):
        sc = SceneCheck(scene=scene.name, file=str(p), verdict="skip", description=scene.description)
        for j, name in enumerate(oracles):
            bc, ref = got[i * len(oracles) + j]
            sc.backends[name] = bc
            sc.reference = sc.reference or ref
        if sc.reference is None:  # no oracle (or every job died): the reference itself, here
            sc.reference = ReferenceCache(scene).get(rules)
        sc.verdict = worst([b.verdict for b in sc.backends.values()])  # no oracle: skip, nothing was compared
        scenes.append(sc)
    return CheckResult(verdict=worst([s.verdict for s in scenes]), scenes=scenes)


# Backends whose renders run in a child process, started ahead by ``run``, ``check_scene`` and
# ``check_backend`` (``_start_ahead``).
def _start_ahead(pool: ThreadPoolExecutor, names, scene: Scene, rules: Rules, options=None) -> dict[str, Any]:
    """Start on ``pool`` the renders of those of ``names`` that run as a child process and are installed
    (the backend's ``concurrent``): name -> Future. Such a render mostly waits for its process, so it overlaps the
    work this process does meanwhile; the results are the same."""
    return {
        n: pool.submit(backends.render, n, scene, rules, options)
        for n in names
        if backends.get(n).concurrent and backends.info(n).available
    }


# ---------------------------------------------------------------------------------------------
# JUnit


def junit_xml(result: CheckResult) -> str:
    import xml.etree.ElementTree as ET

    root = ET.Element("testsuites", name="minirt check")
    for s in result.scenes:
        suite = ET.SubElement(root, "testsuite", name=s.scene, file=s.file)
        n = {"tests": 0, "failures": 0, "errors": 0, "skipped": 0}
        for b in s.backends.values():
            checks = b.checks or {"render": Check(b.verdict, reason=b.reason)}
            for cname, c in checks.items():
                case = ET.SubElement(
                    suite, "testcase", classname=f"{s.scene}.{b.backend}", name=cname, time=f"{b.seconds:.3f}"
                )
                n["tests"] += 1
                if c.verdict == "fail":
                    ET.SubElement(case, "failure", message=c.reason or "fail")
                    n["failures"] += 1
                elif c.verdict == "error":
                    ET.SubElement(case, "error", message=c.reason or "error")
                    n["errors"] += 1
                elif c.verdict == "skip":
                    ET.SubElement(case, "skipped", message=c.reason or "skip")
                    n["skipped"] += 1
        for k, v in n.items():
            suite.set(k, str(v))
    return ET.tostring(root, encoding="unicode", xml_declaration=True)
