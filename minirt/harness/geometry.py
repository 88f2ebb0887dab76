"""Pre-flight and geometry: a backend's buffers against the reference's, on the same rays.

Pre-flight (``preflight``): same size, required channels present, no NaN or infinity where the other side
is finite, values in range. (OpenImageIO's compare lets NaN pixels and size mismatches pass: we check
ourselves, first, and fail loudly.)

Geometry on the same rays (``check_geometry``): hit mask, shape id, t, normal, with a per-pixel silhouette
band and tolerances derived from the oracle's own precision (minirt.harness.tolerances). A check that
could not have failed on most of what it judges says so (``inconclusive``): WARN, not PASS.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from minirt.harness.results import INCONCLUSIVE, Check
from minirt.harness.tolerances import THRESHOLDS, geometry_tolerance
from minirt.model import bitmap, camera
from minirt.model.result import RenderResult
from minirt.model.roots import row_norm
from minirt.model.rules import Rules
from minirt.model.scene import Scene
from minirt.reference import band


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


def angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle between vectors, stable for tiny angles (atan2 of |a x b| and a . b, not acos)."""
    return np.degrees(np.arctan2(row_norm(np.cross(a, b)), np.einsum("...i,...i", a, b)))


def check_geometry(
    scene: Scene, rules: Rules, ref: RenderResult, res: RenderResult, rays: band.Rays | None = None
) -> Check:
    """``rays``: the primary rays under ``rules`` with their margins (minirt.reference.band.Rays), shared by
    every oracle of a check whose rules give the same rays (minirt.harness.references); made here if None."""
    if rays is None:
        rays = band.Rays(scene, *camera.primary_rays(scene, rules))
    margins = rays.margins(bound=band.BOUND)
    tol = geometry_tolerance(
        res,
        ref,
        margins,
        start=rays.start_band,
        scaled=lambda **scales: rays.margins(**scales, bound=1.0),  # compared with 1 (Margins.per_shape_band)
        bound=band.BOUND,
        widen=lambda eps: rays.margins(bound=eps),
    )
    c = _compare(ref, res, tol, margins)
    figures = _figures(ref, tol, c)
    if tol.traced is not None:
        figures["traced_pixels"] = int(tol.traced.sum())
    figures["inconclusive"] = inconclusive(ref, res, tol.band, c.judged, tol.t_abs, tol.normal_deg, tol.traced)
    bad = _failures(c)
    images = {
        "mask_inside_band": c.inside,
        "mask_outside_band": c.outside,
        "id_mismatch": c.id_out,
        "ties": c.ties,  # id mismatches at depth ties: not judged
        "depth_rel_err": c.rel,
        "normal_deg": c.ang,
        "band": tol.band,
        "not_judged": c.same & tol.band,  # t and normals compared but not judged: the silhouette band
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


@dataclass
class _Compared:
    """The per-pixel comparisons ``check_geometry`` reports, (H, W) each: ``said`` counts the non-finite
    values per buffer."""

    mism: np.ndarray
    inside: np.ndarray
    outside: np.ndarray
    nonfinite: np.ndarray
    said: dict[str, int]
    nf_out: np.ndarray
    ties: np.ndarray
    id_out: np.ndarray
    same: np.ndarray
    rel: np.ndarray
    ang: np.ndarray
    judged: np.ndarray
    t_viol: np.ndarray
    n_viol: np.ndarray
    n_len: np.ndarray
    len_viol: np.ndarray


def _compare(ref: RenderResult, res: RenderResult, tol: Any, margins: dict[str, np.ndarray]) -> _Compared:
    """The oracle's geometry against the reference's, pixel by pixel, under the tolerance ``tol``."""
    mism = ref.hit != res.hit
    if tol.traced is not None:  # a pixel the oracle did not trace holds no answer: not a mismatch
        mism &= tol.traced
    inside, outside = mism & tol.band, mism & ~tol.band
    both = ref.hit & res.hit
    # NaN or infinity where the reference is finite: inside the band the oracle's own precision cannot
    # decide the pixel (a float32 normal of a ball 1e8 away, fuzz far_31_0), outside it is a defect.
    nonfinite = res.hit & ~np.isfinite(res.t)
    said = {"t": int(nonfinite.sum())}
    for name in ("position", "normal", "color"):
        a, b = getattr(res, name), getattr(ref, name)
        if a is not None and b is not None:
            bad = bitmap.channel_any(~np.isfinite(a) & np.isfinite(b))
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
    n_len = np.abs(row_norm(res.normal) - 1.0)
    len_viol = judged & (n_len > np.maximum(1e-3, np.radians(tol.normal_deg)))
    return _Compared(
        mism=mism,
        inside=inside,
        outside=outside,
        nonfinite=nonfinite,
        said=said,
        nf_out=nf_out,
        ties=ties,
        id_out=id_out,
        same=same,
        rel=rel,
        ang=ang,
        judged=judged,
        t_viol=t_viol,
        n_viol=n_viol,
        n_len=n_len,
        len_viol=len_viol,
    )


def _figures(ref: RenderResult, tol: Any, c: _Compared) -> dict[str, Any]:
    """The check's figures: counts of each kind of mismatch, the largest errors, the tolerance's own."""
    return {
        "pixels": int(ref.hit.size),
        "band_pixels": int(tol.band.sum()),
        "mask_mismatch": int(c.mism.sum()),
        "mask_mismatch_outside_band": int(c.outside.sum()),
        "id_mismatch": int(c.id_out.sum()),
        "ties": int(c.ties.sum()),
        "nonfinite": {k: v for k, v in c.said.items() if v},
        "nonfinite_outside_band": int(c.nf_out.sum()),
        "depth_rel_err_max": float(c.rel[c.same].max()) if c.same.any() else 0.0,
        "depth_rel_err_p99": float(np.percentile(c.rel[c.same], 99)) if c.same.any() else 0.0,
        "depth_violations": int(c.t_viol.sum()),
        "normal_deg_max": float(c.ang[c.same].max()) if c.same.any() else 0.0,
        "normal_violations": int(c.n_viol.sum()),
        "normal_length_err_max": float(c.n_len[c.judged].max()) if c.judged.any() else 0.0,
        "normal_length_violations": int(c.len_viol.sum()),
        "tolerance": tol.summary,
    }


def _failures(c: _Compared) -> list[str]:
    """One line per kind of defect found outside the band (none: the geometry passes)."""
    bad = []
    if c.nf_out.any():
        where = ", ".join(f"{k}: {v}" for k, v in c.said.items() if v)
        n = int(c.nf_out.sum())
        bad.append(f"NaN or infinity where the reference is finite at {n} pixel(s) outside the band ({where})")
    if c.outside.any():
        bad.append(f"{int(c.outside.sum())} hit-mask mismatch(es) outside the silhouette band")
    if c.id_out.any():
        bad.append(f"{int(c.id_out.sum())} shape id mismatch(es)")
    if c.t_viol.any():
        bad.append(f"{int(c.t_viol.sum())} t error(s) above tolerance")
    if c.n_viol.any():
        bad.append(f"{int(c.n_viol.sum())} normal error(s) above tolerance")
    if c.len_viol.any():
        bad.append(f"{int(c.len_viol.sum())} normal(s) not unit length beyond tolerance (|n| - 1 up to "
                   f"{float(c.n_len[c.len_viol].max()):.3g})")  # fmt: skip
    return bad


def inconclusive(
    ref: RenderResult,
    res: RenderResult,
    band_px: np.ndarray,
    judged: np.ndarray,
    t_abs: np.ndarray,
    normal_deg: np.ndarray,
    traced: np.ndarray | None = None,
) -> dict[str, Any]:
    """Whether the geometry check could have failed on most of what it judges (THRESHOLDS
    "inconclusive_fraction"): the fractions measured, and the reasons it could not (empty: conclusive).
    ``traced``: the pixels the backend rendered (None: all); the fractions are of those."""
    limit = THRESHOLDS["inconclusive_fraction"].value
    hits = ref.hit | res.hit
    if traced is not None:
        hits = hits & traced
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
