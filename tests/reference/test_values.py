"""The scene's two representations (minirt.reference.values): one protocol, the same bits.

``Unrolled`` (constants compiled in or opaque, select chains) and ``Tabled`` (gathers from the shape table)
implement the same methods, and each gives the same values, bit for bit, for every shape id and for a
miss: that is what lets the tracer's code call them without asking which one it has. (The whole trace
through either is compared in tests/reference/test_accel.py.)"""

from __future__ import annotations

from dataclasses import replace

import drjit as dr
import numpy as np
import pytest
from support.scenes import ball, material, plane, scene_text

from minirt.model.rules import PROFILES
from minirt.model.scene import parse_scene
from minirt.reference.accel import ShapeTable
from minirt.reference.values import Tabled, Types, Unrolled, Values

SCENE = scene_text(
    ball((0.3, -0.2, 1.7), 0.7, "a"),
    plane((0.0, 1.0, 0.0), -1.25, "b"),
    ball((-1.1, 0.4, 3.1), 1.3, "b"),
    plane((0.0, 0.0, -1.0), -9.0, "a"),
    distance=2.5,
    light=(3.0, 4.0, -2.0),
    color=(0.9, 0.8, 0.7),
    render={"background": (0.1, 0.2, 0.3)},
    materials={
        "a": material((0.7, 0.3, 0.1), ambient=(0.1, 0.0, 0.2), specular=0.5, reflection=(0.2, 0.1, 0.0)),
        "b": material((0.2, 0.9, 0.4), reflection=0.3),
    },
)


def _bits(x, n: int) -> bytes:
    """A Dr.Jit array's values as bytes, a width-1 array (a literal, an opaque value) broadcast to n."""
    return np.ascontiguousarray(np.broadcast_to(np.asarray(x), (n,))).tobytes()


def _vec_bits(v, n: int) -> list[bytes]:
    return [_bits(v[i], n) for i in range(3)]


def _both(precision: str, runtime: bool, with_tree: bool = True, rules=None) -> tuple[Unrolled, Tabled]:
    scene = parse_scene(SCENE)
    rules, T = rules or PROFILES["conventional"], Types.of(precision)
    table = ShapeTable(scene, T, with_tree=with_tree)
    return Unrolled(scene, rules, T, runtime), Tabled(scene, rules, T, runtime, table)


def _floats(T, a: np.ndarray):
    """NumPy float64 values as a Dr.Jit array (or, (n, 3), 3-vector) of T's precision."""
    if a.ndim == 2:
        return T.Array3(*(_floats(T, a[:, i]) for i in range(3)))
    return T.Float(np.ascontiguousarray(a.astype(T.np_dtype)))


def test_one_protocol():
    """Every method of the protocol is each representation's own (none left abstract, none inherited from
    the other); what both share is the base class's."""
    protocol = {"vec", "camera_z", "material", "_closest", "blocked", "each_ball", "frame", "error_bound", "is_ball"}
    assert protocol <= Values.__abstractmethods__
    for cls in (Unrolled, Tabled):
        assert not cls.__abstractmethods__
        assert all(name in vars(cls) for name in Values.__abstractmethods__), cls


@pytest.mark.parametrize("precision", ["f64", "f32"])
@pytest.mark.parametrize("runtime", [False, True])
def test_per_shape_values_same_bits(precision, runtime):
    """material, frame, error_bound and is_ball of every shape id and of a miss (-1); the scene's
    3-vectors and the camera's z."""
    un, tab = _both(precision, runtime)
    T = un.T
    ids = [-1, 0, 1, 2, 3, 2, 0]
    n = len(ids)
    rng = np.random.default_rng(3)
    lp, lo = _floats(T, rng.uniform(0, 5, n)), _floats(T, rng.uniform(0, 5, n))
    got = {}
    for name, v in (("unrolled", un), ("tabled", tab)):
        sid = T.Int(ids)
        out = {m: _vec_bits(v.material(sid, m), n) for m in ("ambient", "diffuse", "specular", "reflection")}
        plane_n, (c, r, inv_r, is_ball) = v.frame(sid)
        out |= {"n": _vec_bits(plane_n, n), "c": _vec_bits(c, n), "r": _bits(r, n), "inv_r": _bits(inv_r, n)}
        out |= {"frame is_ball": _bits(is_ball, n), "is_ball": _bits(v.is_ball(sid), n)}
        out["error_bound"] = _bits(v.error_bound(sid, lp, lo), n)
        out |= {k: _vec_bits(v.vec(k), n) for k in ("light", "light_color", "background")}
        out |= {f"camera_z {F.__name__}": _bits(v.camera_z(F), n) for F in (T.Float, dr.llvm.Float64)}
        got[name] = out
    assert got["unrolled"] == got["tabled"]
    assert got["unrolled"]["is_ball"] == np.array([0, 1, 0, 1, 0, 1, 1], dtype=bool).tobytes()


@pytest.mark.parametrize("precision", ["f64", "f32"])
@pytest.mark.parametrize("with_tree", [True, False], ids=["bvh", "loop"])
@pytest.mark.parametrize("shadow_range", ["any", "to-light"])
def test_rays_same_bits(precision, with_tree, shadow_range):
    """closest, blocked (recorded or not) and each_ball of random rays."""
    rng = np.random.default_rng(11)
    n = 4000
    o, d, dist = rng.uniform(-3, 3, (n, 3)), rng.normal(size=(n, 3)), rng.uniform(0, 6, n)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    rules = replace(PROFILES["conventional"], shadow_range=shadow_range)
    got = {}
    for name, v in zip(("unrolled", "tabled"), _both(precision, False, with_tree, rules), strict=True):
        T = v.T
        oo, dd, far = _floats(T, o), _floats(T, d), _floats(T, dist)
        sid, t = v.closest(oo, dd)
        blocked, ts = v.blocked(oo, dd, far, record=False)
        rec, rec_ts = v.blocked(oo, dd, far, record=True)
        near = v.each_ball(oo, lambda acc, c, r, oo=oo: dr.minimum(acc, dr.norm(oo - c) - r), dr.full(T.Float, 1e30, n))
        got[name] = {"id": _bits(sid, n), "t": _bits(t, n), "blocked": _bits(blocked, n), "near": _bits(near, n)}
        got[name] |= {"recorded": _bits(rec, n), "ts": [_bits(x, n) for x in rec_ts], "unrecorded ts": len(ts)}
    assert got["unrolled"] == got["tabled"]
    assert got["tabled"]["unrecorded ts"] == 0 and len(got["tabled"]["ts"]) == 4
    assert got["tabled"]["recorded"] == got["tabled"]["blocked"]
    assert set(np.frombuffer(got["tabled"]["id"], dtype=np.int32)) == {-1, 0, 1, 2, 3}  # every shape, and misses
    assert 0.05 < np.frombuffer(got["tabled"]["blocked"], dtype=bool).mean() < 0.95
