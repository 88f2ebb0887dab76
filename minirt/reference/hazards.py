"""What in a scene makes the reference's own image depend on its scale or its precision: said, not fixed.

The exercise's rules are kept (a fixed offset of 1e-6 is the problem set's hint), but three things are
worth a warning because the image then shows rounding or jumps instead of the scene:

- **Offset below the hit point's rounding** (acne). A secondary ray starts at p + offset·v (v the normal,
  or the new ray's direction under offset_along = "ray"); its distance from the surface is offset·|v·n|.
  The hit point itself is rounded: each coordinate by up to u|p_i| (u the unit round-off of the precision
  traced), so its distance from the surface is uncertain by u·‖p‖₁ -- the least error any tracer of that
  precision has there. An offset below it may start the ray behind the surface, which then shadows itself
  (measured: three_balls at scale 1e3 in float32 under the exercise's 1e-6, tests/reference/test_hard_cases.py).
- **Offset larger than a gap** (near contacts). If another shape's surface lies between p and the ray's
  offset origin, the ray starts beyond it (or inside it, where near_root_only sees nothing): its shadow or
  reflection is lost. Decided exactly per pixel: the other surface's implicit function (|x - C| - r for a
  ball, n·x - a for a plane) changes sign between p and the origin.
- **float32 cannot hold a coordinate to the scene's detail.** Each number the tracer uses (centres,
  radii, planes, the light, the camera distance) rounded to float32 moves by |f32(v) - v|; the scene's
  detail is the smallest length it states (a radius, the camera distance, the image plane's pixel pitch
  1/max(W, H)). A move beyond 1/256 of that detail -- more than one 8-bit level of a feature's shading
  across it, or a sizeable fraction of a pixel at the image plane -- changes what is drawn (a centre at
  -1e8 - 1 becomes -1e8 and a ground of radius 1e8 then passes through the camera).

The functions return one line per finding (no scene text beyond its own numbers and key names):
``scene_warnings`` gathers them for a scene as ``minirt render`` and ``minirt check`` print them (as warnings);
``offset_at`` explains one pixel for ``minirt probe``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np

from minirt.errors import MinirtError
from minirt.model import camera
from minirt.model.effects import effects
from minirt.model.result import RenderResult
from minirt.model.roots import row_norm
from minirt.model.rules import Rules
from minirt.model.scene import Ball, Scene, colour_warnings

UNIT_ROUNDOFF = {"f64": 2.0**-53, "f32": 2.0**-24}
DETAIL_FRACTION = 2.0**-8  # see the module docstring: a move beyond 1/256 of the scene's detail is visible
HAZARD_PREVIEW_PIXELS = 2**18  # offset hazards of a render without buffers are counted on a render this size


def _surface(shape, x: np.ndarray) -> np.ndarray:
    """The shape's implicit function at points x (N, 3): > 0 outside a ball / on a plane's normal side."""
    if isinstance(shape, Ball):
        return row_norm(x - np.asarray(shape.center)) - shape.radius
    return x @ np.asarray(shape.normal) - shape.distance


def _secondary(
    scene: Scene,
    rules: Rules,
    res: RenderResult,
    pixels: np.ndarray | None = None,
    directions: bool = True,
    fx: Any = None,
) -> dict[str, np.ndarray | None]:
    """Per primary hit (flat): the point, shading normal, own shape, and the shadow and reflection
    directions of the secondary rays the render spawns there (mask: whether it spawns them).
    ``pixels``: the row-major indices of the hit pixels wanted (default: every hit). ``directions``:
    False leaves the two directions out (None; the kinds spawned are still said by their keys): an
    offset along the normal does not need them. ``fx``: the scene's effects and its shapes' reflecting (as
    ``_reflecting`` gives them), made once for a render's chunks of hits."""
    if pixels is None:
        pixels = np.flatnonzero(res.hit.reshape(-1))
    p, n = _gather(res, "position", pixels), _gather(res, "normal", pixels)
    sid = res.shape_id.reshape(-1)[pixels]
    fx, kr = fx or _reflecting(scene, rules)
    d = None
    if rules.two_sided or (directions and fx.reflection):
        _, d = camera.primary_rays(scene, rules, pixels)  # the hit pixels' rays, the same bits as the image's
    if rules.two_sided:
        n = np.where((np.einsum("ij,ij->i", d, n) > 0)[:, None], -n, n)
    out: dict[str, np.ndarray | None] = {"p": p, "n": n, "id": sid}
    if fx.shadows:
        out["shadow"] = None
        if directions:
            s = np.asarray(scene.light.position) - p
            out["shadow"] = s / np.maximum(np.linalg.norm(s, axis=1, keepdims=True), 1e-300)
    if fx.reflection:
        r = None if d is None else d - 2 * np.einsum("ij,ij->i", d, n)[:, None] * n
        # normalised, as the tracer's reflected Ray (minirt.reference.shading)
        out["reflection"] = None if r is None else r / np.linalg.norm(r, axis=1, keepdims=True)
        out["reflects"] = kr[sid] if len(sid) else np.zeros(0, dtype=bool)
    return out


def _reflecting(scene: Scene, rules: Rules) -> tuple[Any, np.ndarray]:
    """The scene's effects, and per shape whether its material reflects."""
    kr = np.array([any(c != 0 for c in sh.material.reflection) for sh in scene.shapes], dtype=bool)
    return effects(scene, rules), kr


def _gather(res: RenderResult, name: str, pixels: np.ndarray) -> np.ndarray:
    """(N, 3): the vector buffer ``name`` at these row-major pixels, gathered from its components as the
    result holds them (a render's Planes are not stacked into a whole-image copy: 50 MB at 1024^2 for the
    position and the normal, most of what the warnings cost there)."""
    comps = res.components(name)
    out = np.empty((len(pixels), 3))
    for k, c in enumerate(comps):
        out[:, k] = c.reshape(-1)[pixels]
    return out


def _judge(
    scene: Scene, rules: Rules, g: dict[str, np.ndarray], precision: str, balls: _Balls | None = None
) -> dict[str, np.ndarray]:
    """Per hit (flat) and secondary ray kind: offset below the point's rounding, and other shapes jumped.
    ``balls``: the scene's balls and their index (``_Balls.of``), shared by the calls of one render."""
    off = float(rules.offset)
    u = UNIT_ROUNDOFF[precision]
    rounding = u * np.abs(g["p"]).sum(axis=1)
    below = np.zeros(len(g["p"]), dtype=bool)
    jumped = np.zeros(len(g["p"]), dtype=bool)
    if balls is None:
        balls = _Balls.of(scene)  # one index of the balls for both kinds of secondary ray
    # The segment p -> p + offset v of each ray kind that is spawned. Along the normal, both kinds start
    # at the same point: it is tested once, where either kind is spawned (the same answer per point).
    segments: list[tuple[np.ndarray, np.ndarray]] = []
    for kind in ("shadow", "reflection"):
        if kind not in g:
            continue
        spawn = g.get("reflects", np.ones(len(g["p"]), dtype=bool)) if kind == "reflection" else True
        spawn = np.broadcast_to(spawn, len(g["p"]))
        v = g[kind] if rules.offset_along == "ray" else g["n"]
        normal_part = off * np.abs(np.einsum("ij,ij->i", v, g["n"]))
        below |= spawn & (normal_part < rounding)
        if segments and rules.offset_along != "ray":
            segments[0] = (segments[0][0] | spawn, v)
        else:
            segments.append((spawn, v))
    for spawn, v in segments:
        at = np.flatnonzero(spawn)
        p = g["p"][at]
        jumped[at] |= _jumped(scene, p, p + off * v[at], g["id"][at], balls)
    return {"below": below, "jumped": jumped, "rounding": rounding}


CHUNK = 1 << 20  # points per pass of _jumped_tree: bounds its (point, node) pairs whatever the image size
HAZARD_CHUNK = 1 << 16  # hits judged at a time by offset_warnings: ~20 MB of temporaries, reused
GRID_CELLS_PER_BALL = 8  # the grid's cells, per ball: a few balls per cell, a few cells per ball
GRID_CELLS = (64, 1 << 22)  # ... within these bounds (a tiny scene still gets a grid; memory stays bounded)
SCREEN_MAX_PAIRS = 1 << 22  # shape x ball gaps ``_Balls.gaps`` keeps (32 MB); beyond, every point goes to the grid
GRID_SPREAD = 4  # a point visits at most this many cells on average, a ball is filed in at most this many
# times GRID_CELLS_PER_BALL cells on average; beyond that (huge offsets, balls far larger than their
# neighbours' spacing) the grid would cost more than the tree, which then answers instead


class _Balls(NamedTuple):
    """The scene's balls for ``_jumped``: shape ids, centres, radii, and (built when first needed)
    minirt.reference.accel.build's tree and order (None when there are no balls)."""

    ids: list[int]
    center: np.ndarray
    radius: np.ndarray
    tree: list[Any]  # [] until built, then [tree, order]
    grid: list[Any]  # [] until built, then [pad, _Grid or None (a grid would not pay)]
    gap: list[Any]  # [] until built, then [the (shapes, balls) gaps of ``gaps``, or None (too many)]

    @classmethod
    def of(cls, scene: Scene) -> _Balls:
        ids = [k for k, s in enumerate(scene.shapes) if isinstance(s, Ball)]
        center = np.array([scene.shapes[k].center for k in ids], dtype=np.float64).reshape(-1, 3)
        radius = np.array([scene.shapes[k].radius for k in ids], dtype=np.float64)
        return cls(ids, center, radius, [], [], [])

    def gaps(self, shapes: Sequence[Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """Per shape, the least distance between its surface and another ball's (``_gaps``, the least over
        the balls; NaN where one is NaN), whether it is a ball, and its slot among the balls (-1: a plane).
        None when there are more than SCREEN_MAX_PAIRS pairs (then every point is tested)."""
        if not self.gap:
            if len(shapes) * len(self.ids) > SCREEN_MAX_PAIRS:
                self.gap.append(None)
            else:
                is_ball = np.zeros(len(shapes), dtype=bool)
                is_ball[self.ids] = True
                slot = np.full(len(shapes), -1, dtype=np.int64)
                slot[self.ids] = np.arange(len(self.ids))
                self.gap.append((_gaps(shapes, self).min(axis=1), is_ball, slot))  # min: NaN if any is
        return self.gap[0]

    def grid_for(self, pad: float) -> _Grid | None:
        """A grid of the balls' boxes widened by at least ``pad`` (more is as exact: a ball filed where
        it cannot be crossed is tested and found not crossed). Built once for a render's hits, with
        headroom, and again only for a chunk of hits that needs a wider pad."""
        if not self.grid or self.grid[0] < pad:
            self.grid[:] = [2 * pad, _build_grid(self, 2 * pad)]
        return self.grid[1]

    def bvh(self) -> tuple[Any, Any]:
        if not self.tree:
            from minirt.reference import accel  # deferred: accel imports Dr.Jit, which only the tree needs

            self.tree.extend(accel.build(self.center, self.radius) if self.ids else (None, None))
        return self.tree[0], self.tree[1]


def _gaps(shapes: Sequence[Any], balls: _Balls) -> np.ndarray:
    """``_Balls.gaps``: between balls |C_k - C_j| - r_k - r_j (apart), or r_j - |C_k - C_j| - r_k (k inside
    j), or r_k - |C_k - C_j| - r_j (j inside k), the one that is positive (none: the surfaces cross, 0); from a
    plane n·x = a (n of unit length) to a ball |n·C_j - a| - r_j, or 0 where the ball crosses it."""
    out = np.zeros((len(shapes), len(balls.ids)))
    with np.errstate(invalid="ignore", over="ignore"):
        for k, shape in enumerate(shapes):
            if isinstance(shape, Ball):
                dist = row_norm(balls.center - np.asarray(shape.center))
                apart = dist - shape.radius - balls.radius
                inside = np.maximum(balls.radius - dist - shape.radius, shape.radius - dist - balls.radius)
                out[k] = np.maximum(np.maximum(apart, inside), 0.0)
            else:
                side = np.abs(balls.center @ np.asarray(shape.normal) - shape.distance)
                out[k] = np.maximum(side - balls.radius, 0.0)
    for j, k in enumerate(balls.ids):
        out[k, j] = np.inf  # a point's own ball is not tested
    return out


def _near_shapes(scene: Scene, p: np.ndarray, q: np.ndarray, sid: np.ndarray, balls: _Balls) -> np.ndarray | None:
    """Per point: whether a ball other than its own may come near enough to its segment p -> q that the ball's
    sign changes along it (the points ``_jumped`` tests against the balls); None: every point may (no screen).

    Point i lies e_i = |f_k(p_i)| from its own shape k's surface (f_k its implicit function, computed), so at
    least gap(k, j) - e_i from ball j's surface (``_Balls.gaps``), and q_i within L_i = |q_i - p_i| of p_i:
    at both ends the ball's implicit function is at least gap - e_i - L_i from 0, on the same side. Its
    computed value errs by less than pad (``_jumped``), as do e_i's and the gap's (roundings of the same
    sizes, and of the planes' |a|); so where gap(k, j) > max_i (e_i + L_i (1 + 2^-40)) + 4 pad + 2^-40 (max|x|
    + reach + max|a|), no point of shape k can see ball j's sign change -- the answer testing it gives, found
    without testing it. The points of shapes with no ball that near are left out: what the test costs is then
    in proportion to the near contacts a scene has (what it can find), not to its pixels. A point whose e_i or
    L_i is not finite is kept."""
    gaps = balls.gaps(scene.shapes)
    if gaps is None or not len(p) or sid.min() < 0 or sid.max() >= len(scene.shapes):
        return None
    least, is_ball, slot = gaps
    with np.errstate(invalid="ignore", over="ignore"):
        own = np.empty(len(p))
        on_ball = is_ball[sid]
        b = slot[sid[on_ball]]
        own[on_ball] = row_norm(p[on_ball] - balls.center[b]) - balls.radius[b]
        for k, shape in enumerate(scene.shapes):
            if not isinstance(shape, Ball):
                at = sid == k
                own[at] = p[at] @ np.asarray(shape.normal) - shape.distance
        reach = np.abs(own) + row_norm(q - p) * (1 + 2.0**-40)
        bad = ~np.isfinite(reach)
        worst = float(np.where(bad, 0.0, reach).max())
        x_max = float(max(np.abs(p).sum(axis=1).max(), np.abs(q).sum(axis=1).max()))
        ball_reach = float((row_norm(balls.center) + balls.radius).max())
        planes = [abs(s.distance) for s in scene.shapes if not isinstance(s, Ball)]
        pad = 16 * UNIT_ROUNDOFF["f64"] * (x_max + ball_reach)  # _pad's
        margin = 4 * pad + 2.0**-40 * (x_max + ball_reach + max(planes, default=0.0))
        if not math.isfinite(worst + margin):
            return None
        near = ~(least > worst + margin)  # per shape; NaN: near
        return near[sid] | bad


def _jumped(scene: Scene, p: np.ndarray, q: np.ndarray, sid: np.ndarray, balls: _Balls | None = None) -> np.ndarray:
    """Per point: whether the segment p -> q crosses the surface of a shape other than its own (sid), i.e.
    the shape's implicit function, as computed, changes sign between p and q.

    Planes are tested at every point. Balls only where the segment's box meets the ball's box widened by
    ``pad``: outside it the ball's implicit function is > pad at both ends (|x - C| - r is at least the
    distance to the box), and its computed value errs by a few roundings of |x| + |C| + r, far less than
    pad = 16 u (max|x| + max(|C| + r)), so it is positive at both ends and the sign cannot change. Which
    boxes meet is found on a uniform grid over the balls' widened boxes (``_grid_pairs``: each point looks
    in the cells its segment's box covers, a few balls each), else through the BVH of
    minirt.reference.accel (``_jumped_tree``). Either way the balls not tested are only balls whose sign
    cannot change, and the balls tested are tested with the same arithmetic, so the answer is the one
    testing every ball gives (tests/reference/test_hazards.py), at a cost that grows with the balls near
    each point instead of all of them (200 balls at 1024^2: 1.8 s by testing every ball's box through the
    tree, 0.1 s on the grid; benchmarks/README.md).
    """
    out = np.zeros(len(p), dtype=bool)
    with np.errstate(invalid="ignore"):
        for k, shape in enumerate(scene.shapes):
            if not isinstance(shape, Ball):
                out |= (sid != k) & (np.sign(_surface(shape, p)) != np.sign(_surface(shape, q)))
    if balls is None:
        balls = _Balls.of(scene)
    if not balls.ids or not len(p):
        return out
    near = _near_shapes(scene, p, q, sid, balls)
    if near is not None:  # only the points some ball comes near (the rest cannot cross one)
        at = np.flatnonzero(near)
        if len(at) < len(p):
            out[at] |= _jumped_balls(balls, p[at], q[at], sid[at])
            return out
    return out | _jumped_balls(balls, p, q, sid)


def _jumped_balls(balls: _Balls, p: np.ndarray, q: np.ndarray, sid: np.ndarray) -> np.ndarray:
    """``_jumped``'s test of the balls alone, on the grid or through the tree."""
    out = np.zeros(len(p), dtype=bool)
    if not len(p):
        return out
    found = _grid_pairs(balls, p, q)
    if found is None:
        return out | _jumped_tree(balls, p, q, sid)
    pp, bb = found
    shape_of = np.asarray(balls.ids)
    keep = sid[pp] != shape_of[bb]  # a point's own ball is not tested (as with the tree)
    pp, bb = pp[keep], bb[keep]
    crossed = _crosses(p[pp], q[pp], balls.center[bb], balls.radius[bb])
    out |= np.bincount(pp[crossed], minlength=len(p)) > 0
    return out


def _crosses(p: np.ndarray, q: np.ndarray, c: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Per (point, ball) pair: whether the ball's implicit function |x - C| - r, as computed, changes sign
    between p and q (``_jumped``'s test of a ball, found on the grid or through the tree)."""
    with np.errstate(invalid="ignore"):
        return np.sign(row_norm(p - c) - r) != np.sign(row_norm(q - c) - r)


def _pad(balls: _Balls, p: np.ndarray, q: np.ndarray) -> float:
    """How far a ball's box is widened (``_jumped``): 16 u (max|x| + max(|C| + r)) over these points."""
    x_max = float(max(np.abs(p).sum(axis=1).max(), np.abs(q).sum(axis=1).max()))
    reach = float((np.linalg.norm(balls.center, axis=1) + balls.radius).max())
    return 16 * UNIT_ROUNDOFF["f64"] * (x_max + reach)


class _Grid(NamedTuple):
    """Balls filed in the cells of a uniform grid (``_grid_pairs``): the grid's box lo..hi, its cells
    per axis and their size; the balls of flat cell k are filed[start[k]:start[k + 1]]."""

    lo: np.ndarray
    hi: np.ndarray
    res: np.ndarray
    size: np.ndarray
    start: np.ndarray
    filed: np.ndarray

    def index(self, x: np.ndarray) -> np.ndarray:
        return np.clip(np.floor((x - self.lo) / self.size), 0, self.res - 1).astype(np.int64)

    def flat(self, cell: np.ndarray) -> np.ndarray:
        return (cell[:, 0] * self.res[1] + cell[:, 1]) * self.res[2] + cell[:, 2]


def _build_grid(balls: _Balls, pad: float) -> _Grid | None:
    """The balls' boxes widened by ``pad``, filed in the cells they cover; None where that does not pay
    (``GRID_SPREAD``) or the numbers are not finite."""
    n = len(balls.ids)
    if not math.isfinite(pad):
        return None
    lo_b = balls.center - balls.radius[:, None] - pad
    hi_b = balls.center + balls.radius[:, None] + pad
    glo, ghi = lo_b.min(axis=0), hi_b.max(axis=0)
    ext = ghi - glo
    if not (np.isfinite(ext).all() and (ext > 0).all()):
        return None
    cells = min(max(GRID_CELLS_PER_BALL * n, GRID_CELLS[0]), GRID_CELLS[1])
    side = (float(np.prod(ext)) / cells) ** (1 / 3)
    res = np.clip(np.ceil(ext / side), 1, cells).astype(np.int64)
    while res.prod() > 2 * cells:  # a flat box (one side far below the others): coarser, until it fits
        side *= 1.25
        res = np.clip(np.ceil(ext / side), 1, cells).astype(np.int64)
    grid = _Grid(glo, ghi, res, ext / res, np.zeros(int(res.prod()) + 1, dtype=np.int64), np.zeros(0, np.int64))
    b0 = grid.index(lo_b)
    span = grid.index(hi_b) - b0 + 1
    per_ball = span.prod(axis=1)
    if per_ball.sum() > GRID_SPREAD * GRID_CELLS_PER_BALL * n + 1024:
        return None
    ball, cell = _expand(b0, span, per_ball)
    flat = grid.flat(cell)
    np.cumsum(np.bincount(flat, minlength=int(res.prod())), out=grid.start[1:])
    return grid._replace(filed=ball[np.argsort(flat, kind="stable")])


def _grid_pairs(balls: _Balls, p: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """(point, ball) pairs, indices into p and into the balls, that include every pair whose segment box
    meets the ball's box widened by ``_pad`` (some pairs more, never fewer); None where a grid does not
    pay (``GRID_SPREAD``) or the numbers are not finite (then the tree answers).

    The grid (``_build_grid``): ``res`` cells per axis over the box of every widened ball box, a cell
    index ``clip(floor((x - lo) / size), 0, res - 1)`` per coordinate. That index never decreases as x
    grows (a subtraction, a division by a positive number, floor and clip are each monotone, also as
    rounded), so when a segment's box [a, b] meets a ball's [lo_b, hi_b] (a <= hi_b and b >= lo_b per
    axis), the cells of the one, index(a) .. index(b), meet those of the other: the ball is filed in a
    cell the point looks in. A segment box wholly outside the grid's box meets no ball box (exact
    comparisons)."""
    grid = balls.grid_for(_pad(balls, p, q))
    if grid is None:
        return None
    # The points: the cells their segment's box covers (none outside the grid's box; NaN is never inside).
    seg_lo, seg_hi = np.minimum(p, q), np.maximum(p, q)
    inside = np.flatnonzero(np.all((seg_hi >= grid.lo) & (seg_lo <= grid.hi), axis=1))
    a0 = grid.index(seg_lo[inside])
    span = grid.index(seg_hi[inside]) - a0 + 1
    per_point = span.prod(axis=1)
    if per_point.sum() > GRID_SPREAD * len(p) + 1024:
        return None
    if (per_point == 1).all():  # every segment within one cell (an offset far below a cell): no expansion
        point, cell = np.arange(len(inside)), a0
    else:
        point, cell = _expand(a0, span, per_point)
    flat = grid.flat(cell)
    first, count = grid.start[flat], grid.start[flat + 1] - grid.start[flat]
    pp = np.repeat(inside[point], count)
    slot = np.repeat(first - (np.cumsum(count) - count), count) + np.arange(int(count.sum()))
    return pp, grid.filed[slot]


def _expand(first: np.ndarray, span: np.ndarray, count: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each row i's cells first[i] + (0 .. span[i] - 1) per axis (count[i] = their product), as (row, cell)."""
    row = np.repeat(np.arange(len(count)), count)
    k = np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count)
    s = span[row]
    dz = k % s[:, 2]
    k //= s[:, 2]
    dy = k % s[:, 1]
    dx = k // s[:, 1]
    return row, first[row] + np.stack([dx, dy, dz], axis=1)


def _jumped_tree(balls: _Balls, p: np.ndarray, q: np.ndarray, sid: np.ndarray) -> np.ndarray:
    """``_jumped``'s balls found through the BVH: each segment's box tested against the nodes' boxes
    widened by the pad, top down, breadth first (the grid's fallback)."""
    out = np.zeros(len(p), dtype=bool)
    center, radius = balls.center, balls.radius
    tree, order = balls.bvh()
    shape_of = np.asarray(balls.ids)[order]  # ball slot of the tree -> shape id
    for a in range(0, len(p), CHUNK):
        pc, qc, ic = p[a : a + CHUNK], q[a : a + CHUNK], sid[a : a + CHUNK]
        seg_lo, seg_hi = np.minimum(pc, qc), np.maximum(pc, qc)
        x_max = float(np.max(np.abs(np.concatenate([pc, qc])).sum(axis=1)))
        pad = 16 * UNIT_ROUNDOFF["f64"] * (x_max + float(tree.reach.max()))
        pi, node = np.arange(len(pc)), np.zeros(len(pc), dtype=np.int64)
        pairs_p, pairs_b = [], []
        while len(pi):
            meets = np.all((seg_lo[pi] <= tree.hi[node] + pad) & (seg_hi[pi] >= tree.lo[node] - pad), axis=1)
            pi, node = pi[meets], node[meets]
            count = tree.count[node]
            leaf = count > 0
            rep = count[leaf]
            pairs_p.append(np.repeat(pi[leaf], rep))
            starts = np.repeat(tree.first[node[leaf]], rep)
            pairs_b.append(starts + np.arange(rep.sum()) - np.repeat(np.cumsum(rep) - rep, rep))
            inner = node[~leaf]
            pi = np.concatenate([pi[~leaf], pi[~leaf]])
            node = np.concatenate([inner + 1, tree.right[inner]])
        pp, bb = np.concatenate(pairs_p), np.concatenate(pairs_b)
        crossed = _crosses(pc[pp], qc[pp], center[order[bb]], radius[order[bb]]) & (ic[pp] != shape_of[bb])
        out[a : a + len(pc)] |= np.bincount(pp[crossed], minlength=len(pc)) > 0
    return out


def offset_warnings(scene: Scene, rules: Rules, res: RenderResult, precision: str = "f64") -> list[str]:
    """One line per offset hazard of this render (module docstring), with the number of pixels affected.
    ``res``: a render of the scene with its geometry buffers (the primary hits); none for the error-bound
    offset, which is the hit point's error bound itself."""
    if rules.offset == "error-bound" or res.hit is None or not res.hit.any():
        return []
    fx = effects(scene, rules)
    if not (fx.shadows or fx.reflection):  # no secondary rays
        return []
    # The hits a chunk at a time: the same findings per pixel, in working memory that stays in the caches
    # and is reused chunk after chunk (fresh memory costs a page fault per 4 KiB, slow on a VM).
    hits = np.flatnonzero(res.hit.reshape(-1))
    balls = _Balls.of(scene)
    made = _reflecting(scene, rules)
    below = jumped = 0
    worst = -math.inf
    for a in range(0, len(hits), HAZARD_CHUNK):
        g = _secondary(scene, rules, res, hits[a : a + HAZARD_CHUNK], rules.offset_along == "ray", made)
        j = _judge(scene, rules, g, precision, balls)
        below += int(j["below"].sum())
        jumped += int(j["jumped"].sum())
        if j["below"].any():
            worst = max(worst, float(j["rounding"][j["below"]].max()))
    off, lines = float(rules.offset), []
    name = "float32" if precision == "f32" else "float64"
    along = "along the new ray" if rules.offset_along == "ray" else "along the normal"
    if below:
        lines.append(
            f"offset {off:g} ({along}) is below the hit point's {name} rounding (up to {worst:.3g}) on "
            f"{below} pixel(s): their shadow or reflection rays may start behind the surface "
            '(acne); the scene\'s scale, not its content, then decides the image (offset = "error-bound" does not)'
        )
    if jumped:
        lines.append(
            f"offset {off:g} ({along}) jumps over another shape's surface on {jumped} pixel(s) "
            "(a near contact closer than the offset): their shadow or reflection rays start beyond it and miss it"
        )
    return lines


def offset_at(scene: Scene, rules: Rules, p, n, sid: int, shadow=None, reflection=None, precision="f64") -> dict:
    """The offset hazards of one hit point (for minirt probe): the offset, the point's rounding, whether
    the offset is below it, and the shapes whose surface the secondary rays' offset jumps."""
    if rules.offset == "error-bound":
        return {"offset": "error-bound", "note": "secondary rays start the hit point's error bound away"}
    g = {"p": np.asarray([p], dtype=np.float64), "n": np.asarray([n], dtype=np.float64), "id": np.array([sid])}
    if shadow is not None:
        g["shadow"] = np.asarray([shadow], dtype=np.float64)
    if reflection is not None:
        g["reflection"] = np.asarray([reflection], dtype=np.float64)
        g["reflects"] = np.array([True])
    j = _judge(scene, rules, g, precision)
    q_jumps = []
    off = float(rules.offset)
    for kind in ("shadow", "reflection"):
        if kind in g:
            v = g[kind] if rules.offset_along == "ray" else g["n"]
            q = g["p"] + off * v
            for k, shape in enumerate(scene.shapes):
                if k != sid and np.sign(_surface(shape, g["p"]))[0] != np.sign(_surface(shape, q))[0]:
                    q_jumps.append({"ray": kind, "shape": k, "gap": float(abs(_surface(shape, g["p"])[0]))})
    return {
        "offset": off,
        "along": rules.offset_along,
        "rounding": float(j["rounding"][0]),
        "below_rounding": bool(j["below"][0]),
        "jumps": q_jumps,
    }


@np.errstate(over="ignore")  # a value past float32's range is inf there: the line below says so
def float32_warnings(scene: Scene, who: str = "float32") -> list[str]:
    """One line per scene key whose value float32 cannot hold to the scene's detail (module docstring)."""
    w, h = scene.camera.width, scene.camera.height
    radii = [s.radius for s in scene.shapes if isinstance(s, Ball)]
    detail = min([*radii, scene.camera.distance, 1.0 / max(w, h)])
    limit = DETAIL_FRACTION * detail
    values: list[tuple[str, float]] = [("camera.distance", scene.camera.distance)]
    values += [(f"light.position[{i}]", c) for i, c in enumerate(scene.light.position)]
    for k, s in enumerate(scene.shapes):
        if isinstance(s, Ball):
            values += [(f"shapes[{k}].center[{i}]", c) for i, c in enumerate(s.center)]
            values.append((f"shapes[{k}].radius", s.radius))
        else:
            values.append((f"shapes[{k}].distance", s.distance))
    lines = []
    for key, v in values:
        moved = abs(float(np.float32(v)) - v) if math.isfinite(float(np.float32(v))) else math.inf
        if moved > limit:
            lines.append(
                f"{key} = {v!r} is {float(np.float32(v))!r} in {who} (moved by {moved:.3g}, more than 1/256 of the "
                f"scene's detail {detail:.3g}: its smallest radius, camera distance or pixel pitch)"
            )
    return lines


def scene_warnings(
    scene: Scene,
    rules: Rules,
    reference: RenderResult | None = None,
    precision: str = "f64",
    float32_by: Sequence[str] = (),
) -> list[str]:
    """The warning lines of a scene: for float32 tracers (``float32_by``, their names) its coordinates, then its
    offset hazards (on ``reference``'s primary hits, else on a reference render of the scene, reduced to
    HAZARD_PREVIEW_PIXELS when larger; none when that render cannot be made: it said why itself)."""
    from minirt.reference import tracer  # deferred: the tracer imports Dr.Jit, needed only without ``reference``

    lines = colour_warnings(scene)
    lines += float32_warnings(scene, "float32 (" + ", ".join(float32_by) + ")") if float32_by else []
    if rules.offset == "error-bound":
        return lines
    note = ""
    if reference is None or not reference.ok or reference.hit is None:
        w, h = scene.camera.width, scene.camera.height
        k = math.sqrt(HAZARD_PREVIEW_PIXELS / (w * h))
        if k < 1:
            scene = scene.with_overrides(width=max(1, int(w * k)), height=max(1, int(h * k)))
            note = f" (counted on a {scene.camera.width}x{scene.camera.height} render of the scene)"
        try:
            reference = tracer.render(scene, rules, precision=precision)
        except MinirtError:  # the render itself reported why it cannot trace this scene
            return lines
    return lines + [line + note for line in offset_warnings(scene, rules, reference, precision)]
