"""The roots of rays against a ball, in NumPy, float64: one helper for the reference's bands
(minirt.reference.band) and the oracles' error bounds (oracles/embree.py), which must agree on them.

A ray o + t d (d a unit vector) meets the ball |P - C| = r where t^2 + 2 b t + c = 0, with f = o - C,
b = f·d and c = |f|^2 - r^2. The textbook discriminant b^2 - c cancels catastrophically for a ball far
from the ray's origin (its error is ~2^-53 |f|^2, against r^2 - h^2 near the silhouette), so the stable
forms are used throughout:

- the discriminant as (r - h)(r + h), h = |f - b d| the ray's distance from the centre (its error is a
  few ulps of r^2, whatever |f|);
- c as (|f| - r)(|f| + r), for the same reason;
- the root of larger magnitude q = -(b + sign(b) sqrt(disc)) (no cancellation: b and sign(b) sqrt(disc)
  have one sign), and the other from Vieta's formula, c / q (0 where q = 0: a ray from the centre
  of a ball of radius 0).

Each is a handful of float64 roundings: a root errs by a few ulps of max(|t|, |f|). The callers
compute exactly these operations in exactly this order (their results are compared bit for bit with
the recorded ones); what they do with a miss differs, so ``on_miss`` says what sqrt(disc) is there.

Two other root computations keep the textbook form b^2 - c on purpose, so they are not this helper:
POV-Ray's encoding ranges (oracles/povray/buffers.py: the hits POV-Ray's own textbook arithmetic
finds) and Mitsuba's viewing distance (oracles/mitsuba/exporter.py: a median for display only).
"""

from __future__ import annotations

from typing import Literal, NamedTuple

import numpy as np


def row_norm(v: np.ndarray) -> np.ndarray:
    """|v| of each row of an (..., 3) array: sqrt((x^2 + y^2) + z^2), the same bits as np.linalg.norm(v,
    axis=-1) (which sums the three squares in this order; NaN and infinities alike, tested) in a fifth of
    its time: its reduction over a 3-long axis costs more than the arithmetic."""
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    return np.sqrt((x * x + y * y) + z * z)


class BallRoots(NamedTuple):
    """Per ray (arrays of shape (N,)): the quantities of the stable root forms (module docstring)."""

    b: np.ndarray  # f·d
    h: np.ndarray  # |f - b d|: the ray's distance from the centre
    lf: np.ndarray  # |f|: the ray origin's distance from the centre
    disc: np.ndarray  # (r - h)(r + h) = r^2 - h^2, negative on a miss
    sq: np.ndarray  # sqrt(disc): 0 (``on_miss="zero"``) or nan (``"nan"``) on a miss
    r0: np.ndarray  # c / q, the root of smaller magnitude (0 where q = 0)
    q: np.ndarray  # -(b + sign(b) sq), the root of larger magnitude


def ball_roots(
    center, radius: float, o: np.ndarray, d: np.ndarray, on_miss: Literal["zero", "nan"] = "zero"
) -> BallRoots:
    """Both roots, unsorted, of rays o + t d ((N, 3) each, d unit) against the ball (center, radius).

    ``on_miss`` "zero": sqrt(max(disc, 0)), so a miss yields the tangent roots and the caller masks it
    with ``disc >= 0``; "nan": sqrt of nan, so a miss yields nan roots."""
    f = o - np.asarray(center)
    b = np.einsum("ij,ij->i", f, d)
    h = row_norm(f - b[:, None] * d)
    disc = (radius - h) * (radius + h)
    sq = np.sqrt(np.maximum(disc, 0.0) if on_miss == "zero" else np.where(disc >= 0, disc, np.nan))
    lf = row_norm(f)
    with np.errstate(divide="ignore", invalid="ignore"):
        q = -(b + np.copysign(sq, b))
        c = (lf - radius) * (lf + radius)
        r0 = np.where(q != 0, c / q, 0.0)
    return BallRoots(b=b, h=h, lf=lf, disc=disc, sq=sq, r0=r0, q=q)
