"""The scene as the kernels read it: two representations behind one protocol (``Values``).

A kernel reads the scene -- the shapes' centres, radii, normals and materials, the light, the
background, the camera's distance -- and finds the shapes a ray meets in one of two ways, chosen per
Tracer (its ``accel``):

- ``Unrolled``: every shape in code generated for this scene. A shape's value is a Python constant
  compiled into the kernel as a literal, or under ``runtime`` an opaque value the kernel reads
  (``Values.k``); a value of the hit shape is a select chain over the shapes; the closest hit tests
  every shape in turn. Fastest for a few shapes; one kernel per layout.
- ``Tabled``: the values gathered from the arrays of a ``ShapeTable``, the balls found through its BVH
  ("bvh") or a loop over them ("loop"), planes in a loop (minirt.reference.accel): kernels independent of
  the layout, time ~log N.

Both have the same methods, and each method does the same operations on the same values either way, so
the same bits (tested: tests/reference/test_accel.py and test_values.py). The tracer's code calls these
methods and never asks which representation it has. A representation also says how the kernel sees the
rules' yes/no switches (``rule``) and numbers (``number``): compiled in, or under ``runtime`` read at run
time like the values -- or, for a batch of rule sets traced in one kernel (``Candidates``), gathered per ray
from a table of the candidates' values by the ray's lane (``Values.lane``).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import drjit as dr
import numpy as np

from minirt.model.rules import Rules
from minirt.model.scene import Ball, Plane, Scene
from minirt.reference import accel, shapes
from minirt.reference.accel import ShapeTable, gamma


@dataclass
class Types:
    """The kernels' Dr.Jit types for one precision, and its unit round-off."""

    Float: Any
    UInt: Any
    Int: Any
    Bool: Any
    Array3: Any
    Bits: Any
    np_dtype: Any
    u: float  # unit round-off

    @classmethod
    def of(cls, precision: str) -> Types:
        from drjit import llvm

        # what differs between the two: the float, its 3-vector, the unsigned integer of its bits, NumPy's dtype, u
        own = {
            "f64": (llvm.Float64, llvm.Array3f64, llvm.UInt64, np.float64, 2.0**-53),
            "f32": (llvm.Float, llvm.Array3f, llvm.UInt32, np.float32, 2.0**-24),
        }
        if precision not in own:
            raise ValueError(f"unknown precision {precision!r} (f64 or f32)")
        Float, Array3, Bits, np_dtype, u = own[precision]
        return cls(Float, llvm.UInt32, llvm.Int32, llvm.Bool, Array3, Bits, np_dtype, u)

    def zero3(self) -> Any:
        """(0, 0, 0) as a 3-vector of literals."""
        return self.Array3(0.0, 0.0, 0.0)

    def reciprocal(self, x: float) -> float:
        """1 / x rounded as the kernel's 1.0 / x in this precision (one IEEE division, correctly rounded
        either side): a per-shape constant the kernel selects instead of dividing per ray."""
        dt = self.np_dtype
        return float(dt(1.0) / dt(x))


def _numeric_offset(r: Rules) -> float:
    return float(r.offset) if not isinstance(r.offset, str) else 0.0  # error-bound: no number (not read)


# The rules a kernel reads per ray under ``runtime`` (``Values.rule``, ``Values.number``): name -> (the value
# for one rule set, its type). Every other rule is compiled in (``Candidates``: a batch must agree on it).
PER_RAY: dict[str, tuple[Callable[[Rules], Any], str]] = {
    "hit_point_origin": (lambda r: r.hit_point == "origin", "bool"),
    "ball_normal_inward": (lambda r: r.ball_normal == "inward", "bool"),
    "offset_along_ray": (lambda r: r.offset_along == "ray", "bool"),
    "offset": (_numeric_offset, "float"),
    "near_root_only": (lambda r: bool(r.near_root_only), "bool"),
    "two_sided": (lambda r: bool(r.two_sided), "bool"),
    "clamp_all": (lambda r: r.clamp is True, "bool"),
    "clamp_specular": (lambda r: r.clamp == "specular", "bool"),
    "light_direction": (lambda r: r.light == "direction", "bool"),
    "specular_negated": (lambda r: r.specular_s == "-s", "bool"),
    "specular_exponent": (lambda r: int(r.specular_exponent), "uint"),
    "raw_ball_shading": (lambda r: r.raw_normals_ball in ("shading", "both"), "bool"),
    "raw_ball_reflection": (lambda r: r.raw_normals_ball in ("reflection", "both"), "bool"),
    "raw_plane_shading": (lambda r: r.raw_normals_plane in ("shading", "both"), "bool"),
    "raw_plane_reflection": (lambda r: r.raw_normals_plane in ("reflection", "both"), "bool"),
    "pixel_uv": (lambda r: 0.0 if r.pixel_sample == "corner" else 0.5, "float"),
    "shift_x": (lambda r: float(r.pixel_shift[0]), "float"),
    "shift_y": (lambda r: float(r.pixel_shift[1]), "float"),
    "camera_origin": (lambda r: r.ray_origin == "camera", "bool"),
    "t_max": (lambda r: float(r.t_max), "float"),
}


# Rules a single rule set's kernel compiles in, whatever ``runtime`` (they change which work is done), but a
# batch reads per ray (``Values.switch``): candidates that differ only in them share one kernel -- a search
# step's candidates fell into seven kernels by these and the offset's kind, each an LLVM compile (~0.2 s).
SWITCHES: dict[str, Callable[[Rules], bool]] = {
    "shadow_rays": lambda r: bool(r.shadow_rays),
    "background_none": lambda r: r.background == "none",
    "background_on_hit": lambda r: r.background == "on-hit",
    # shadow_range "to-light": a batch computes each ball's t along the shadow ray (which "any" does without)
    # and takes each ray's candidate's test
    "shadow_to_light": lambda r: r.shadow_range == "to-light",
    # offset "error-bound": a batch computes both starts of a secondary ray (the bound's and the number's) and
    # the ball's point put back on it, and takes each ray's candidate's
    "offset_error_bound": lambda r: r.offset == "error-bound",
}

_YES_NO = {n: fn for n, (fn, own) in PER_RAY.items() if own == "bool"} | SWITCHES
_BIT = {name: k for k, name in enumerate(_YES_NO)}
_EXPONENT_SHIFT = len(_BIT)  # the exponent's bits above the yes/no rules' (exponents < 2^11: 21 + 11 bits)
assert _EXPONENT_SHIFT + 11 <= 32, "the yes/no rules and the exponent must fit one UInt32"


def _packed(r: Rules) -> int:
    """A rule set's yes/no per-ray rules as bits, its exponent above them."""
    bits = sum(1 << k for name, k in _BIT.items() if _YES_NO[name](r))
    return bits | (int(r.specular_exponent) << _EXPONENT_SHIFT)


class Divergent(Exception):
    """A batch's rule sets disagree on a rule its kernel compiles in (``fn`` of the rules): they cannot
    share one kernel."""

    def __init__(self, fn: Callable[[Rules], Any]):
        super().__init__(getattr(fn, "__name__", "rule"))
        self.fn = fn


class Candidates:
    """Several rule sets traced in one kernel (``Tracer(scene, [rules, ...])``), as the kernel's code reads
    them: a rule they all agree on reads as that value (``candidates.two_sided``, compiled in or read at run
    time as for one rule set); one they differ on raises ``Divergent``, except where the code reads it per
    ray (``Values.rule``, ``Values.number``: each ray its own candidate's value). So a rule the kernel
    compiles in can never be taken from the wrong candidate: the batch is split instead
    (minirt.diagnose.variants). Lane k of the batch is the k-th rule set."""

    def __init__(self, rules: Sequence[Rules]):
        self.all = tuple(rules)

    def agree(self, fn: Callable[[Rules], Any]) -> Any:
        """fn's answer, the same for every candidate (else ``Divergent``)."""
        first = fn(self.all[0])
        for r in self.all[1:]:
            other = fn(r)
            if type(other) is not type(first) or other != first:
                raise Divergent(fn)
        return first

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__") or not hasattr(self.all[0], name) or callable(getattr(self.all[0], name)):
            raise AttributeError(name)  # a rule, not a method: methods answer for one rule set

        def rule(r: Rules, _n=name) -> Any:
            return getattr(r, _n)

        rule.__name__ = name
        return self.agree(rule)


class Values(ABC):
    """The protocol both representations follow, and what they share.

    Shared: a rule's switch (``rule``) and a scene value (``k``) as the kernel sees them, the closest hit
    (``closest``, around each representation's search), a shape's own values (``ball``, ``plane``) and the
    tests of one shape (``intersect``, ``occludes``, ``blocked_each``) -- which the per-shape reports (the
    probe, a recorded shadow ray) read whatever the representation. Each representation's own: the
    abstract methods below, and ``tabled_balls``."""

    tabled_balls = 0  # the balls rays find through a shape table (0: none); the integrator's choice of path

    def __init__(self, scene: Scene, rules: Rules | Candidates, T: Types, runtime: bool):
        self.scene, self.rules, self.T, self.runtime = scene, rules, T, runtime
        self._consts: dict[Any, Any] = {}  # ``k``'s opaque values
        self._index = {id(s): k for k, s in enumerate(scene.shapes)}
        # a batch: each ray's candidate (``set_lanes``), and the tables its per-ray rules are gathered from
        self.batch: Candidates | None = rules if isinstance(rules, Candidates) else None
        self.lane: Any = None
        self._tables: dict[Any, Any] = {}  # the opaque per-ray rules of one rule set
        self._per_ray: dict[Any, Any] = {}  # a batch's, gathered

    def set_lanes(self, rays_each: int) -> None:
        """A batch's rays: ``rays_each`` of the first candidate, then as many of the second ... (an input
        array, as a subset's pixel indices are: one kernel whatever the count)."""
        if self.batch is not None:
            from minirt.jit.arrays import aligned  # (an unaligned input array compiles another kernel)

            lane = np.repeat(np.arange(len(self.batch.all), dtype=np.uint32), rays_each)
            self.lane = dr.llvm.UInt32(aligned(lane, np.uint32))
            # the per-ray rules gathered here, before any loop of the kernel: a gather at each reading site
            # (a ball's test reads near_root_only for every ball at every level) tripled the kernels' LLVM
            # compile, and twenty gathered values live through the loops still cost ~40 %. So the yes/no
            # rules and the exponent (< 2^11) travel as the bits of one integer per ray, which each reading
            # site takes its bit from (``number``); the numbers are gathered where first read.
            table = [_packed(r) for r in self.batch.all] * (2 if len(self.batch.all) == 1 else 1)
            self._bits = dr.gather(dr.llvm.UInt32, dr.llvm.UInt32(table), self.lane)
            # the numbers too, here: one gathered inside a loop or a conditional may not be used outside it
            F = self.T.Float
            self._per_ray = {(n, F): self._gather(n, F) for n, (_, own) in PER_RAY.items() if own == "float"}

    @abstractmethod
    def vec(self, name: str) -> Any:
        """A scene 3-vector: "light", "light_color" or "background"."""

    @abstractmethod
    def camera_z(self, F) -> Any:
        """-distance, the camera's z, in float type F (rounded from float64 as a literal would be)."""

    @abstractmethod
    def material(self, shape_id, name: str) -> Any:
        """The hit shape's material colour ``name`` (ambient, diffuse, specular, reflection); 0 on a miss."""

    @abstractmethod
    def _closest(self, o, d, t_best, id_best) -> tuple[Any, Any]:
        """``closest``'s search: (id, t) of the closest hit, merged into (t_best, id_best)."""

    @abstractmethod
    def blocked(self, o, s, light_dist, record: bool) -> tuple[Any, list[Any]]:
        """Is the shadow ray (o, s) blocked (``shading.shadow_blocked``), and with ``record`` each shape's t
        along it in id order (else an empty list)."""

    @abstractmethod
    def each_ball(self, o, fn, acc) -> Any:
        """acc = fn(acc, center, radius) over every ball (per-ray quantities no tree can prune, such as the
        distance from the nearest silhouette)."""

    @abstractmethod
    def frame(self, shape_id) -> tuple[Any, Any]:
        """(n, ball) of the hit shape: the hit plane's normal (0 elsewhere), and (C, r, 1 / r, is_ball) of the
        hit ball (C 0 and r 1 elsewhere; None in a scene without balls) -- what
        ``interaction.hit_point_and_normal`` applies its formula to, once."""

    @abstractmethod
    def error_bound(self, shape_id, lp, lo) -> Any:
        """``interaction.error_bound`` (its derivation is there) of the hit shape's point p of the ray from
        o, lp = |p| and lo = |o|: gamma(6) (r + |p|) for a ball, gamma(4) (|a| + |p| + |o|) for a plane."""

    @abstractmethod
    def is_ball(self, shape_id) -> Any:
        """Whether the hit shape is a ball (false on a miss)."""

    def normal_length(self, shape_id) -> Any:
        """The length of the hit shape's normal as a solution that never normalises it has it (rule
        raw_normals): a ball's radius (p - c, not divided by it), a plane's normal's length as written in
        the scene (``Plane.written``); 1 on a miss. A select chain over the shapes (the balls' radii
        gathered from the table when the scene has one)."""
        out = self.T.Float(1.0)
        for k, s in enumerate(self.scene.shapes):
            key, v = (("radius", k), s.radius) if isinstance(s, Ball) else (("normal_length", k), s.written)
            out = dr.select(shape_id == k, self.k(key, v), out)
        return out

    def closest(self, o, d) -> tuple[Any, Any]:
        """Appendix 1 (``Scene.Intersect``): (id, t) of the closest hit over all shapes, -1 and inf on a miss;
        ties keep the lower shape id."""
        # Full width from the start: with no shapes at all these are the results, one per ray.
        t_best = dr.full(self.T.Float, math.inf, dr.width(d))
        if self.runtime or self.rules.t_max != math.inf:
            # rule t_max: the search starts at a finite "infinity", so hits beyond it are ignored (and a
            # ray that finds none is a miss: shade_level gives it inf). Under ``runtime`` read at run time
            # (``number``), inf included (min(inf, inf) is inf): one kernel for every t_max a diagnosis tries.
            t_max = self.number("t_max") if self.runtime else self.k("t_max", self.rules.t_max)
            t_best = dr.minimum(t_best, t_max)
        id_best = dr.full(self.T.Int, -1, dr.width(d))
        return self._closest(o, d, t_best, id_best)

    def number(self, name: str, kind: Any = None) -> Any:
        """A per-ray rule's number (``PER_RAY``) as the kernel reads it at run time (``runtime`` only), in
        Dr.Jit type ``kind`` (default its own): an opaque value -- or for a batch each ray's candidate's,
        gathered once per kernel from a table of the candidates' values by the ray's lane (``set_lanes``;
        the same value in the same operations: the same bits as the candidate traced alone)."""
        fn, own = PER_RAY[name]
        kind = kind or self._kind(own)
        if self.batch is None:
            v = self._tables.get((name, kind))
            if v is None:
                v = self._tables[(name, kind)] = dr.opaque(kind, fn(self.rules))
            return v
        if own == "bool":
            return ((self._bits >> _BIT[name]) & 1) != 0
        if own == "uint":
            return self._bits >> _EXPONENT_SHIFT
        v = self._per_ray.get((name, kind))
        # another float type (a camera's rays in float64 for a float32 trace): gathered where asked, outside
        # the loops, and not kept
        return self._gather(name, kind) if v is None else v

    def switch(self, name: str) -> Any:
        """A rule a single rule set's kernel compiles in (``SWITCHES``): the Python bool -- or for a batch
        each ray's candidate's (a mask), so that candidates differing in it share the kernel."""
        if self.batch is None:
            return bool(SWITCHES[name](self.rules))
        return ((self._bits >> _BIT[name]) & 1) != 0

    def rule(self, name: str) -> Any:
        """A per-ray rule's yes/no (``PER_RAY``) as the kernel sees it: under ``runtime`` read at run time,
        one kernel for both answers (``number``), else the Python bool itself (compiled in)."""
        if not self.runtime:
            return bool(PER_RAY[name][0](self.rules))
        return self.number(name)

    def _kind(self, own: str) -> Any:
        return {"bool": self.T.Bool, "float": self.T.Float, "uint": self.T.UInt}[own]

    def _gather(self, name: str, kind: Any) -> Any:
        """Each ray's candidate's value of ``name``: a table of the candidates' values (at least two
        entries: a batch of one then gathers as a batch of many does, where Dr.Jit would fold a gather from
        one value into that value -- one kernel for both), gathered by the ray's lane."""
        fn = PER_RAY[name][0]
        vals = [fn(r) for r in self.batch.all] * (2 if len(self.batch.all) == 1 else 1)
        return dr.gather(kind, kind(vals), self.lane)

    def k(self, key, value, F=None) -> Any:
        """A value of the scene (a shape's, a material's, the light's, the camera's) as the unrolled path's
        kernels see it, in float type F (default the precision's; a sequence: a 3-vector). Compiled in as
        a literal -- or under ``runtime`` an opaque value the kernel reads, made once per Tracer under
        ``key``: a scene that differs only in its values (a ball moved, a colour changed, a campaign's
        defect) then reuses the compiled kernels, at the cost of the literals' folding (three_balls
        1024^2: 8.5 -> 9.7 ms a trace), which is why large images compile them in. The same value in the
        same operations either way, so the same bits (tested, as the table path, whose values are
        gathered, is). A literal is never cached: one made inside a symbolic conditional may not be used
        outside it."""
        F = F or self.T.Float
        if isinstance(value, int | float):
            kind, value = F, float(value)
        else:
            kind, value = (self.T.Array3 if F is self.T.Float else dr.llvm.Array3f64), [float(c) for c in value]
        if not self.runtime:
            return kind(*value) if isinstance(value, list) else kind(value)
        v = self._consts.get(key)
        if v is None:
            v = self._consts[key] = dr.opaque(kind, value)
        return v

    def ball(self, ball: Ball) -> tuple[Any, Any]:
        """A ball's centre and radius (``k``)."""
        k = self._index[id(ball)]
        return self.k(("center", k), ball.center), self.k(("radius", k), ball.radius)

    def plane(self, plane: Plane) -> tuple[Any, Any]:
        """A plane's normal and point (``k``)."""
        k = self._index[id(plane)]
        return self.k(("normal", k), plane.normal), self.k(("point", k), plane.point)

    def intersect(self, shape, o, d, gate: bool = False) -> Any:
        """t of the ray (o, d) at the shape, inf on a miss; ``gate``: see ``shapes.ball_t``, ``shapes.plane_t``."""
        if isinstance(shape, Ball):
            return shapes.ball_t(self, *self.ball(shape), o, d, gate)
        return shapes.plane_t(self, *self.plane(shape), o, d, gate)

    def occludes(self, ball: Ball, o, d) -> Any:
        """Does the ray (o, d) meet the ball at some t > 0 (``shapes.ball_occludes``, without the square root)?"""
        k = self._index[id(ball)]
        lo, hi = shapes.sqrt_bounds(ball.radius, self.T.np_dtype)
        return shapes.ball_occludes(
            self, *self.ball(ball), o, d, (self.k(("sqrt_lo", k), lo), self.k(("sqrt_hi", k), hi))
        )

    def blocked_each(self, o, s, light_dist, record: bool) -> tuple[Any, list[Any]]:
        """``blocked`` shape by shape, and with ``record`` each shape's t along the shadow ray."""
        blocked = self.T.Bool(False)
        ts = []
        to_light = self.switch("shadow_to_light")  # a batch's: each ray its candidate's (a mask)
        for shape in self.scene.shapes:
            need_t = record or to_light is not False or not isinstance(shape, Ball)
            tk = self.intersect(shape, o, s, gate=True) if need_t else None
            if record:
                ts.append(tk)
            if to_light is True:
                blocked |= tk < light_dist
                continue
            # Planes keep t: a near-parallel ray's quotient can overflow to inf (a miss), which signs
            # alone would not see; a division is cheap beside a ball's square roots.
            anywhere = self.occludes(shape, o, s) if isinstance(shape, Ball) else tk < math.inf
            blocked |= anywhere if to_light is False else dr.select(to_light, tk < light_dist, anywhere)
        return blocked, ts


class Unrolled(Values):
    """Every shape in the kernel's code: constants (``k``), select chains, a test per shape."""

    def vec(self, name: str) -> Any:
        sc = self.scene
        return self.k(
            name, {"light": sc.light.position, "light_color": sc.light.color, "background": sc.background}[name]
        )

    def camera_z(self, F) -> Any:
        return self.k(("camera_z", F), -self.scene.camera.distance, F)

    def _by_id(self, shape_id, values: list, zero) -> Any:
        """Per-lane lookup of a per-shape constant: a select chain (shapes are few)."""
        out = zero
        for k, v in enumerate(values):
            out = dr.select(shape_id == k, v, out)
        return out

    def material(self, shape_id, name: str) -> Any:
        vals = [self.k((name, k), getattr(s.material, name)) for k, s in enumerate(self.scene.shapes)]
        return self._by_id(shape_id, vals, self.T.zero3())

    def _closest(self, o, d, t_best, id_best) -> tuple[Any, Any]:
        """Every shape tested in id order (so a tie keeps the lower id)."""
        for k, s in enumerate(self.scene.shapes):
            tk = self.intersect(s, o, d, gate=True)
            closer = tk < t_best
            t_best = dr.select(closer, tk, t_best)
            id_best = dr.select(closer, k, id_best)
        return id_best, t_best

    def blocked(self, o, s, light_dist, record: bool) -> tuple[Any, list[Any]]:
        return self.blocked_each(o, s, light_dist, record)

    def each_ball(self, o, fn, acc) -> Any:
        """In id order."""
        for ball in self.scene.shapes:
            if isinstance(ball, Ball):
                acc = fn(acc, *self.ball(ball))
        return acc

    def frame(self, shape_id) -> tuple[Any, Any]:
        """Each selected by shape id."""
        T = self.T
        zero = T.zero3()
        balls = [(k, s) for k, s in enumerate(self.scene.shapes) if isinstance(s, Ball)]
        planes = [(k, s) for k, s in enumerate(self.scene.shapes) if isinstance(s, Plane)]
        n = zero
        for k, s in planes:
            n = dr.select(shape_id == k, self.k(("normal", k), s.normal), n)
        if not balls:
            return n, None
        is_ball = T.Bool(False)
        c, r, inv_r = zero, T.Float(1.0), T.Float(1.0)
        for k, s in balls:
            on = shape_id == k
            is_ball |= on
            ck, rk = self.ball(s)
            c = dr.select(on, ck, c)
            r = dr.select(on, rk, r)
            inv_r = dr.select(on, self.k(("inv_radius", k), T.reciprocal(s.radius)), inv_r)
        return n, (c, r, inv_r, is_ball)

    def error_bound(self, shape_id, lp, lo) -> Any:
        """Per shape, then selected."""
        u = self.T.u
        vals = []
        for k, s in enumerate(self.scene.shapes):
            if isinstance(s, Ball):  # + 0.0: the table path's sum, same bits
                vals.append(gamma(6, u) * ((self.k(("radius", k), s.radius) + lp) + 0.0))
            else:
                vals.append(gamma(4, u) * ((self.k(("abs_distance", k), abs(s.distance)) + lp) + lo))
        return self._by_id(shape_id, vals, self.T.Float(0))

    def is_ball(self, shape_id) -> Any:
        is_ball = self.T.Bool(False)
        for k, s in enumerate(self.scene.shapes):
            if isinstance(s, Ball):
                is_ball |= shape_id == k
        return is_ball


class Tabled(Values):
    """The scene's values gathered from a ``ShapeTable``; the balls found through its BVH when it has one,
    else in a loop (the brute force the tree is tested against); planes in a loop."""

    def __init__(self, scene: Scene, rules: Rules, T: Types, runtime: bool, table: ShapeTable):
        super().__init__(scene, rules, T, runtime)
        self.table = table
        self.tabled_balls = table.n_balls

    def vec(self, name: str) -> Any:
        return self.table.vec(name)

    def camera_z(self, F) -> Any:
        return self.table.camera_z(F)

    def material(self, shape_id, name: str) -> Any:
        return dr.gather(self.T.Array3, self.table.material[name], self.T.UInt(shape_id), shape_id >= 0)

    def _closest(self, o, d, t_best, id_best) -> tuple[Any, Any]:
        """Planes in a loop, then the balls, merged by the lower-id tie rule."""
        tab = self.table
        if tab.n_planes:
            t_best, id_best = accel.planes_closest(self, tab, o, d, t_best, id_best)
        if tab.n_balls and tab.tree is not None:
            t_best, id_best = accel.traverse(self, tab, o, d, t_best, id_best)
        elif tab.n_balls:
            t_best, id_best = accel.balls_closest_loop(self, tab, o, d, t_best, id_best)
        return id_best, t_best

    def blocked(self, o, s, light_dist, record: bool) -> tuple[Any, list[Any]]:
        """Planes in a loop, balls through the BVH (a ray stops at its first blocker): the same decisions
        per shape, so the same answer. With ``record`` shape by shape (``blocked_each``): a record holds
        each shape's t, which a ray that stops early never computes."""
        if record:
            return self.blocked_each(o, s, light_dist, record)
        T, tab = self.T, self.table
        to_light = self.switch("shadow_to_light")  # a batch's: each ray its candidate's (a mask)
        blocked = dr.full(T.Bool, False, dr.width(s))
        if tab.n_planes:
            blocked = accel.planes_block(self, tab, o, s, light_dist, to_light)
        if tab.n_balls:
            if to_light is True:
                blocks = lambda c, r: shapes.ball_t(self, c, r, o, s) < light_dist  # noqa: E731
                bound = light_dist
            elif to_light is False:
                blocks = lambda c, r: shapes.ball_occludes(self, c, r, o, s)  # noqa: E731
                bound = dr.full(T.Float, math.inf, dr.width(s))
            else:  # each ray its candidate's test, and its own distance beyond which boxes are skipped

                def blocks(c, r):
                    near = shapes.ball_t(self, c, r, o, s) < light_dist
                    return dr.select(to_light, near, shapes.ball_occludes(self, c, r, o, s))

                bound = dr.select(to_light, light_dist, T.Float(math.inf))
            if tab.tree is not None:
                by_balls, _ = accel.traverse(self, tab, o, s, bound, None, blocks=blocks)
            else:
                by_balls = accel.balls_each(
                    self, tab, o, lambda acc, c, r, _: acc | blocks(c, r), dr.full(T.Bool, False, dr.width(s)),
                    stop=lambda acc: acc,
                )  # fmt: skip
            blocked = blocked | by_balls
        return blocked, []

    def each_ball(self, o, fn, acc) -> Any:
        """In a loop, in the table's ball order."""
        if self.table.n_balls:
            acc = accel.balls_each(self, self.table, o, lambda acc, c, r, _id: fn(acc, c, r), acc)
        return acc

    def frame(self, shape_id) -> tuple[Any, Any]:
        """Gathered: the same values as ``Unrolled.frame`` selects, so the same bits."""
        T, tab = self.T, self.table
        hit = shape_id >= 0
        k = T.UInt(shape_id)
        is_ball = dr.gather(T.Bool, tab.is_ball, k, hit)
        n = dr.gather(T.Array3, tab.plane_normal, k, hit & ~is_ball)
        c = dr.gather(T.Array3, tab.center, k, is_ball)
        r = dr.select(is_ball, dr.gather(T.Float, tab.radius, k, is_ball), T.Float(1.0))
        inv_r = dr.select(is_ball, dr.gather(T.Float, tab.inv_radius, k, is_ball), T.Float(1.0))
        return n, (c, r, inv_r, is_ball)

    def error_bound(self, shape_id, lp, lo) -> Any:
        """The factor and the length gathered from the table (``ShapeTable.err_factor``, ``err_length``)."""
        T, tab = self.T, self.table
        k, hit = T.UInt(shape_id), shape_id >= 0
        factor = dr.gather(T.Float, tab.err_factor, k, hit)
        is_ball = dr.gather(T.Bool, tab.is_ball, k, hit)
        extra = dr.select(is_ball, T.Float(0.0), lo)
        return factor * ((dr.gather(T.Float, tab.err_length, k, hit) + lp) + extra)

    def is_ball(self, shape_id) -> Any:
        return dr.gather(self.T.Bool, self.table.is_ball, self.T.UInt(shape_id), shape_id >= 0)

    def normal_length(self, shape_id) -> Any:
        """Gathered by shape id from an array of its own (a ball's radius, a plane's length as written),
        made once per Tracer: kernels independent of the layout, as the table's."""
        T = self.T
        if getattr(self, "_lengths", None) is None:
            own = [s.radius if isinstance(s, Ball) else s.written for s in self.scene.shapes]
            self._lengths = T.Float(np.array(own, dtype=T.np_dtype))
        hit = shape_id >= 0
        return dr.select(hit, dr.gather(T.Float, self._lengths, T.UInt(shape_id), hit), T.Float(1.0))
