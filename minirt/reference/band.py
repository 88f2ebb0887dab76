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

**Many balls** (``Rays``): every ray against every ball is rays x balls work (a 1,024-ball check at 128x128
spent 17 s of its 50 here). Callers only ever ask whether a margin is below a threshold, so ``Rays`` gives
the silhouette, origin and overall margins exactly where they are below a ``bound`` the caller names (at
least its threshold) and inf elsewhere; the other quantities (ties, the nearest hit, grazing planes) are
exact everywhere. A ball can only give a silhouette or origin margin below ``bound`` (scaled: below
``bound`` times its scale) to a ray whose line passes within r (1 + bound scale) of its centre, and it can
only be hit by such a ray, so the ball tree (minirt.reference.accel.build) finds those (ray, ball) pairs,
the candidates, and only they are computed -- each with the very arithmetic of the every-ball path
(minirt.model.roots.ball_roots), so the same bits (tests/reference/test_band_tree.py compares the two).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from minirt.model import camera
from minirt.model.roots import ball_roots, row_norm
from minirt.model.rules import Rules
from minirt.model.scene import Ball, Scene


class _Candidate:
    """Per ray: a candidate hit's t, the |n·d| of its plane (inf for a ball), its cosine against the surface
    and its shape's index."""

    def __init__(self, n: int):
        self.t, self.nd = np.full(n, np.inf), np.full(n, np.inf)
        self.cos, self.owner = np.ones(n), np.zeros(n, dtype=np.int64)

    def take(self, where: np.ndarray, src: _Candidate | tuple) -> None:
        """Where ``where``, the candidate ``src`` (another's, or (t, nd, cos, owner)), written in place: each
        _Candidate owns its arrays, so a copy from one never aliases another."""
        t, nd, cos, owner = (src.t, src.nd, src.cos, src.owner) if isinstance(src, _Candidate) else src
        np.copyto(self.t, t, where=where)
        np.copyto(self.nd, nd, where=where)
        np.copyto(self.cos, cos, where=where)
        np.copyto(self.owner, owner, where=where)


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
    bound: float | None = None,
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
    a quantity quadratic in the margin far from the silhouette, t moves linearly) scales them apart.

    ``bound`` (at least every threshold the caller compares these margins with): None, every margin exact,
    every ray tested against every ball; a number, ``silhouette``, ``origin`` and ``margin`` exact where
    below it and inf elsewhere, the rest exact, through the ball tree (``Rays``): what a comparison
    ``margin < eps`` with eps <= bound gives is the same either way."""
    if bound is not None:
        return Rays(scene, origins, directions).margins(scale, origin_scale, inside_scale, tie_scale, bound)
    return _every_ball(scene, origins, directions, scale, origin_scale, inside_scale, tie_scale)


def _every_ball(
    scene: Scene,
    origins: np.ndarray,
    directions: np.ndarray,
    scale: Sequence[float] | None = None,
    origin_scale: Sequence[float] | None = None,
    inside_scale: Sequence[float] | None = None,
    tie_scale: Sequence[float] | None = None,
    bound: float | None = None,
) -> dict[str, np.ndarray]:
    """``margins`` by testing every ray against every ball (rays x balls work); ``bound`` clips as ``Rays`` does."""
    o = np.asarray(origins, dtype=np.float64)
    d = np.asarray(directions, dtype=np.float64)
    n = o.shape[0]
    sil = np.full(n, np.inf)
    origin = np.full(n, np.inf)
    graze = np.full(n, np.inf)
    nearest = _Nearest(n)  # the candidate hits (each root of a ball, each plane's), two nearest kept
    sc, so, si, st = _scales(len(scene.shapes), scale, origin_scale, inside_scale, tie_scale)
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
    return _result(nearest, sil, graze, origin, st, o, bound)


def _scales(n: int, scale, origin_scale, inside_scale, tie_scale) -> tuple[np.ndarray, ...]:
    """The per-shape scales (sc, so, si, st) of ``margins``, each defaulting to ``scale``, which defaults to 1."""
    sc = np.ones(n) if scale is None else np.asarray(scale, dtype=np.float64)
    so = sc if origin_scale is None else np.asarray(origin_scale, dtype=np.float64)
    si = sc if inside_scale is None else np.asarray(inside_scale, dtype=np.float64)
    st = sc if tie_scale is None else np.asarray(tie_scale, dtype=np.float64)
    return sc, so, si, st


def _result(nearest: _Nearest, sil, graze, origin, st, o, bound: float | None) -> dict[str, np.ndarray]:
    """``margins``' dictionary from the per-ray minima and the nearest candidates."""
    # The two nearest candidates, whichever shapes (which root is nearest decides t and the normal), give
    # the tie; the nearest and the nearest of another shape give id_tie -- a ball's two roots never change
    # the shape id (fuzz far_5_0: a far ball's roots 6e-6 apart excused a swapped id as a "tie"). A surface
    # off by e along its normal moves its hit by e / cos along the ray (cos = |n·d| there), so the two
    # candidates' order is as uncertain as their gap is small against t2 / cos: the relative gap is taken
    # times the smaller cos of the two (fuzz start_11_4: two crossing balls 0.0043 apart in t at a grazing
    # hit, Embree's tessellation swapped them).
    a, n = nearest.first, len(o)

    def gap(b: _Candidate) -> np.ndarray:
        both = np.isfinite(a.t) & np.isfinite(b.t)
        cos = np.minimum(np.minimum(a.cos, b.cos), 1.0)
        pair = np.maximum(st[a.owner], st[b.owner])
        with np.errstate(invalid="ignore"):  # inf - inf where fewer than two shapes are hit
            return np.where(both, (b.t - a.t) / np.where(both, b.t, 1.0) * cos / pair, np.inf)

    tie, id_tie = (gap(nearest.second), gap(nearest.other)) if len(st) else (np.full(n, np.inf),) * 2
    margin = np.minimum.reduce([sil, graze, tie, origin])
    if bound is not None:  # what lies at or beyond the bound is not known exactly on the tree's path: inf on both
        sil, origin, margin = (np.where(x < bound, x, np.inf) for x in (sil, origin, margin))
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
        "origin_norm": row_norm(o),  # |o|, for oracles whose origin rounding scales with it
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
    caught too). Tangent ball roots (cos -> 0) fall in the silhouette band anyway. Only the balls a ray's
    line meets have a candidate: ``Rays.start_band`` finds them through the ball tree, the same answer."""
    return Rays(scene, origins, directions).start_band(t_min, plane_err, ball_err)


def _start_every_ball(scene: Scene, o: np.ndarray, d: np.ndarray, t_min: float, plane_err, ball_err) -> np.ndarray:
    """``start_band`` with every ray tested against every ball (what ``Rays.start_band`` must equal)."""
    out = np.zeros(o.shape[0], dtype=bool)
    for s in scene.shapes:
        if isinstance(s, Ball):
            br = ball_roots(s.center, s.radius, o, d)  # stable forms (minirt.model.roots)
            cos = br.sq / s.radius
            for t in (br.r0, br.q):
                tc = t * cos
                out |= (br.disc >= 0) & (tc > -ball_err) & (tc < t_min * cos + ball_err)
        else:
            out |= _plane_starts(s, o, d, t_min, plane_err)
    return out


def _plane_starts(s, o: np.ndarray, d: np.ndarray, t_min: float, plane_err) -> np.ndarray:
    nn = np.asarray(s.normal)
    nd = d @ nn
    tc = np.where(nd < 0, -1.0, 1.0) * ((np.asarray(s.point) - o) @ nn)
    return (tc > -plane_err) & (tc < t_min * np.abs(nd) + plane_err)


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
    threshold = eps if scale is None else 1.0
    balls = None  # the ball tree, built for the first sample's rays and kept for the others
    for s in range(samples):
        o, d = camera.rays_through(scene, rules, *camera.sample_offsets(samples, s, w * h))
        rays = Rays(scene, o, d, balls)
        balls = rays.balls
        with np.errstate(invalid="ignore"):
            m = rays.margins(scale, origin_scale, inside_scale, bound=threshold)
        out |= (m["margin"] < threshold) | rays.start_band(t_min, start_err, start_err)
        out |= np.isfinite(m["near"]) & (m["near"] >= t_max)
    return out.reshape(h, w)


# The bound of the margins a check shares between its oracles (``Rays.margins``' default): above the thresholds
# the bundled scenes' oracles compare with (Embree's tessellation gap at its default subdivisions, the float32
# bands: 1e-7 to 1e-2), so a check widens the bound only for a scene with a larger threshold (a coarse
# tessellation, a tiny ball far from the origin: Embree's 8 float32 ulps of the mesh's extent over r). Any
# bound gives the same comparisons below it; a larger one only finds more candidates.
BOUND = 2.0**-4
# Beyond this bound (relative to each ball's radius) a ray's candidates are most balls near its line: the
# every-ball path is taken (the same answers).
WIDEST = 64.0
# Up to this many balls (the bundled scenes have at most 4) a ray is tested against every ball, the same
# answers: few balls often cover much of the image, and sorting every ray's candidates then costs more than
# testing them all (measured under load, 1024²: the rules scene's 4 balls and 2 planes 2.2 s every ball
# against 10.9 s through the tree; random balls at 512², 8 of them: 1.3 s against 0.7 s, 64: 5.5 against 1.6).
FEW_BALLS = 4
# The candidate search's slack, relative to the lengths it compares (derivation at ``_Balls.search``).
SLACK = 2.0**-40
BLOCK = 1 << 15  # rays per block of the candidate search: bounds its frontier of (ray, node) pairs


class _Balls:
    """A scene's balls for the candidate search: centres, radii and shape ids (ball order), their tree
    (minirt.reference.accel.build, the tracer's) and each node's bounding sphere, the sphere around its box."""

    def __init__(self, scene: Scene):
        from minirt.reference.accel import build  # (accel imports Dr.Jit for its kernels: only when needed)

        balls = [(k, s) for k, s in enumerate(scene.shapes) if isinstance(s, Ball)]
        self.ids = np.array([k for k, _ in balls], dtype=np.int64)
        self.center = np.array([s.center for _, s in balls], dtype=np.float64).reshape(-1, 3)
        self.radius = np.array([s.radius for _, s in balls], dtype=np.float64)
        self.tree, self.order = build(self.center, self.radius)
        t = self.tree
        self.mid = (t.lo + t.hi) / 2
        self.half = np.linalg.norm(t.hi - t.lo, axis=1) / 2
        self.levels = []  # the nodes by depth, root first (a node's children in the next level)
        cur = np.zeros(min(1, t.nodes), dtype=np.int64)
        while cur.size:
            self.levels.append(cur)
            inner = cur[t.count[cur] == 0]
            cur = np.concatenate([inner + 1, t.right[inner]])

    def _node_max(self, x: np.ndarray) -> np.ndarray:
        """Per node, the largest of ``x`` (per ball, ball order) over its balls."""
        t = self.tree
        out = np.zeros(t.nodes)
        leaf = np.flatnonzero(t.count > 0)
        for j in range(int(t.count.max(initial=0))):
            on = leaf[t.count[leaf] > j]
            out[on] = np.maximum(out[on], x[self.order[t.first[on] + j]])
        for level in reversed(self.levels):
            inner = level[t.count[level] == 0]
            out[inner] = np.maximum(out[inner + 1], out[t.right[inner]])
        return out

    def search(self, o: np.ndarray, d: np.ndarray, beta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(ray, ball) index pairs, ball in ball order: every pair whose computed margins (``Rays``) can be
        below ``beta`` times the ball's scales -- its line within r (1 + beta) of the centre -- or that hits.

        Derivation. A node is entered when the line passes within R = (half + e) (1 + SLACK) + SLACK (R +
        |f| + S) of its middle (f = o - middle, S = max(|C| + r) of its balls, half its box's half diagonal,
        e = max r beta of its balls). Exactly: a ball within the node's box lies within half of the middle,
        and the line's distance from a point is 1-Lipschitz, so a line within r (1 + beta) of a ball's
        centre passes within half + r beta <= half + e of the middle. Rounding: the box's corners are the
        balls' C +- r rounded (u (|C| + r) each), the middle and half diagonal a few roundings more, the
        line's computed distance |f - (f·d) d| errs by <= 12 u |f| (minirt.reference.accel._Pad); and a
        ball's computed margin below its bound, |h' - r| / r < beta (1 + 4 u) or | |f'| - r | / r alike,
        or its computed discriminant >= 0 (h' <= r), puts its exact distance within r (1 + beta) (1 + 4 u)
        + 14 u |f|. All of it is below 2^-40 of the lengths involved (u = 2^-53): SLACK covers it 100
        times over, so no pair the every-ball path counts is missed; extra pairs are harmless (their
        margins are computed and clipped as the every-ball path's)."""
        t = self.tree
        if not t.nodes:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        reach = (self.half + self._node_max(self.radius * beta)) * (1 + SLACK)
        slack = SLACK * (reach + t.reach)
        rays, balls = [], []
        for start in range(0, len(o), BLOCK):
            ray = np.arange(start, min(start + BLOCK, len(o)))
            node = np.zeros(len(ray), dtype=np.int64)
            while ray.size:
                f = o[ray] - self.mid[node]
                dd = d[ray]
                b = np.einsum("ij,ij->i", f, dd)
                h = row_norm(f - b[:, None] * dd)
                keep = h <= reach[node] + slack[node] + SLACK * row_norm(f)
                ray, node = ray[keep], node[keep]
                count = t.count[node]
                for j in range(int(count.max(initial=0))):
                    on = count > j
                    rays.append(ray[on])
                    balls.append(self.order[t.first[node[on]] + j])
                inner = count == 0
                ray, node = ray[inner], node[inner]
                ray, node = np.repeat(ray, 2), np.stack([node + 1, t.right[node]], axis=1).reshape(-1)
        return np.concatenate(rays or [np.zeros(0, np.int64)]), np.concatenate(balls or [np.zeros(0, np.int64)])


class Rays:
    """One set of rays through a scene, whose margins several callers ask for (a check: every oracle, each
    unscaled and with its own per-shape scales): the ball tree, the candidate (ray, ball) pairs and the
    nearest hits are found once and shared. Margins as ``margins`` gives them with a ``bound``: exact below
    it, inf elsewhere (``silhouette``, ``origin``, ``margin``; the rest exact); ``start_band`` exact."""

    def __init__(self, scene: Scene, origins: np.ndarray, directions: np.ndarray, balls: _Balls | None = None):
        self.scene = scene
        self.o = np.asarray(origins, dtype=np.float64)
        self.d = np.asarray(directions, dtype=np.float64)
        self._balls = balls
        self._pairs: tuple | None = None  # (beta, ray, ball, BallRoots) of the widest search so far
        self._nearest: _Nearest | None = None
        self._planes: list | None = None
        self._plain: dict[float, dict[str, np.ndarray]] = {}  # unscaled margins by bound
        self._n_balls: int | None = None

    @property
    def balls(self) -> _Balls:
        if self._balls is None:
            self._balls = _Balls(self.scene)
        return self._balls

    def margins(
        self,
        scale: Sequence[float] | None = None,
        origin_scale: Sequence[float] | None = None,
        inside_scale: Sequence[float] | None = None,
        tie_scale: Sequence[float] | None = None,
        bound: float = BOUND,
    ) -> dict[str, np.ndarray]:
        """minirt.reference.band.margins of these rays with this ``bound`` (the same arrays, bit for bit)."""
        plain = scale is None and origin_scale is None and inside_scale is None and tie_scale is None
        if plain and bound in self._plain:
            return self._plain[bound]
        if not bound <= WIDEST or self._few():  # (nan included)
            m = _every_ball(self.scene, self.o, self.d, scale, origin_scale, inside_scale, tie_scale, bound)
            if plain:
                self._plain[bound] = m
            return m
        n = len(self.o)
        sc, so, si, st = _scales(len(self.scene.shapes), scale, origin_scale, inside_scale, tie_scale)
        ids = self.balls.ids
        beta = max(bound, 0.0) * np.maximum(np.maximum(sc[ids], si[ids]), so[ids])
        _, ray, ball, br = self._candidates(beta)
        k, r = ids[ball], self.balls.radius[ball]
        sil, origin, graze = np.full(n, np.inf), np.full(n, np.inf), np.full(n, np.inf)
        with np.errstate(divide="ignore", invalid="ignore"):
            for out, v in (
                (sil, np.abs(br.h - r) / r / np.where(br.h < r, si[k], sc[k])),
                (origin, np.abs(br.lf - r) / r / so[k]),
            ):
                on = v < bound
                np.minimum.at(out, ray[on], v[on])
        for k_, nd, _ in self._plane_hits():
            graze = np.minimum(graze, np.abs(nd) / sc[k_])
        m = _result(self._hits(), sil, graze, origin, st, self.o, bound)
        if plain:
            self._plain[bound] = m
        return m

    def start_band(self, t_min: float = 0.0, plane_err=0.0, ball_err=0.0) -> np.ndarray:
        """minirt.reference.band.start_band of these rays (the same answer)."""
        if self._few():
            return _start_every_ball(self.scene, self.o, self.d, t_min, plane_err, ball_err)
        out = np.zeros(len(self.o), dtype=bool)
        if self._pairs is None:
            self._candidates(np.zeros(len(self.balls.ids)))
        _, ray, ball, br = self._pairs
        be = np.asarray(ball_err)[ray] if np.ndim(ball_err) else ball_err
        cos = br.sq / self.balls.radius[ball]
        on = np.zeros(len(ray), dtype=bool)
        for t in (br.r0, br.q):
            tc = t * cos
            on |= (br.disc >= 0) & (tc > -be) & (tc < t_min * cos + be)
        out[ray[on]] = True
        for s in self.scene.shapes:
            if not isinstance(s, Ball):
                out |= _plane_starts(s, self.o, self.d, t_min, plane_err)
        return out

    def _few(self) -> bool:
        """At most FEW_BALLS balls: every ray against every ball."""
        if self._n_balls is None:
            self._n_balls = sum(isinstance(s, Ball) for s in self.scene.shapes)
        return self._n_balls <= FEW_BALLS

    def _candidates(self, beta: np.ndarray) -> tuple:
        """The (ray, ball) pairs of ``_Balls.search`` for at least ``beta`` (a wider search kept), with their roots."""
        if self._pairs is not None and not (beta > self._pairs[0]).any():
            return self._pairs
        if self._pairs is not None:
            beta = np.maximum(beta, self._pairs[0])
        ray, ball = self.balls.search(self.o, self.d, beta)
        b = self.balls
        self._pairs = (beta, ray, ball, ball_roots(b.center[ball], b.radius[ball], self.o[ray], self.d[ray]))
        return self._pairs

    def _plane_hits(self) -> list:
        """Per plane: its shape id, n·d and t of every ray (as the every-ball path computes them)."""
        if self._planes is None:
            self._planes = []
            for k, s in enumerate(self.scene.shapes):
                if not isinstance(s, Ball):
                    nn = np.asarray(s.normal)
                    nd = self.d @ nn
                    with np.errstate(divide="ignore", invalid="ignore"):
                        t = ((np.asarray(s.point) - self.o) @ nn) / nd
                    self._planes.append((k, nd, t))
        return self._planes

    def _hits(self) -> _Nearest:
        """The nearest candidate hits as ``_Nearest`` keeps them when every shape is pushed in order: every
        candidate (a hit ball's roots > 0, a plane's t > 0) sorted by ray, t and push order, its first,
        second and first of another shape per ray (tests/reference/test_band_scale.py: the same picks)."""
        if self._nearest is not None:
            return self._nearest
        if self._pairs is None:
            self._candidates(np.zeros(len(self.balls.ids)))
        _, ray, ball, br = self._pairs
        k, r = self.balls.ids[ball], self.balls.radius[ball]
        hit, cos = br.disc >= 0, br.sq / r
        cols: list[list[np.ndarray]] = [[], [], [], [], [], []]  # ray, t, push order, nd, cos, owner

        def add(on, *c):
            for col, x in zip(cols, c, strict=True):
                col.append(np.broadcast_to(x, on.shape)[on])

        for j, t in enumerate((np.minimum(br.r0, br.q), np.maximum(br.r0, br.q))):
            add(hit & (t > 0), ray, t, 2 * k + j, np.inf, cos, k)
        every = np.arange(len(self.o))
        for k_, nd, t in self._plane_hits():
            add(np.isfinite(t) & (t > 0), every, t, 2 * k_, np.abs(nd), np.abs(nd), k_)
        rs, ts, seq, nds, coss, owners = (np.concatenate(c) for c in cols)
        order = np.lexsort((seq, ts, rs))
        rs, ts, nds, coss, owners = rs[order], ts[order], nds[order], coss[order], owners[order]
        near = _Nearest(len(self.o))

        def put(c: _Candidate, at: np.ndarray) -> None:
            c.t[rs[at]], c.nd[rs[at]], c.cos[rs[at]], c.owner[rs[at]] = ts[at], nds[at], coss[at], owners[at]

        new = np.ones(len(rs), dtype=bool)
        new[1:] = rs[1:] != rs[:-1]
        first = np.flatnonzero(new)
        put(near.first, first)
        second = first[first + 1 < len(rs)] + 1
        put(near.second, second[~new[second]])
        other = np.flatnonzero(owners != near.first.owner[rs])
        if other.size:
            lead = np.ones(len(other), dtype=bool)
            lead[1:] = rs[other[1:]] != rs[other[:-1]]
            put(near.other, other[lead])
        self._nearest = near
        return near
