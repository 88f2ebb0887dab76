"""How a ray finds its closest ball among thousands: the shape table and a bounding volume hierarchy.

The scene's shapes become arrays (``ShapeTable``) that kernels gather from, so a kernel's code depends on
the rules and effects, not on the scene's layout: a new scene of the same kind reuses the compiled
kernels, and compile time does not grow with the number of shapes. Balls are grouped in a BVH (built
here in NumPy, traversed in a Dr.Jit loop with a small per-ray stack); planes, being unbounded, are tested
one after the other in a loop of their own.

**The same answers as testing every shape.** Every ball a ray reaches is tested with the very function the
brute-force path uses (``minirt.reference.shapes.ball_t``), on the same inputs, so its t carries the same bits; ties
keep the lower shape id whatever the visiting order (``(t < t_best) | (t == t_best & id < id_best)``). The
tree only decides which balls are *not* tested, and it may skip a ball only if that ball's computed t
could not have won. That is where care is needed: a box test that is exact about the ball is not enough,
because the ball test rounds. Each node's box is therefore widened, per ray, by ``pad`` (derivation at
``_Pad``), a bound on how far a ball test's rounding can move a hit: its hit/miss decision (the distance
of the ray from the centre, |g|, errs by ~12 u |f|, f = o - C) and its t (which near a tangent ray errs
by up to the square root of the discriminant's error, ~sqrt(2 r δ)). The slab test itself follows
pbrt-v4's ``Bounds3::IntersectP``: t_far grows by 1 + 2 gamma(3), so the box test's own rounding never
rejects a ray that reaches the exact box. Tests: bit-identical buffers against the brute-force path
(tests/reference/test_accel.py), on the bundled scenes, random scenes and tangent rays.

Build: median split of the centroids along their widest axis down to leaves of at most ``LEAF`` balls,
flattened depth first (left child = next node). Traversal visits one node per loop iteration: a leaf's
balls are tested; at an interior node both children's (widened) boxes are slab-tested, the ray descends
into the one it enters first and pushes the other with its entry t, and a popped node whose entry t is
beyond the best t found since is dropped without a box test. Measured against testing each node's own box
when it is popped (and ordering by the sign of the direction): 13-20 % less trace time, 512², 16 to
100,000 balls, same buffers bit for bit.

The kernel code below takes ``v``, the scene's values as the kernel reads them (minirt.reference.values:
the ``Tabled`` representation, which calls it): its float types ``v.T`` and the rules the ball and plane
tests read.
"""

from __future__ import annotations

import hashlib
import math
import threading
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

import drjit as dr
import numpy as np

from minirt.jit.arrays import aligned
from minirt.model.scene import Ball, Plane, Scene
from minirt.reference import shapes

LEAF = 1  # balls per leaf at most. Every loop iteration pays for LEAF masked ball tests, leaf or not: 1 is
# fastest (measured, 384², 32 to 16,384 balls: leaves of 2 cost 5-25 % more time, of 4 20-45 %)
STACK = 64  # per-ray stack entries; a median split of 10^7 balls is 22 levels deep


def gamma(n: int, u: float) -> float:
    """pbrt's gamma(n) = n u / (1 - n u): bound on the relative error of n chained roundings."""
    return n * u / (1 - n * u)


@dataclass
class Tree:
    """The flattened BVH (NumPy, float64 boxes): node k's box is lo[k]..hi[k]; a leaf (count > 0) holds
    balls first..first+count of the table's ball order; an interior node's children are k + 1 and
    right[k], split along axis[k]. reach[k] = max(|C| + r) and rmax[k] = max(r) over its balls (for the pad)."""

    lo: np.ndarray
    hi: np.ndarray
    first: np.ndarray
    count: np.ndarray
    right: np.ndarray
    axis: np.ndarray
    reach: np.ndarray
    rmax: np.ndarray
    depth: int

    @property
    def nodes(self) -> int:
        return len(self.count)


_BUILT: OrderedDict[bytes, tuple[Tree, np.ndarray]] = OrderedDict()  # the last few trees built, by their balls
_BUILT_KEEP = 4
_BUILT_LOCK = threading.Lock()


def build(center: np.ndarray, radius: np.ndarray) -> tuple[Tree, np.ndarray]:
    """A BVH over balls (center (n, 3), radius (n,)): the tree and the ball order it indexes (``_build``),
    read-only. The last few are kept by their balls' bytes: a check builds one scene's tree for every
    render and margin of it (the rule diagnosis' 136 variant renders of a 10,000-ball scene: 19 s of its
    check), and the same balls give the same tree."""
    c = np.ascontiguousarray(center, dtype=np.float64)
    r = np.ascontiguousarray(radius, dtype=np.float64)
    key = hashlib.blake2b(repr((c.shape, r.shape)).encode() + c.tobytes() + r.tobytes(), digest_size=20).digest()
    with _BUILT_LOCK:
        got = _BUILT.get(key)
        if got is not None:
            _BUILT.move_to_end(key)
            return got
    tree, order = _build(c, r)
    for a in (*vars(tree).values(), order):
        if isinstance(a, np.ndarray):
            a.setflags(write=False)
    with _BUILT_LOCK:
        _BUILT[key] = (tree, order)
        while len(_BUILT) > _BUILT_KEEP:
            _BUILT.popitem(last=False)
    return tree, order


def _build(center: np.ndarray, radius: np.ndarray) -> tuple[Tree, np.ndarray]:
    """The BVH over balls (center (n, 3), radius (n,)): the tree and the ball order it indexes.

    Node by node the definition is: a node holds balls order[start:end]; more than LEAF of them are split
    at the middle after a stable sort of their centres along the axis where the centres spread most,
    left half first; nodes are numbered depth first, left child next. It is built here a level at a
    time, every node of a level at once in NumPy (one stable sort keyed by (node, coordinate) per level):
    100,000 balls 3.2 -> 0.5 s, the same tree bit for bit as building node by node (tests/reference/test_accel.py)."""
    n = len(radius)
    order = np.arange(n)
    if not n:
        z = np.zeros((0, 3))
        e = np.zeros(0, dtype=np.int64)
        return Tree(z, z, e, e, e, e, np.zeros(0), np.zeros(0), 0), order
    lo_b, hi_b = center - radius[:, None], center + radius[:, None]
    reach_b = np.linalg.norm(center, axis=1) + radius
    sizes: dict[int, int] = {}

    def nodes_of(m: int) -> int:  # the nodes of a subtree over m balls
        if m not in sizes:
            sizes[m] = 1 if m <= LEAF else 1 + nodes_of(m // 2) + nodes_of(m - m // 2)
        return sizes[m]

    total = nodes_of(n)
    lo, hi = np.empty((total, 3)), np.empty((total, 3))
    first, count = np.empty(total, dtype=np.int64), np.zeros(total, dtype=np.int64)
    right, axis = np.full(total, -1, dtype=np.int64), np.zeros(total, dtype=np.int64)
    reach, rmax = np.empty(total), np.empty(total)
    # The nodes of one level: their index, first ball and ball count (segments of order, ascending).
    k, start, m = np.zeros(1, dtype=np.int64), np.zeros(1, dtype=np.int64), np.array([n], dtype=np.int64)
    depth = 0
    while len(k):
        depth += 1
        at = np.concatenate([[0], np.cumsum(m)[:-1]])  # each node's first entry in idx
        pos = np.arange(int(m.sum())) + np.repeat(start - at, m)  # the level's slots of order
        idx = order[pos]
        seg = np.repeat(np.arange(len(k)), m)  # each ball's node in this level
        lo[k], hi[k] = np.minimum.reduceat(lo_b[idx], at), np.maximum.reduceat(hi_b[idx], at)
        reach[k], rmax[k] = np.maximum.reduceat(reach_b[idx], at), np.maximum.reduceat(radius[idx], at)
        first[k] = start
        leaf = m <= LEAF
        count[k[leaf]] = m[leaf]
        c = center[idx]
        ax = np.argmax(np.maximum.reduceat(c, at) - np.minimum.reduceat(c, at), axis=1)
        axis[k[~leaf]] = ax[~leaf]
        split = ~leaf[seg]
        # A stable sort of each splitting node's balls by their coordinate along its axis: the same tree
        # for the same scene, on every machine.
        coord = c[np.arange(len(idx)), ax[seg]]
        part = np.lexsort((coord[split], seg[split]))
        order[pos[split]] = idx[split][part]
        inner, mid = k[~leaf], m[~leaf] // 2
        right[inner] = inner + 1 + np.array([nodes_of(int(x)) for x in mid], dtype=np.int64)
        k = np.stack([inner + 1, right[inner]], axis=1).reshape(-1)
        start = np.stack([start[~leaf], start[~leaf] + mid], axis=1).reshape(-1)
        m = np.stack([mid, m[~leaf] - mid], axis=1).reshape(-1)
    tree = Tree(lo=lo, hi=hi, first=first, count=count, right=right, axis=axis, reach=reach, rmax=rmax, depth=depth)
    if depth > STACK:
        raise ValueError(f"BVH depth {depth} exceeds the traversal stack ({STACK})")
    return tree, order


def _outward(x: np.ndarray, dtype, down: bool) -> np.ndarray:
    """x rounded to dtype away from the box's inside (lo down, hi up): the stored box contains the exact one."""
    y = x.astype(dtype)
    if down:
        return np.where(y.astype(np.float64) > x, np.nextafter(y, dtype(-np.inf)), y)
    return np.where(y.astype(np.float64) < x, np.nextafter(y, dtype(np.inf)), y)


class ShapeTable:
    """A scene's shapes as Dr.Jit arrays of the tracer's precision (``T``: minirt.reference.values.Types).

    Per shape id (gathered by the shading code): the four material colours, and for the normal and
    the error bound whether it is a ball, its centre or plane normal, its radius (1 for planes) and the
    error-bound factor and length (gamma(6) and r for balls, gamma(4) and |a| for planes). Balls again in
    BVH order for traversal; planes in id order.
    """

    def __init__(self, scene: Scene, T: Any, with_tree: bool = True):
        self.T = T
        I3, F = T.Array3, self._float
        shapes = scene.shapes
        dt = T.np_dtype
        balls = [(k, s) for k, s in enumerate(shapes) if isinstance(s, Ball)]
        planes = [(k, s) for k, s in enumerate(shapes) if isinstance(s, Plane)]
        self.n_balls, self.n_planes = len(balls), len(planes)

        def a3(rows: list) -> Any:
            a = np.asarray(rows, dtype=np.float64).reshape(-1, 3).astype(dt)
            return I3(*(F(a[:, i]) for i in range(3)))

        u = T.u
        self.material = {
            name: a3([getattr(s.material, name) for s in shapes])
            for name in ("ambient", "diffuse", "specular", "reflection")
        }
        self.is_ball = T.Bool(aligned([isinstance(s, Ball) for s in shapes], bool))
        self.center = a3([s.center if isinstance(s, Ball) else (0.0, 0.0, 0.0) for s in shapes])
        self.plane_normal = a3([s.normal if isinstance(s, Plane) else (0.0, 0.0, 0.0) for s in shapes])
        radius = np.array([s.radius if isinstance(s, Ball) else 1.0 for s in shapes], dtype=dt)
        self.radius = F(radius)
        self.inv_radius = F(dt(1.0) / radius)  # the kernel's 1.0 / r, element by element: the same bits
        self.err_factor = F([gamma(6, u) if isinstance(s, Ball) else gamma(4, u) for s in shapes])
        self.err_length = F([s.radius if isinstance(s, Ball) else abs(s.distance) for s in shapes])
        # Planes, in id order.
        self.p_id = T.Int(aligned([k for k, _ in planes], np.int32))
        self.p_normal = a3([s.normal for _, s in planes])
        self.p_point = a3([s.point for _, s in planes])
        # Balls, in BVH order.
        center = np.asarray([s.center for _, s in balls], dtype=np.float64).reshape(-1, 3)
        radius = np.asarray([s.radius for _, s in balls], dtype=np.float64)
        ids = np.array([k for k, _ in balls], dtype=np.int32)
        self.tree = None
        if with_tree and balls:
            tree, order = build(center, radius)
            center, radius, ids = center[order], radius[order], ids[order]
            self.tree = tree
            self._tree_arrays(tree)
        self.b_id = T.Int(aligned(ids, np.int32))
        # (centre, radius) packets: one 4-wide load per ray (``_ball_at``)
        self.b_sphere = F(np.column_stack([center.astype(dt), radius.astype(dt)]).reshape(-1))
        # The scene's scalars, read from arrays rather than compiled in. (One array per type: Dr.Jit's
        # width-1 opaque values are packed so that their alignment, which is part of the kernel's code,
        # varies from run to run, and a kernel would be compiled again for the same scene.)
        self._scalars: dict[str, int] = {}
        vals: list[float] = []
        for name, v in (
            ("light", scene.light.position),
            ("light_color", scene.light.color),
            ("background", scene.background),
        ):
            self._scalars[name] = len(vals)
            vals += [float(c) for c in v]
        self._f = F(vals)
        self._f64 = dr.llvm.Float64(aligned([-scene.camera.distance], np.float64))
        self._u = T.UInt(aligned([self.n_planes, self.n_balls], np.uint32))

    def vec(self, name: str) -> Any:
        """A scene 3-vector (light, light_color, background) read at run time."""
        k = self._scalars[name]
        return self.T.Array3(*(dr.gather(self.T.Float, self._f, self.T.UInt(k + i)) for i in range(3)))

    def camera_z(self, F: Any) -> Any:
        """-distance, the camera's z, in float type F (rounded from float64 as a literal would be)."""
        return F(dr.gather(dr.llvm.Float64, self._f64, self.T.UInt(0)))

    def count(self, what: str) -> Any:
        return dr.gather(self.T.UInt, self._u, self.T.UInt(("planes", "balls").index(what)))

    def _float(self, a: Any) -> Any:
        """A Dr.Jit float array of the tracer's precision from host values, at a 64-byte boundary (every
        array the table hands over is: see minirt.jit.arrays)."""
        return self.T.Float(aligned(a, self.T.np_dtype))

    def _tree_arrays(self, tree: Tree) -> None:
        T = self.T
        dt = T.np_dtype
        F = self._float

        def U(a) -> Any:
            return T.UInt(aligned(a, np.uint32))

        lo, hi = _outward(tree.lo, dt, True), _outward(tree.hi, dt, False)
        pad = _Pad(T.u)
        # A node is two packets of four floats, (lo, pad b) and (hi, pad c), and one of four integers,
        # (count, first, right, axis): its box is two 4-wide loads per ray from one cache line, its links
        # one, where an array per field made eleven gathers from eleven places (trace of 100,000 balls at
        # 512^2: ~960 -> ~720 ms, the same bits).
        box = np.empty((tree.nodes, 8), dtype=dt)
        box[:, 0:3], box[:, 3] = lo, np.asarray(pad.b(tree.rmax)).astype(dt)
        box[:, 4:7], box[:, 7] = hi, np.asarray(pad.c(tree.rmax, tree.reach)).astype(dt)
        self.n_box = F(box.reshape(-1))
        meta = np.stack([tree.count, tree.first, np.maximum(tree.right, 0), tree.axis], axis=1)
        self.n_meta = U(meta.astype(np.uint32).reshape(-1))
        self.pad_a = pad.a


class _Pad:
    """How far a ball test's rounding can move a hit, as a widening of a node's box for one ray:
    pad = a |o| + b sqrt|o| + c, with b and c per node (r_max, S = max(|C| + r) of its balls).

    Derivation (u the unit round-off, f = o - C, |f| <= |o| + S):
    - The hit decision is the sign of D = r^2 - |g|^2, g = f - (f·d) d (one fused multiply-add of the
      exact r^2). f, f·d, (f·d) d and the difference round by ~8 u |f|, the squared length by 1.5 u |g|
      more in |g| terms, and |g| <= |f|: |g| errs by δ <= 12 u |f| (generous). A ball the ball test calls
      hit has its centre within r + δ of the ray, so it lies in the box widened by δ.
    - Its t: t = -b ± sqrt(D). D errs by <= 2 (r + δ) δ + 3 u r^2, so sqrt(D) by
      <= sqrt(2.2 r δ) (the square root of a perturbation, the tangent ray's worst case; generous for
      u r^2 too), b by <= 3 u |f|, and the final roundings by u t with t <= |f| + r. The Vieta form c / q
      of the near root is no worse.
    - The box may be skipped when its entry t_near exceeds the best t so far. A box widened by w contains
      every point within w of its balls, so along the unit ray its entry is at least w before the exact
      hit; it can wrongly be skipped only if a computed t undershoots its exact t by more than w.
    So w = 2 (sqrt(2.2 r δ) + 4 u (|f| + r) + δ) suffices, doubled for margin, with δ = 12 u (|o| + S):
    sqrt(2.2 r 12 u (|o| + S)) <= sqrt(26.4 u r) (sqrt|o| + sqrt S), and 16 u (|o| + S + r) <= 32 u (|o| + S).
    """

    def __init__(self, u: float):
        self.u = u
        self.a = 2 * (12 * u + 32 * u)

    def b(self, rmax: np.ndarray) -> np.ndarray:
        return 2 * np.sqrt(26.4 * self.u * rmax)

    def c(self, rmax: np.ndarray, reach: np.ndarray) -> np.ndarray:
        return self.b(rmax) * np.sqrt(reach) + self.a * reach


def _array4(T: Any) -> Any:
    """The 4-vector of T's float type: what a packet gather loads (one 4-wide load per ray)."""
    return dr.llvm.Array4f64 if T.np_dtype == np.float64 else dr.llvm.Array4f


def _ball_at(T: Any, tab: ShapeTable, k: Any, active: Any = True) -> tuple[Any, Any]:
    """Centre and radius of the table's ball k (BVH order), from its packet."""
    ball = dr.gather(_array4(T), tab.b_sphere, k, active)
    return T.Array3(ball[0], ball[1], ball[2]), ball[3]


def _inverse(T: Any, d: Any) -> Any:
    """1 / d per component, a zero component replaced by a tiny one of its sign: its slab is then a
    huge finite interval (never 0 * inf = NaN). Harmless: boxes are widened beyond the exact balls."""
    tiny = 1e-300 if T.np_dtype == np.float64 else 1e-30
    return T.Array3(*(1 / dr.select(d[i] == 0, dr.copysign(T.Float(tiny), d[i]), d[i]) for i in range(3)))


def _slab(T: Any, tab: ShapeTable, node: Any, o: Any, inv: Any, pa: Any, ps: Any, active: Any) -> tuple[Any, Any]:
    """Entry and exit t of the ray with node's box widened by its pad, pa + ps b + c (``_Pad``; pa = a |o|,
    ps = sqrt|o|): pbrt's slab test, exit grown by 1 + 2 gamma(3)."""
    A4 = _array4(T)
    b0 = dr.gather(A4, tab.n_box, 2 * node, active)  # lo, b
    b1 = dr.gather(A4, tab.n_box, 2 * node + 1, active)  # hi, c
    pad = pa + ps * b0[3] + b1[3]
    lo = T.Array3(b0[0], b0[1], b0[2]) - pad
    hi = T.Array3(b1[0], b1[1], b1[2]) + pad
    t0, t1 = (lo - o) * inv, (hi - o) * inv
    near, far = dr.minimum(t0, t1), dr.maximum(t0, t1)
    t_near = dr.maximum(dr.maximum(near[0], near[1]), near[2])
    t_far = dr.minimum(dr.minimum(far[0], far[1]), far[2]) * (1 + 2 * gamma(3, T.u))
    return t_near, t_far


def traverse(v: Any, tab: ShapeTable, o: Any, d: Any, t_best: Any, id_best: Any, blocks=None) -> tuple[Any, Any]:
    """Closest hit among the table's balls, merged into (t_best, id_best) by the lower-id tie rule.

    With ``blocks`` (a function (center, radius) -> Bool for the shadow ray o, d) the traversal answers
    "does any ball block?" instead, and a ray stops at its first blocker: then the result is
    (blocked, None) and t_best is the distance beyond which boxes are skipped (inf for shadow_range "any").
    """
    T = v.T
    U, Int, F = T.UInt, T.Int, T.Float
    n = dr.width(d)
    inv = _inverse(T, d)
    lo = dr.norm(o)
    pa, ps = tab.pad_a * lo, dr.sqrt(lo)  # the per-ray parts of _Pad: a |o| and sqrt|o|
    grow = 1 + 2 * gamma(3, T.u)
    stack = dr.alloc_local(U, STACK)
    tstack = dr.alloc_local(F, STACK)

    def box(node, t_best, on):
        t_near, t_far = _slab(T, tab, node, o, inv, pa, ps, on)
        return on & (t_near <= t_far) & (t_far >= 0) & (t_near <= t_best * grow), t_near

    node = dr.zeros(U, n)
    root, tn = box(node, t_best, dr.full(T.Bool, True, n))
    sp = dr.zeros(U, n)
    blocked = dr.full(T.Bool, False, n)

    def cond(node, tn, sp, active, t_best, id_best, blocked, stack, tstack):
        return active

    def body(node, tn, sp, active, t_best, id_best, blocked, stack, tstack):
        live = active & (tn <= t_best * grow)
        meta = dr.gather(dr.llvm.Array4u, tab.n_meta, node, live)  # count, first, right, axis
        count, first = meta[0], meta[1]
        leaf = live & (count > 0)
        for j in range(LEAF):
            on = leaf & (j < count)
            k = first + j
            c, r = _ball_at(T, tab, k, on)
            if blocks is None:
                sid = dr.gather(Int, tab.b_id, k, on)
                tk = shapes.ball_t(v, c, r, o, d, gate=True)  # a packet all of whose rays pass the ball skips its roots
                closer = on & ((tk < t_best) | ((tk == t_best) & (sid < id_best)))
                t_best = dr.select(closer, tk, t_best)
                id_best = dr.select(closer, sid, id_best)
            else:
                blocked |= on & blocks(c, r)
        inner = live & (count == 0)
        kids = (node + 1, meta[2])
        (e0, t0), (e1, t1) = box(kids[0], t_best, inner), box(kids[1], t_best, inner)
        both = e0 & e1
        go_left = e0 & (~e1 | (t0 <= t1))
        stack.write(dr.select(go_left, kids[1], kids[0]), sp, both)
        tstack.write(dr.select(go_left, t1, t0), sp, both)
        sp = dr.select(both, sp + 1, sp)
        down = e0 | e1
        more = active & ~down & (sp > 0)
        sp = dr.select(more, sp - 1, sp)
        node = dr.select(down, dr.select(go_left, kids[0], kids[1]), stack.read(sp, more))
        tn = dr.select(down, dr.select(go_left, t0, t1), tstack.read(sp, more))
        active = down | more
        if blocks is not None:
            active &= ~blocked
        return node, tn, sp, active, t_best, id_best, blocked, stack, tstack

    _, _, _, _, t_best, id_best, blocked, _, _ = dr.while_loop(
        (node, tn, sp, root, t_best, id_best, blocked, stack, tstack), cond, body, label="bvh"
    )
    if blocks is not None:
        return blocked, None
    return t_best, id_best


def planes_closest(v: Any, tab: ShapeTable, o: Any, d: Any, t_best: Any, id_best: Any) -> tuple[Any, Any]:
    """Every plane in a loop (planes are unbounded: no tree), merged by the lower-id tie rule."""
    T = v.T
    n = dr.width(d)
    k = dr.zeros(T.UInt, n)
    count = tab.count("planes")

    def cond(k, t_best, id_best):
        return k < count

    def body(k, t_best, id_best):
        nrm = dr.gather(T.Array3, tab.p_normal, k)
        q = dr.gather(T.Array3, tab.p_point, k)
        sid = dr.gather(T.Int, tab.p_id, k)
        tk = shapes.plane_t(v, nrm, q, o, d)
        closer = (tk < t_best) | ((tk == t_best) & (sid < id_best))
        return k + 1, dr.select(closer, tk, t_best), dr.select(closer, sid, id_best)

    _, t_best, id_best = dr.while_loop((k, t_best, id_best), cond, body, label="planes")
    return t_best, id_best


def planes_block(v: Any, tab: ShapeTable, o: Any, s: Any, light_dist: Any, to_light: Any) -> Any:
    """Does any plane block the shadow ray (within light_dist under shadow_range "to-light")? ``to_light``:
    a bool, or a batch's mask (each ray its candidate's)."""
    T = v.T
    n = dr.width(s)
    k = dr.zeros(T.UInt, n)
    count = tab.count("planes")
    blocked = dr.full(T.Bool, False, n)

    def cond(k, blocked):
        return (k < count) & ~blocked

    def body(k, blocked):
        tk = shapes.plane_t(v, dr.gather(T.Array3, tab.p_normal, k), dr.gather(T.Array3, tab.p_point, k), o, s)
        if isinstance(to_light, bool):
            return k + 1, blocked | ((tk < light_dist) if to_light else (tk < math.inf))
        return k + 1, blocked | dr.select(to_light, tk < light_dist, tk < math.inf)

    _, blocked = dr.while_loop((k, blocked), cond, body, label="plane shadows")
    return blocked


def balls_each(v: Any, tab: ShapeTable, o: Any, fn, acc: Any, stop=None) -> Any:
    """acc = fn(acc, center, radius, id) over every ball in a loop (for per-ray quantities no tree can
    prune, such as the distance from the nearest silhouette, and for the brute-force "loop" path).
    ``stop(acc)``: lanes where it holds leave the loop early."""
    T = v.T
    n = dr.width(o)
    k = dr.zeros(T.UInt, n)
    count = tab.count("balls")

    def cond(k, acc):
        go = k < count
        return go if stop is None else go & ~stop(acc)

    def body(k, acc):
        c, r = _ball_at(T, tab, k)
        return k + 1, fn(acc, c, r, dr.gather(T.Int, tab.b_id, k))

    _, acc = dr.while_loop((k, acc), cond, body, label="balls")
    return acc


def balls_closest_loop(v: Any, tab: ShapeTable, o: Any, d: Any, t_best: Any, id_best: Any) -> tuple[Any, Any]:
    """Every ball in a loop, merged by the lower-id tie rule: the brute force the tree must equal."""

    def merge(acc, c, r, sid):
        t_best, id_best = acc
        tk = shapes.ball_t(v, c, r, o, d)
        closer = (tk < t_best) | ((tk == t_best) & (sid < id_best))
        return dr.select(closer, tk, t_best), dr.select(closer, sid, id_best)

    return balls_each(v, tab, o, merge, (t_best, id_best))
