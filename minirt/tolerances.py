"""Every tolerance and threshold the harness applies, in one place, each with its derivation.

Geometry tolerances come from the oracle's own precision (recorded in ``result.meta["precision"]``
by the oracle that knows its encoding, intersector and tessellation); this module translates each
oracle's vocabulary into one shape, :class:`GeometryTolerance`. Shading and statistical thresholds
are the harness's own and are listed in :data:`THRESHOLDS`. The report prints both.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from minirt.result import RenderResult

U32 = 2.0**-24  # float32 unit round-off
U64 = 2.0**-53


@dataclass(frozen=True)
class Threshold:
    value: float
    why: str


THRESHOLDS: dict[str, Threshold] = {
    "mask_outside_band": Threshold(
        0,
        "A hit/miss disagreement on a ray whose every decision is farther than the oracle's precision from "
        "flipping is a defect.",
    ),
    "id_mismatch": Threshold(
        0, "Outside the band and away from depth ties the closest shape is decided with margin: ids must agree."
    ),
    "color8_levels": Threshold(
        1,
        "8-bit levels: both sides round floor(c*255+0.5); a value within float error of a .5 tie may round either "
        "way, so 1 level is rounding, 2 or more is a shading difference.",
    ),
    "color8_off_by_one_fraction": Threshold(
        0.002,
        "Fraction of compared pixels allowed at exactly 1 level: ties are rare (a value must lie within ~1e-6 of a "
        "tie, ~1e-4 of values for POV-Ray's half-precision internals); measured 3/65536 on the bundled scenes.",
    ),
    "color8_tie_rel": Threshold(
        2.0**-20,
        "A channel whose reference value c has c*255 + 0.5 within 2^-20 c*255 of an integer sits on a rounding tie: "
        "a 1-level difference there is not counted against color8_off_by_one_fraction. 2^-20 bounds 16 "
        "single-precision roundings (POV-Ray's colour arithmetic, its average of up to 16 samples); flat regions "
        "can sit exactly on a tie (a 0.1 channel is 25.5 levels).",
    ),
    "diffuse_rel": Threshold(
        2e-4,
        "Mitsuba diffuse after its factors (pi r^2 / I) are divided out, relative to lc*dc: float32 shading "
        "(~16 u32 = 1e-6) plus the float32 normal's angle error (<= 0.01 deg = 1.7e-4 rad) moving cos(theta).",
    ),
    "z_significance": Threshold(
        0.01,
        "Per-pixel significance before correction, as in Mitsuba's own render tests (there a Z-test; here Welch's t "
        "with Welch-Satterthwaite degrees of freedom, since the variances are estimated from the samples: the two "
        "agree for many samples, and at 4 samples the normal law fails correct renders).",
    ),
    "z_pass_fraction": Threshold(
        0.9975, "Fraction of pixel-channels that must pass the Sidak-corrected Z-test (Mitsuba's test_renders.py)."
    ),
    "z_var_floor": Threshold(
        1e-8,
        "Variance floor per pixel-channel: a constant pixel has zero sample variance, and the float32 renderer's "
        "rounding (~1e-4 of 1 at worst) must not count as a significant difference.",
    ),
    "shape_mean_sigma": Threshold(
        4.0, "Per-shape mean shading: the two means must agree within 4 combined standard errors."
    ),
    "inconclusive_fraction": Threshold(
        0.5,
        "A geometry check speaks for a scene only where it could fail. It is inconclusive (WARN, not PASS) when "
        "more than this fraction of the hit pixels (either side) lie in the band, where hit/miss and ids are not "
        "judged; or of the judged pixels, more than this fraction have a t tolerance at least the view's depth "
        "range (max - min t over the reference's hits: any visible depth would pass; an infinite tolerance "
        "included) or a normal tolerance of 90 degrees or more (any normal facing the same half-space would "
        "pass). One half: a check that judges fewer than half of what it is about is mostly not a check.",
    ),
    "delta_e_p95": Threshold(
        1.0, "CIEDE2000 95th percentile on the 8-bit images: 1.0 is the just-noticeable difference (WARN above)."
    ),
}


@dataclass
class GeometryTolerance:
    """Per-pixel tolerances for one oracle's geometry buffers against the float64 reference."""

    band: np.ndarray  # bool (H, W): decisions within the oracle's precision of flipping
    t_abs: np.ndarray  # float (H, W): allowed |t_oracle - t_ref|
    normal_deg: np.ndarray  # float (H, W): allowed angle between normals
    why: dict[str, str] = field(default_factory=dict)
    summary: dict[str, float | str] = field(default_factory=dict)  # figures; "<key>_reason" beside a non-finite one
    # bool (H, W) or None: where two shapes' nearest hits are a depth tie at the oracle's per-shape precision
    # (an id mismatch there is not a defect); None: the harness's scene-wide rule, id_tie < 4 band_eps
    ties: np.ndarray | None = None


def farthest_hit(p: dict) -> float:
    """The farthest t along the harness's rays at which an oracle that records ``max_distance`` (POV-Ray's
    MAX_DISTANCE from its own ray's origin, ``max_distance_lift`` before the harness's) still reports a
    hit, less 1e-6 of it for the rounding of t; inf for an oracle without one."""
    return p.get("max_distance", math.inf) * (1 - 1e-6) - p.get("max_distance_lift", 0.0)


def _per_shape_band(scaled: Callable[..., dict[str, np.ndarray]], p: dict, h: int, w: int):
    """(band, ties), both bool (H, W), from the per-shape scales an oracle records (``band_scale`` and the
    optional ``band_origin_scale``, ``band_inside_scale``, ``band_tie_scale``): a ray is in the band where
    a margin divided by its shape's scale is below 1; an id mismatch is a depth tie where the id-tie margin
    divided by the pair's scale is below 4 -- the scene-wide rule id_tie < 4 band_eps with each pair's own
    scale for band_eps (one scene-wide value excused every id mismatch beside a far ball: defect campaign
    f32_2027_22, ids-swapped passed POV-Ray on judged pixels)."""
    m = scaled(
        scale=p["band_scale"],
        origin_scale=p.get("band_origin_scale"),
        inside_scale=p.get("band_inside_scale"),
        tie_scale=p.get("band_tie_scale"),
    )
    return m["margin"].reshape(h, w) < 1.0, m["id_tie"].reshape(h, w) < 4.0


def geometry_tolerance(
    result: RenderResult,
    ref: RenderResult,
    margins: dict[str, np.ndarray],
    start: Callable[..., np.ndarray] | None = None,
    scaled: Callable[..., dict[str, np.ndarray]] | None = None,
) -> GeometryTolerance:
    """Translate an oracle's recorded precision into per-pixel tolerances (see each oracle's docstring).

    ``start(t_min=, plane_err=, ball_err=)``: minirt.band.start_band on the checked rays (flat, per ray),
    the rays whose "does this candidate count" decision lies within the oracle's position error of its
    minimum distance; without it no such band is applied. ``scaled(scale=, origin_scale=, inside_scale=)``:
    minirt.band.margins on the same rays with per-shape scales, for an oracle that records them (POV-Ray's
    band_scale); without it the scene-wide threshold is used."""
    h, w = ref.height, ref.width

    def start_band(**kw) -> np.ndarray:
        return np.zeros((h, w), dtype=bool) if start is None else start(**kw).reshape(h, w)

    p = result.meta.get("precision") or {}
    m = {k: v.reshape(h, w) for k, v in margins.items()}
    t_ref = np.where(ref.hit, ref.t, 0.0)
    name = result.backend
    ties = None
    if name == "mitsuba":
        eps = p["band_k"] * p["band_eps"]
        plane_abs = max([pl.get("abs_error", 0.0) for pl in result.meta.get("planes", {}).values()] or [0.0])
        # A shadow or hit decision moved by the rectangle's absolute error: relative to the smallest radius.
        band = m["margin"] < eps
        # Rays starting on a plane (t ~ 0): Mitsuba 3 has no minimum distance (Ray3f carries maxt only), and
        # whether its rectangle lies in front of the origin is decided in float32: the error of the origin's
        # signed distance from the rectangle (its normal_error, older documents: its abs_error), plus the
        # origin rounded to float32 and taken to the rectangle's local frame (a few roundings of terms <= |o|:
        # 4 u32 |o|). Balls: the relative origin margin above (band_eps) covers it.
        plane_normal = max(
            [pl.get("normal_error", pl.get("abs_error", 0.0)) for pl in result.meta.get("planes", {}).values()] or [0.0]
        )
        start_err = plane_normal + 4 * U32 * m["origin_norm"]
        starts = start_band(t_min=0.0, plane_err=start_err.reshape(-1))
        if scaled is not None and p.get("band_scale"):  # each shape's own band (oracles.mitsuba.band_scales)
            band, ties = _per_shape_band(scaled, p, h, w)
        band = band | starts
        # A plane's t = n·(Q - o)/(n·d): the rectangle's absolute error and the float32 rounding of the ray's
        # direction (dir_err) move t by (plane_abs + t dir_err)/|n·d| -- large where the ray grazes the plane.
        inv_nd = 1.0 / m["hit_nd"]
        dir_err = p.get("dir_err", 0.0)
        t_abs = p["t_rel"] * t_ref + plane_abs + (plane_abs + dir_err * t_ref) * inv_nd
        # near a ball's silhouette the float32 discriminant is ill-conditioned: the oracle's per-pixel bound
        t_abs = t_abs + result.aux.get("t_silhouette_bound", 0.0)
        nd = np.full((h, w), p["normal_deg"])
        why = {
            "band": f"margin < each shape's own band (at most band_k*band_eps = {eps:.3g}; a ball's discriminant "
            "error against r^2 - h^2, exact in the margin): {p.get('why', '')}; or a ray starting within "
            f"normal_error + 4 u32 |o| = {plane_normal:.3g} + 4 u32 |o| of a plane (float32 decides t > 0 there)",
            "t": f"t_rel*t + plane_abs + (plane_abs + dir_err*t)/|n·d| = {p['t_rel']:.3g}*t + {plane_abs:.3g} + "
            f"({plane_abs:.3g} + {dir_err:.3g}*t)/|n·d| (float32 roots; rectangles interpolate their corners; "
            "a plane's t is conditioned by 1/|n·d|, n·d of the hit plane, inf for balls) + per pixel "
            "4 u32 |f|^2/(r sqrt(2m)) near a ball's silhouette (aux t_silhouette_bound)",
            "normal": f"{p['normal_deg']} deg (float32 normals)",
        }
        summary = {
            "band_eps": eps,
            "t_rel": p["t_rel"],
            "plane_abs": plane_abs,
            "plane_normal_error": plane_normal,
            "normal_deg": p["normal_deg"],
            "start_band_pixels": int(starts.sum()),
        }
    elif name == "povray":
        eps = p["band_threshold"]
        # its minimum distance along the harness's rays and its position error there (oracles.povray.start_decision)
        t_min, start_err = p.get("min_distance", 0.0), p.get("start_err", 0.0)
        starts = start_band(t_min=t_min, plane_err=start_err, ball_err=start_err)
        if scaled is not None and p.get("band_scale"):  # each shape's own threshold (oracles.povray.band_scales)
            band, ties = _per_shape_band(scaled, p, h, w)
            band = band | starts
        else:
            band = (m["margin"] < eps) | starts
        # POV-Ray drops hits beyond MAX_DISTANCE 1e7 from its ray's origin (a pinhole ray's origin is the
        # camera, up to max_distance_lift before the harness's): where the nearest candidate lies that far,
        # POV-Ray misses what the reference hits -- a decision it cannot make, like its minimum distance
        # (fuzz far_2026_6: rays starting just inside a ground of radius 4.5e7 meet its far side 1.04e7 away).
        if "max_distance" in p:
            band |= np.isfinite(m["near"]) & (m["near"] >= farthest_hit(p))
        # plus the conditioning of the hit: a ray whose origin and direction err by dir_err (R + t) -- the mesh
        # camera's single-precision rays, R its origins' reach -- meets a surface dir_err (R + t)/cos away, cos = |n·d|
        # at the hit, ball or plane (fuzz start_2026_83: a ball met at an angle, dt 1.65e-6 > t_abs 1.54e-6)
        # and POV-Ray's own sphere root, 12 2^-53 |f|^2/(r cos) along the ray (oracles.povray.root_errors; fuzz
        # f32_2026_22: a ball 2.4e4 away, its hit 8.6e-7 off along the ray near its silhouette), which turns
        # the normal (P - C)/r by as much over r
        root = np.zeros((h, w))
        root_n = np.zeros((h, w))
        if p.get("root_err"):
            # ids the scene does not have (a defective reference's, fuzz --defects ids-swapped on a one-ball
            # scene) get no root term: those pixels are id mismatches, never compared in t or normal
            n_shapes = len(p["root_err"])
            ids = np.where(ref.hit & (ref.shape_id < n_shapes), ref.shape_id, -1)
            k = np.maximum(ids, 0)
            per_t = np.asarray(p["root_err"], dtype=np.float64)[k]
            per_n = np.asarray(p.get("root_normal_err", np.zeros(len(p["root_err"]))), dtype=np.float64)[k]
            with np.errstate(divide="ignore", invalid="ignore"):
                root = np.where(ids >= 0, per_t / m["hit_cos"], 0.0)
                root_n = np.where(ids >= 0, per_n / m["hit_cos"], 0.0)
        with np.errstate(divide="ignore"):
            t_abs = p["t_abs"] + p.get("dir_err", 0.0) * (p.get("ray_reach", 1.0) + t_ref) / m["hit_cos"] + root
        deg = math.degrees(math.asin(min(1.0, 2 * p["normal_abs"]))) + 1e-9
        nd = np.degrees(np.arcsin(np.minimum(1.0, 2 * (p["normal_abs"] + root_n)))) + 1e-9
        why = {
            "band": f"margin < each shape's own threshold (at most {eps:.3g}): single-precision bounding boxes "
            "and textbook sphere roots in POV-Ray, its mesh camera's single-precision rays; "
            f"or a candidate hit with t cos within {start_err:.3g} of [0, {t_min:.3g}] (POV-Ray drops hits within "
            "its minimum distance 1e-4 of a mesh-camera ray's origin; its rays are off by start_err there)",
            "t": f"|dt| <= {p['t_abs']:.3g} + {p.get('dir_err', 0.0):.3g}*(R + t)/|n·d| (n at the hit, R = ray_reach) "
            "+ 12 2^-53 |f|^2/(r |n·d|) (POV-Ray's textbook sphere root, |f| from its ray's origin to the centre): "
            f"{p.get('derivation', '')}",
            "normal": f"{deg:.3g} deg: normals from decoded positions, |dn| <= {p['normal_abs']:.3g}, plus per pixel "
            "POV-Ray's root error over r: 12 2^-53 |f|^2/(r^2 |n·d|)",
        }
        summary = {
            "band_eps": eps,
            "t_abs": p["t_abs"],
            "normal_deg": deg,
            "min_distance": t_min,
            "start_band_pixels": int(starts.sum()),
        }
    elif name == "embree":
        tb = result.aux.get("t_bound", np.full((h, w), p["t_abs"]))
        t_abs = tb + p["eps32_abs"]
        # A depth tie is relative to the ray's nearest candidate hit in the scene (margins "near"), not to
        # the reference's t: where the reference misses, t_ref is 0 and a ratio to it put every ray that
        # meets a ball in the band -- a reference that skipped a ball was never caught there (the defect
        # campaign, far_2027_34: 46 of its pixels).
        near = m["near"]
        with np.errstate(divide="ignore", invalid="ignore"):
            tie_rel = np.where(np.isfinite(near) & (near > 0), t_abs / np.maximum(near, 1e-300), np.inf)
        band = (
            (m["silhouette"] < p["band_abs"])
            | (m["origin"] < p["origin_band_abs"])
            | (m["grazing"] < p["grazing_abs"])
            | (m["tie"] < 2 * tie_rel)
        )
        # Rays starting on a plane (t ~ 0): Embree's minimum distance is 0 (trimesh casts t in (0, inf)); its
        # quads are float32 coordinates of the mesh's extent (origins included), 8 ulps: eps32_abs.
        starts = start_band(t_min=0.0, plane_err=p["eps32_abs"])
        band = band | starts
        nd = result.aux.get("normal_bound_deg", np.full((h, w), p["normal_deg"]))
        why = {
            "band": f"silhouette < {p['band_abs']:.3g} (tessellation gap + float32), grazing < {p['grazing_abs']:.3g} "
            f"(far plane cut), depth ties within the t bound, rays starting within {p['eps32_abs']:.3g} of a plane",
            "t": "per pixel: the tessellated shell's thickness along the ray (aux t_bound) "
            "+ float32 of the mesh extent",
            "normal": "per pixel: face-to-vertex normal angle + the shell's tilt (aux normal_bound_deg)",
        }
        summary = {
            "band_eps": p["band_abs"],
            "t_abs_max": float(np.max(t_abs)),
            "normal_deg_max": float(np.max(nd)),
            "start_band_pixels": int(starts.sum()),
        }
        for key in ("t_abs_max", "normal_deg_max"):  # the reason strict JSON writes beside the null (minirt.jsonout)
            if not math.isfinite(summary[key]):
                summary[key + "_reason"] = "infinite: the bound is unlimited on pixels the oracle misses"
    else:  # a backend that records only generic keys
        eps = p.get("band_eps", 1e-6)
        band = m["margin"] < eps
        t_abs = p.get("t_rel", 1e-6) * t_ref + p.get("t_abs", 0.0)
        nd = np.full((h, w), p.get("normal_deg", 1e-3))
        why = {"band": f"margin < {eps:.3g}", "t": "t_rel*t + t_abs from the backend", "normal": "normal_deg"}
        summary = {"band_eps": eps}
    return GeometryTolerance(band=band, t_abs=t_abs, normal_deg=nd, why=why, summary=summary, ties=ties)
