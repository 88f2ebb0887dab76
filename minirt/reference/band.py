"""How close each primary ray is to a decision that rounding can flip: the silhouette band.

A renderer working with relative precision e may legitimately disagree with the reference on a ray
whose hit/miss or closest-shape decision is within e of changing. Per ray (float64, from the scene's
exact description) this module gives the relative margin of every such decision:

- ball silhouettes: the ray passes at distance h from the centre; the hit flips at h = r, so the
  margin is |h - r| / r (h from the stable form |f - (f·d) d|);
- grazing planes: the hit point runs off to infinity as n·d -> 0; margin |n·d|;
- two surfaces at nearly the same depth (intersection curves, occlusion edges in depth, ties):
  margin |t1 - t2| / max(t1, t2) over the two nearest candidate hits;
- a ray starting near a ball's surface (an image-plane origin just inside or outside a ball that
  crosses z = 0): whether it starts inside flips at |o - C| = r; margin | |o - C| - r | / r.

``margin`` is the minimum over these; ``near`` (absolute) is the distance to the nearest candidate hit,
for renderers that ignore hits closer than a fixed depth; ``hit_nd`` is |n·d| of the plane holding
that hit (inf for a ball), the conditioning of a plane's t. A disagreement on a ray with margin < k·e (k from the
oracle's error analysis, chosen by the harness) is inside the band; elsewhere it is a real defect.

One decision is absolute, not relative: whether a candidate hit counts at all, ``t > t_min`` (the
reference: t > 0; POV-Ray: t > 1e-4 from its ray's origin). ``start_band`` gives the rays where some
candidate lies within an oracle's own position error of that minimum distance -- a ray that starts on
a plane through the image plane (exact t = 0, a miss under t > 0) hit at t ~ 1e-7 by a float32
intersector, or a hit POV-Ray drops as too near -- a decision the oracle cannot make.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from minirt.model import camera
from minirt.model.roots import ball_roots
from minirt.model.rules import Rules
from minirt.model.scene import Ball, Scene


class _Candidate:
    """Per ray: a candidate hit's t, the |n·d| of its plane (inf for a ball), its cosine against the surface
    and its shape's index."""

    def __init__(self, n: int):
        self.t, self.nd = np.full(n, np.inf), np.full(n, np.inf)
        self.cos, self.owner = np.ones(n), np.zeros(n, dtype=np.int64)

    def take(self, where: np.ndarray, src: _Candidate | tuple) -> None:
        t, nd, cos, owner = (src.t, src.nd, src.cos, src.owner) if isinstance(src, _Candidate) else src
        self.t, self.nd = np.where(where, t, self.t), np.where(where, nd, self.nd)
        self.cos, self.owner = np.where(where, cos, self.cos), np.where(where, owner, self.owner)


class _Nearest:
    """Per ray, of the candidate hits pushed one after the other: the nearest (``first``), the next nearest
    (``second``) and the nearest of another shape than the nearest's (``other``) -- what sorting every
    candidate stably by t gives at positions 0, 1 and the first of another shape (tests/reference/test_band_scale.py
    sorts and compares, ties included: an earlier candidate wins a tie), in O(rays) memory where the sort
    held rays x candidates (a 1,024-ball check at 128x128: 3 GB, and 34 s of its 59). Only finite t is
    ever read of ``second`` and ``other``; where there is none they hold t = inf."""

    def __init__(self, n: int):
        self.first, self.second, self.other = _Candidate(n), _Candidate(n), _Candidate(n)

    def push(self, t: np.ndarray, nd, cos, owner: int) -> None:
        x = (t, nd, cos, owner)
        a = self.first
        before = t < a.t  # strictly: the earlier candidate stays first on a tie
        another = a.owner != owner
        # second: the old first when x goes before it, else x if it goes before the second
        self.second.take(~before & (t < self.second.t), x)
        self.second.take(before, a)
        # other: when x goes first, the old first if its shape is another (else other stays: its shape
        # still differs); when x does not, x if its shape is another than the first's and it is nearer
        self.other.take(~before & another & (t < self.other.t), x)
        self.other.take(before & another, a)
        a.take(before, x)


def margins(
    scene: Scene,
    origins: np.ndarray,
    directions: np.ndarray,
    scale: Sequence[float] | None = None,
    origin_scale: Sequence[float] | None = None,
    inside_scale: Sequence[float] | None = None,
    tie_scale: Sequence[float] | None = None,
) -> dict[str, np.ndarray]:
    """Per-ray margins (N,) for silhouettes, grazing planes and depth ties, and their minimum.

    ``scale`` (one positive number per shape): an oracle's precision that differs from shape to shape
    (a ball 1e6 away is held far less exactly than the ground under the camera); every margin is then
    divided by the scale of the shape it is about -- a depth tie by the larger of its two shapes' -- so a
    ray is within that precision of flipping where the scaled margin is below 1, whichever shape it
    meets. One scene-wide threshold would be the worst shape's, and would put every ray in the band.
    ``origin_scale`` (default: ``scale``) does the same for the origin margin: whether a ray starts inside
    a ball is decided at the ray's origin, where an oracle's error need not be what it is along the ray.
    ``inside_scale`` (default: ``scale``) divides the silhouette margin of rays that meet the ball (h < r):
    an error that can only lose a hit (POV-Ray's bounding boxes) bands the disc, not the space around it.
    ``tie_scale`` (default: ``scale``) divides the depth ties: an oracle whose hit/miss decision and whose
    t err differently (Mitsuba's float32 discriminant: hit/miss flips where its error reaches r^2 - h^2,
    a quantity quadratic in the margin far from the silhouette, t moves linearly) scales them apart."""
    o = np.asarray(origins, dtype=np.float64)
    d = np.asarray(directions, dtype=np.float64)
    n = o.shape[0]
    sil = np.full(n, np.inf)
    origin = np.full(n, np.inf)
    graze = np.full(n, np.inf)
    nearest = _Nearest(n)  # the candidate hits (each root of a ball, each plane's), two nearest kept
    sc = np.ones(len(scene.shapes)) if scale is None else np.asarray(scale, dtype=np.float64)
    so = sc if origin_scale is None else np.asarray(origin_scale, dtype=np.float64)
    si = sc if inside_scale is None else np.asarray(inside_scale, dtype=np.float64)
    st = sc if tie_scale is None else np.asarray(tie_scale, dtype=np.float64)
    for k, s in enumerate(scene.shapes):
        if isinstance(s, Ball):
            br = ball_roots(s.center, s.radius, o, d)  # stable forms (minirt.model.roots)
            h, disc, sq = br.h, br.disc, br.sq
            sil = np.minimum(sil, np.abs(h - s.radius) / s.radius / np.where(h < s.radius, si[k], sc[k]))
            origin = np.minimum(origin, np.abs(br.lf - s.radius) / s.radius / so[k])
            # Both roots: the near one decides hit/miss, but either can be the closest (from inside).
            for r in (np.minimum(br.r0, br.q), np.maximum(br.r0, br.q)):
                # |n·d| of a ball's hit is inf (not a plane); its cosine against the surface sqrt(disc) / r
                nearest.push(np.where((disc >= 0) & (r > 0), r, np.inf), np.inf, sq / s.radius, k)
        else:
            nn = np.asarray(s.normal)
            nd = d @ nn
            graze = np.minimum(graze, np.abs(nd) / sc[k])
            with np.errstate(divide="ignore", invalid="ignore"):
                t = ((np.asarray(s.point) - o) @ nn) / nd
            nearest.push(np.where(np.isfinite(t) & (t > 0), t, np.inf), np.abs(nd), np.abs(nd), k)
    # The two nearest candidates, whichever shapes (which root is nearest decides t and the normal), give
    # the tie; the nearest and the nearest of another shape give id_tie -- a ball's two roots never change
    # the shape id (fuzz far_5_0: a far ball's roots 6e-6 apart excused a swapped id as a "tie"). A surface
    # off by e along its normal moves its hit by e / cos along the ray (cos = |n·d| there), so the two
    # candidates' order is as uncertain as their gap is small against t2 / cos: the relative gap is taken
    # times the smaller cos of the two (fuzz start_11_4: two crossing balls 0.0043 apart in t at a grazing
    # hit, Embree's tessellation swapped them).
    a = nearest.first

    def gap(b: _Candidate) -> np.ndarray:
        both = np.isfinite(a.t) & np.isfinite(b.t)
        cos = np.minimum(np.minimum(a.cos, b.cos), 1.0)
        pair = np.maximum(st[a.owner], st[b.owner])
        with np.errstate(invalid="ignore"):  # inf - inf where fewer than two shapes are hit
            return np.where(both, (b.t - a.t) / np.where(both, b.t, 1.0) * cos / pair, np.inf)

    tie, id_tie = (gap(nearest.second), gap(nearest.other)) if scene.shapes else (np.full(n, np.inf),) * 2
    margin = np.minimum.reduce([sil, graze, tie, origin])
    # Not a relative margin, so not in `margin`: the distance to the nearest candidate hit (either root
    # of any shape). Renderers that ignore hits closer than a fixed depth (POV-Ray: 1e-4) disagree there.
    near = a.t
    found = np.isfinite(near)
    # |n·d| of the plane whose hit is nearest (inf when a ball's is): a plane's t = n·(Q - o)/(n·d) turns a
    # direction error e into a relative t error e/|n·d|, so oracles' t tolerances scale with 1/hit_nd.
    hit_nd = np.where(found, a.nd, np.inf)
    hit_cos = np.where(found, a.cos, 1.0)  # |n·d| at the nearest candidate, ball or plane (1 where nothing is hit)
    return {
        "silhouette": sil,
        "grazing": graze,
        "tie": tie,
        "id_tie": id_tie,
        "origin": origin,
        "margin": margin,
        "near": near,
        "hit_nd": hit_nd,
        "hit_cos": hit_cos,
        "origin_norm": np.linalg.norm(o, axis=1),  # |o|, for oracles whose origin rounding scales with it
    }


def start_band(
    scene: Scene,
    origins: np.ndarray,
    directions: np.ndarray,
    t_min: float = 0.0,
    plane_err: float | np.ndarray = 0.0,
    ball_err: float | np.ndarray = 0.0,
) -> np.ndarray:
    """(N,) bool: rays with a candidate hit (any root, in front or behind, signed t) whose "does it count"
    decision ``t > t_min`` an oracle with this position error cannot make, or makes by another rule.

    Derivation: the oracle's ray origin (or the surface it intersects) is off by at most ``err`` (absolute,
    per ray or scalar; ``plane_err`` for planes, ``ball_err`` for balls). A shift e along the surface normal
    moves a candidate's t by e / cos, cos = |n·d| at the candidate (a plane's |n·d|; a ball's root:
    sqrt(r^2 - h^2) / r, h the ray's distance from the centre). So the oracle may place the candidate on
    either side of t_min when |t - t_min| cos < err. And when t_min > 0 a candidate with 0 < t <= t_min is
    counted by the reference but dropped by the oracle's own rule (POV-Ray's minimum distance): also not a
    defect. Together: -err < t cos < t_min cos + err. For a plane t cos = sign(n·d) n·(Q - o), the origin's
    signed distance from the plane, computed without dividing (a ray parallel to a plane it starts in is
    caught too). Tangent ball roots (cos -> 0) fall in the silhouette band anyway."""
    o = np.asarray(origins, dtype=np.float64)
    d = np.asarray(directions, dtype=np.float64)
    out = np.zeros(o.shape[0], dtype=bool)
    for s in scene.shapes:
        if isinstance(s, Ball):
            br = ball_roots(s.center, s.radius, o, d)  # stable forms (minirt.model.roots)
            cos = br.sq / s.radius
            for t in (br.r0, br.q):
                tc = t * cos
                out |= (br.disc >= 0) & (tc > -ball_err) & (tc < t_min * cos + ball_err)
        else:
            nn = np.asarray(s.normal)
            nd = d @ nn
            tc = np.where(nd < 0, -1.0, 1.0) * ((np.asarray(s.point) - o) @ nn)
            out |= (tc > -plane_err) & (tc < t_min * np.abs(nd) + plane_err)
    return out


def sample_band(
    scene: Scene,
    rules: Rules,
    samples: int,
    eps: float,
    t_min: float = 0.0,
    start_err: float = 0.0,
    scale: Sequence[float] | None = None,
    origin_scale: Sequence[float] | None = None,
    t_max: float = np.inf,
    inside_scale: Sequence[float] | None = None,
) -> np.ndarray:
    """(H, W) bool: pixels where any of the ``samples`` stratified rays (camera.sample_offsets) has a
    margin below ``eps`` or lies in ``start_band(t_min, start_err)`` (for planes and balls alike). With
    a per-shape ``scale``, ``origin_scale`` and ``inside_scale`` (see margins), the scaled margin below 1
    instead of ``eps``. Rays whose nearest candidate hit lies at ``t_max`` or beyond (an oracle's farthest
    hit) too."""
    w, h = scene.camera.width, scene.camera.height
    out = np.zeros(w * h, dtype=bool)
    for s in range(samples):
        o, d = camera.rays_through(scene, rules, *camera.sample_offsets(samples, s, w * h))
        with np.errstate(invalid="ignore"):
            m = margins(scene, o, d, scale, origin_scale, inside_scale)
        out |= (m["margin"] < (eps if scale is None else 1.0)) | start_band(scene, o, d, t_min, start_err, start_err)
        out |= np.isfinite(m["near"]) & (m["near"] >= t_max)
    return out.reshape(h, w)
