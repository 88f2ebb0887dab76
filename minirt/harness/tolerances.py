"""Every threshold the harness applies, in one place, each with its derivation; and the way to each
backend's geometry tolerance.

Geometry tolerances come from the oracle's own precision (recorded in ``result.meta["precision"]``
by the oracle that knows its encoding, intersector and tessellation); each oracle translates its own
vocabulary into one shape, minirt.model.backend's ``GeometryTolerance``, in its ``geometry_tolerance``
beside its derivations. Shading and statistical thresholds are the harness's own and are listed in
:data:`THRESHOLDS`. The report prints both.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from minirt.harness import backends
from minirt.model.result import RenderResult
from minirt.model.tolerance import GeometryTolerance, Margins, generic_tolerance


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


def geometry_tolerance(
    result: RenderResult,
    ref: RenderResult,
    margins: dict[str, np.ndarray],
    start: Callable[..., np.ndarray] | None = None,
    scaled: Callable[..., dict[str, np.ndarray]] | None = None,
    bound: float = math.inf,
    widen: Callable[[float], dict[str, np.ndarray]] | None = None,
) -> GeometryTolerance:
    """The backend's own translation of its recorded precision into per-pixel tolerances (each oracle's
    ``geometry_tolerance``, beside its derivations; minirt.model.backend.Margins says what ``margins``,
    ``start``, ``scaled``, ``bound`` and ``widen`` are). A result no registered backend made gets the generic
    translation."""
    measured = Margins(margins, start, scaled, bound, widen)
    b = backends.find(result.backend)
    return b.geometry_tolerance(result, ref, measured) if b else generic_tolerance(result, ref, measured)
