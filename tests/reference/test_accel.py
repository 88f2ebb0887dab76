"""The shape table and the BVH (minirt.reference.accel) give the same bits as testing every shape.

Three ways to find a ray's shapes (Tracer ``accel``): "unrolled" (every shape compiled into the kernel),
"loop" (every ball gathered from the table in a loop) and "bvh" (the tree). Every buffer of a render,
diagnostics included, must be bit-identical between them: the tree may only skip balls whose computed t
could not win, and the tie rule keeps the lower id whatever the visiting order. Unrolled kernels grow with
the scene, so big scenes compare the tree with the loop, which shares no traversal code with it.
"""

from __future__ import annotations

import math
import re

import drjit as dr
import numpy as np
import pytest
from support.plain import render_plain

from minirt.campaign.generate import balls_scene
from minirt.model import camera
from minirt.model.rules import PROFILES, resolve
from minirt.model.scene import load_scene, parse_scene
from minirt.reference import accel
from minirt.reference.tracer import Tracer

FIELDS = ("color", "hit", "shape_id", "t", "position", "normal")


def _differs(a, b) -> list[str]:
    bad = [f for f in FIELDS if getattr(a, f).tobytes() != getattr(b, f).tobytes()]
    bad += ["term." + k for k in a.terms if a.terms[k].tobytes() != b.terms[k].tobytes()]
    bad += ["aux." + k for k in a.aux if a.aux[k].tobytes() != b.aux[k].tobytes()]
    return bad


def _pair(scene, rules, precision, x: str, y: str) -> list[str]:
    a = Tracer(scene, rules, precision, accel=x).render(diagnostics=True)
    b = Tracer(scene, rules, precision, accel=y).render(diagnostics=True)
    return _differs(a, b)


@pytest.mark.parametrize("precision", ["f64", "f32"])
@pytest.mark.parametrize("profile", list(PROFILES))
def test_bundled_scenes_same_bits(scene_path, profile, precision):
    scene = load_scene(scene_path).with_overrides(width=40, height=40, samples=1)
    rules = resolve(scene, profile)
    assert _pair(scene, rules, precision, "unrolled", "bvh") == []
    assert _pair(scene, rules, precision, "unrolled", "loop") == []


@pytest.mark.parametrize("precision", ["f64", "f32"])
@pytest.mark.parametrize("profile", list(PROFILES))
@pytest.mark.parametrize("n", [1, 2, 5, 13, 40])
def test_random_small_scenes_same_bits_as_unrolled(n, profile, precision):
    scene = parse_scene(balls_scene(n, seed=100 + n, width=48, height=48))
    assert _pair(scene, resolve(scene, profile), precision, "unrolled", "bvh") == []


@pytest.mark.slow
@pytest.mark.parametrize("precision", ["f64", "f32"])
@pytest.mark.parametrize("profile", list(PROFILES))
@pytest.mark.parametrize("n", [300, 2000])
def test_random_large_scenes_same_bits_as_loop(n, profile, precision):
    scene = parse_scene(balls_scene(n, seed=n, width=64, height=64))
    assert _pair(scene, resolve(scene, profile), precision, "loop", "bvh") == []


@pytest.mark.parametrize("precision", ["f64", "f32"])
def test_tangent_and_grazing_rays(precision):
    """Rays built to touch a ball's silhouette (|g| = r, and 1e-12 .. 1e-3 relative inside and outside),
    from near and far, among a crowd of touching balls: where a rounding decides the hit and the near
    root is worst conditioned. The tree's ids and t equal the loop's, bit for bit."""
    rng = np.random.default_rng(5)
    n = 400
    scene = parse_scene(balls_scene(n, seed=7, floor=False))
    tr_loop = Tracer(scene, PROFILES["exercise"], precision, accel="loop")
    tr_bvh = Tracer(scene, PROFILES["exercise"], precision, accel="bvh")
    balls = scene.shapes
    rays_o, rays_d = [], []
    for _ in range(20000):
        b = balls[rng.integers(n)]
        c, r = np.array(b.center), b.radius
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        side = np.cross(axis, rng.normal(size=3))
        side /= np.linalg.norm(side)
        rel = rng.choice([0.0, 1e-12, -1e-12, 1e-9, -1e-9, 1e-6, -1e-6, 1e-3, -1e-3])
        touch = c + side * r * (1 + rel)
        dist = 10.0 ** rng.uniform(-1, 3)
        o = touch - axis * dist
        rays_o.append(o)
        rays_d.append(axis)
    o = np.array(rays_o)
    d = np.array(rays_d)
    d /= np.linalg.norm(d, axis=1)[:, None]
    out = []
    for tr in (tr_loop, tr_bvh):
        ids, t = tr.closest(tr.load(o), tr.load(d))
        out.append((np.asarray(ids), np.asarray(t)))
    assert np.array_equal(out[0][0], out[1][0])
    assert out[0][1].tobytes() == out[1][1].tobytes()
    assert (out[0][0] >= 0).mean() > 0.3  # the rays do hit: the comparison is not vacuous


def test_ties_keep_the_lower_id():
    """Two identical balls (and a plane through nothing): every hit is a tie, won by the lower id in
    every path, however the tree orders them."""
    text = balls_scene(1, seed=1, floor=False)
    ball = text[text.index("[[shapes]]") :]
    scene = parse_scene(text + "\n" + ball + "\n" + ball)
    for a in ("unrolled", "loop", "bvh"):
        res = Tracer(scene, PROFILES["exercise"], accel=a).render()
        assert set(np.unique(res.shape_id)) <= {-1, 0}, a


def test_tree_is_a_tree():
    """Every ball in exactly one leaf; leaves hold at most LEAF balls; every box contains its balls."""
    rng = np.random.default_rng(3)
    center = rng.uniform(-10, 10, (1000, 3))
    radius = rng.uniform(0.1, 1.0, 1000)
    tree, order = accel.build(center, radius)
    assert sorted(order) == list(range(1000))
    leaves = tree.count > 0
    assert tree.count.max() <= accel.LEAF
    assert tree.count.sum() == 1000
    for k in np.flatnonzero(leaves):
        idx = order[tree.first[k] : tree.first[k] + tree.count[k]]
        assert (center[idx] - radius[idx, None] >= tree.lo[k]).all()
        assert (center[idx] + radius[idx, None] <= tree.hi[k]).all()
    assert tree.depth <= 11  # a median split: ceil(log2(1000 / LEAF)) + 1 levels


def _build_node_by_node(center, radius):
    """accel.build's definition, one node at a time: a node's balls are split at the middle after a stable
    sort along the axis where their centres spread most, nodes numbered depth first, left child next."""
    lo_b, hi_b = center - radius[:, None], center + radius[:, None]
    reach_b = np.linalg.norm(center, axis=1) + radius
    order = np.arange(len(radius))
    nodes, depth = [], 0
    todo = [(0, len(radius), -1, 1)]
    while todo:
        start, end, patch, level = todo.pop()
        depth = max(depth, level)
        idx = order[start:end]
        if patch >= 0:
            nodes[patch][4] = len(nodes)
        node = [lo_b[idx].min(axis=0), hi_b[idx].max(axis=0), start, 0, -1, 0, reach_b[idx].max(), radius[idx].max()]
        k = len(nodes)
        nodes.append(node)
        if end - start <= accel.LEAF:
            node[3] = end - start
            continue
        c = center[idx]
        node[5] = axis = int(np.argmax(c.max(axis=0) - c.min(axis=0)))
        mid = (end - start) // 2
        order[start:end] = idx[np.argsort(c[:, axis], kind="stable")]
        todo += [(start + mid, end, k, level + 1), (start, start + mid, -1, level + 1)]
    return [np.array(col) for col in zip(*nodes, strict=True)], depth, order


@pytest.mark.parametrize("n", [1, 2, 3, 5, 16, 17, 100, 1000, 4097])
@pytest.mark.parametrize("layout", ["random", "ties", "flat"])
def test_the_level_by_level_build_is_the_node_by_node_tree(n, layout):
    """accel.build builds a level at a time (every node of a level at once): the same tree, array by array,
    as building its definition node by node -- ties in the coordinates included (the stable sort)."""
    rng = np.random.default_rng(n)
    center = rng.uniform(-5, 5, (n, 3))
    if layout == "ties":
        center = np.round(center)
    elif layout == "flat":
        center[:, 1] = 0.0
    radius = rng.uniform(0.1, 1.0, n)
    tree, order = accel.build(center, radius)
    cols, depth, want = _build_node_by_node(center, radius)
    got = [tree.lo, tree.hi, tree.first, tree.count, tree.right, tree.axis, tree.reach, tree.rmax]
    assert all(np.array_equal(a, b) for a, b in zip(got, cols, strict=True))
    assert tree.depth == depth and np.array_equal(order, want)


def _kernel_code(scene) -> set[str]:
    """The code of every kernel a render runs, without the alignment annotations and the kernel's
    name (a hash of its text). Dr.Jit writes each input buffer's alignment into the code, and small
    buffers come from an allocator whose 128-byte alignment varies from run to run, so the same code
    can still be compiled twice; what must not vary with the layout is the code itself."""
    dr.kernel_history()  # clear
    Tracer(scene, PROFILES["exercise"]).render()
    out = set()
    for k in dr.kernel_history():
        if k.get("type") == dr.KernelType.JIT:
            ir = re.sub(r"align \d+", "align _", k["ir"].getvalue())
            out.add(re.sub(r"drjit_[0-9a-f]+", "drjit_", ir))
    return out


def test_kernels_do_not_depend_on_the_layout():
    """A second random scene of the same kind (other positions, light, camera, other count) runs the
    same kernels as the first: compile time does not grow with the scene."""
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        first = _kernel_code(parse_scene(balls_scene(500, seed=1, width=32, height=32)))
        second = _kernel_code(parse_scene(balls_scene(2000, seed=2, width=32, height=32)))
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    assert len(first) >= 1  # a render is one kernel (integrator.trace_fused): what matters is that it is captured
    assert second == first


@pytest.mark.slow
def test_against_the_plain_transcription_2000_balls():
    """The tree on a 2,000-ball scene against the recursive pure-Python transcription (tests/support/plain.py)."""
    size = 10
    scene = parse_scene(balls_scene(2000, seed=11, width=size, height=size))
    rules = PROFILES["exercise"]
    fast = Tracer(scene, rules, accel="bvh").render()
    o, d = camera.primary_rays(scene, rules)
    colors, fragile = render_plain(scene, rules, o, d)
    plain = np.array(colors).reshape(size, size, 3)
    fragile = np.array(fragile).reshape(size, size)
    diff = np.abs(fast.color - plain).max(axis=-1)
    assert fast.hit.mean() > 0.5
    assert not ((diff > 1e-9) & ~fragile).any()
    assert math.isfinite(float(diff.max()))


def test_a_tree_is_built_once_for_the_same_balls_and_kept_read_only():
    """accel.build keeps the last few trees by their balls' bytes: the same balls give the same (read-only)
    tree without building it again; other balls another tree."""
    rng = np.random.default_rng(11)
    center, radius = rng.uniform(-5, 5, (300, 3)), rng.uniform(0.1, 1.0, 300)
    tree, order = accel.build(center, radius)
    again, order2 = accel.build(center.copy(), radius.copy())
    assert again is tree and order2 is order
    assert not tree.lo.flags.writeable and not order.flags.writeable
    moved = center.copy()
    moved[0, 0] += 1e-12
    other, _ = accel.build(moved, radius)
    assert other is not tree and not np.array_equal(other.lo, tree.lo)
