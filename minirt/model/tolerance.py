"""What a backend tells the harness of its precision: per-pixel geometry tolerances (``GeometryTolerance``),
computed by the backend's ``geometry_tolerance`` from what the harness measured of the rays (``Margins``).

Value types of the harness's geometry check (minirt.harness.tolerances, minirt.harness.compare), here in
the model because every backend -- the reference and the oracles, below the harness -- builds them.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from minirt.model.result import RenderResult

U32 = 2.0**-24  # float32 unit round-off
U64 = 2.0**-53


@dataclass
class GeometryTolerance:
    """Per-pixel tolerances for one backend's geometry buffers against the float64 reference."""

    band: np.ndarray  # bool (H, W): decisions within the backend's precision of flipping
    t_abs: np.ndarray  # float (H, W): allowed |t_backend - t_ref|
    normal_deg: np.ndarray  # float (H, W): allowed angle between normals
    why: dict[str, str] = field(default_factory=dict)
    summary: dict[str, float | str] = field(default_factory=dict)  # figures; "<key>_reason" beside a non-finite one
    # bool (H, W) or None: where two shapes' nearest hits are a depth tie at the backend's per-shape precision
    # (an id mismatch there is not a defect); None: the harness's scene-wide rule, id_tie < 4 band_eps
    ties: np.ndarray | None = None
    # bool (H, W) or None: the pixels the backend rendered (None: every pixel). The others are in ``band`` (not
    # judged) and out of the fractions that make a check inconclusive: a sampled render is judged where it is.
    traced: np.ndarray | None = None


@dataclass(frozen=True)
class Margins:
    """What the harness measured of the checked rays, for a backend to turn into its tolerance.

    ``margins``: minirt.reference.band.margins of the reference's primary rays, flat per ray (margin,
    origin, silhouette, grazing, tie, near, id_tie, hit_nd, hit_cos, origin_norm); ``margin``, ``origin`` and
    ``silhouette`` exact below ``bound`` and inf elsewhere (the rest exact): compare them with a threshold
    through ``below``, which widens the bound when the threshold is larger (``widen(eps)``: the margins
    exact below eps). ``start(t_min=, plane_err=, ball_err=)``: minirt.reference.band.start_band on the same
    rays, the rays whose "does this candidate count" decision lies within the backend's position error of
    its minimum distance (None: no such band). ``scaled(scale=, origin_scale=, inside_scale=, tie_scale=)``:
    the margins with per-shape scales, exact below 1 (what ``per_shape_band`` compares), for a backend that
    records them (None: the scene-wide threshold)."""

    margins: dict[str, np.ndarray]
    start: Callable[..., np.ndarray] | None = None
    scaled: Callable[..., dict[str, np.ndarray]] | None = None
    bound: float = math.inf
    widen: Callable[[float], dict[str, np.ndarray]] | None = None

    def below(self, key: str, eps: float, h: int, w: int) -> np.ndarray:
        """(H, W) bool: ``margins[key] < eps``, exact whatever eps (``margin``, ``origin``, ``silhouette``
        are known exactly only below ``bound``: a larger eps asks ``widen`` for them)."""
        m = self.margins if eps <= self.bound or self.widen is None else self.widen(eps)
        return m[key].reshape(h, w) < eps

    def image(self, h: int, w: int) -> dict[str, np.ndarray]:
        return {k: v.reshape(h, w) for k, v in self.margins.items()}

    def start_band(self, h: int, w: int, **kw) -> np.ndarray:
        return np.zeros((h, w), dtype=bool) if self.start is None else self.start(**kw).reshape(h, w)

    def per_shape_band(self, p: dict, h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
        """(band, ties), both bool (H, W), from the per-shape scales a backend records (``band_scale`` and
        the optional ``band_origin_scale``, ``band_inside_scale``, ``band_tie_scale``): a ray is in the band
        where a margin divided by its shape's scale is below 1; an id mismatch is a depth tie where the
        id-tie margin divided by the pair's scale is below 4 -- the scene-wide rule id_tie < 4 band_eps with
        each pair's own scale for band_eps (one scene-wide value excused every id mismatch beside a far
        ball: defect campaign f32_2027_22, ids-swapped passed POV-Ray on judged pixels)."""
        m = self.scaled(
            scale=p["band_scale"],
            origin_scale=p.get("band_origin_scale"),
            inside_scale=p.get("band_inside_scale"),
            tie_scale=p.get("band_tie_scale"),
        )
        return m["margin"].reshape(h, w) < 1.0, m["id_tie"].reshape(h, w) < 4.0


def farthest_hit(p: dict) -> float:
    """The farthest t along the harness's rays at which a backend that records ``max_distance`` (POV-Ray's
    MAX_DISTANCE from its own ray's origin, ``max_distance_lift`` before the harness's) still reports a
    hit, less 1e-6 of it for the rounding of t; inf for a backend without one."""
    return p.get("max_distance", math.inf) * (1 - 1e-6) - p.get("max_distance_lift", 0.0)


def tolerance_inputs(
    result: RenderResult, ref: RenderResult, measured: Margins
) -> tuple[int, int, dict[str, Any], dict[str, np.ndarray], np.ndarray]:
    """What every ``geometry_tolerance`` starts from: the image's height and width, the precision the backend
    recorded (``result.meta["precision"]``, {} if none), the measured margins as (H, W) images, and the
    reference's t (0 where it misses)."""
    h, w = ref.height, ref.width
    return h, w, result.meta.get("precision") or {}, measured.image(h, w), np.where(ref.hit, ref.t, 0.0)


def generic_tolerance(result: RenderResult, ref: RenderResult, measured: Margins) -> GeometryTolerance:
    """The tolerance of a backend that records only generic keys in ``meta["precision"]`` (``band_eps``,
    ``t_rel``, ``t_abs``, ``normal_deg``), or a result no registered backend made (a test's)."""
    h, w, p, _, t_ref = tolerance_inputs(result, ref, measured)
    eps = p.get("band_eps", 1e-6)
    band = measured.below("margin", eps, h, w)
    t_abs = p.get("t_rel", 1e-6) * t_ref + p.get("t_abs", 0.0)
    nd = np.full((h, w), p.get("normal_deg", 1e-3))
    why = {"band": f"margin < {eps:.3g}", "t": "t_rel*t + t_abs from the backend", "normal": "normal_deg"}
    return GeometryTolerance(band=band, t_abs=t_abs, normal_deg=nd, why=why, summary={"band_eps": eps})
