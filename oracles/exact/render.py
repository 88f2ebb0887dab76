"""Pixels of the exact model: each at rising precision until every decision is certified and its colour
known to ``COLOR_ABS``; the chosen pixels of an image, in this process or on a pool of processes; the
buffers of a RenderResult from them.

A pixel is tried at each precision of ``PRECISIONS`` in turn (minirt.oracles.exact.model raises
``Uncertain`` at a decision it cannot certify); one whose decisions stay uncertain at the last is an
exact tie, flagged (``aux["exact_tie"]``) with the decision named, and its buffers hold the values of its
last attempt with that decision taken by the interval's midpoint -- for the picture only, never judged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from flint import arb, fmpq

from minirt.model.result import TERMS
from minirt.model.rules import Rules
from minirt.model.scene import Scene
from minirt.oracles.exact import model as exact_model
from minirt.oracles.exact.model import Level, Model, Uncertain, primary_lines, q, set_precision

# Working precisions, bits, tried in turn. 128 certifies nearly every pixel of a campaign scene (binary64
# inputs need 106 bits for an exact product, and a far ball's discriminant cancels ~log2(|C|/r)^2 bits
# more); a decision still uncertain at 1,024 bits -- 300 decimal digits, beyond any cancellation scenes
# within 1e-100 .. 1e100 can cause save an exact one -- is an exact tie.
PRECISIONS = (128, 256, 512, 1024)
# Colours to 2^-40 absolute: 2^-32 of an 8-bit level, so the level of every colour not within 2^-40 of a
# rounding threshold is certain.
COLOR_ABS = 2.0**-40
# The robust evaluation's relative widening of every ray, hit point and plane offset (model docstring), a
# unit round-off for the intervals: each quantity computed from widened inputs carries SLACK times the sizes
# it is computed from, as the reference's carries u times them. 2^-44 = 512 u: measured on generated scenes
# (tests/campaign/test_judge.py), the reference's largest error against the interval's reach was 1/4 of it at
# 2^-46 (a planet's t: |f| 7e7, 1.1e-6 against 4.2e-6) and exceeded it at 2^-48; 512 u keeps 16 times that.
# A smaller widening settles more pixels (a far cluster whose 1e-6 offset is below 2^-44 |p| is not settled).
SLACK = 2.0**-44


@dataclass
class Pixel:
    """One pixel's certified values (midpoints of intervals narrower than the stated bounds)."""

    index: int
    shape_id: int = -1
    t: float = math.inf
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    normal: tuple[float, float, float] = (0.0, 0.0, 0.0)
    color: tuple[float, float, float] = (0.0, 0.0, 0.0)
    terms: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    color_rad: float = 0.0  # the largest radius of a colour channel's interval
    t_rel: float = 0.0  # the t interval's radius over |t|
    bits: int = 0  # the precision that certified it (the last tried, for a tie)
    tie: str = ""  # the decision no precision certified ("": none)
    levels: int = 0  # levels of the ray tree traced
    robust: bool = False  # every decision certified under SLACK too (then the colour bounds hold)
    robust_geometry: bool = False  # the primary ray's decisions certified under SLACK (then t and normal bounds)
    t_bounds: tuple[float, float] = (math.inf, math.inf)
    color_bounds: tuple[tuple[float, ...], tuple[float, ...]] = ((0.0,) * 3, (0.0,) * 3)
    normal_bounds: tuple[tuple[float, ...], tuple[float, ...]] = ((0.0,) * 3, (0.0,) * 3)


def _mid(x: arb) -> float:
    return float(x)  # the midpoint to nearest, as float(x.mid()), at half the cost


def _vec(v) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


def _bounds(v) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Lower and upper bounds of each component, rounded outwards to binary64."""
    lo = tuple(math.nextafter(float(c.lower()), -math.inf) for c in v)
    hi = tuple(math.nextafter(float(c.upper()), math.inf) for c in v)
    return lo, hi


class PixelTracer:
    """The exact model of one scene under one set of rules, pixel by pixel (a Model per precision)."""

    def __init__(self, scene: Scene, rules: Rules):
        self.scene, self.rules = scene, rules
        self._models: dict[int, Model] = {}
        self._robust: Model | None = None
        self.depth = scene.max_depth
        # (index, u, v) -> the balls a primary ray may meet (``prepare``), for the rays of the batch at hand
        self._near: dict[tuple[int, float, float], list[int]] = {}

    def prepare(self, indices, uv) -> None:
        """Cull the balls for these primary rays at once (minirt.oracles.exact.model.Model.line_misses, with
        the robust evaluation's radii: a ball culled is a certified miss of both evaluations at every
        precision); ``run`` and ``robust`` then test only the balls left. Replaces the last batch's."""
        self._near = {}
        m = self.model(PRECISIONS[0])
        if len(m.ball_ids) < exact_model.PRIMARY_CULL_FROM or len(m.ball_ids) >= exact_model.GROUP_FROM:
            return
        for start in range(0, len(indices), 4096):
            idx, pos = indices[start : start + 4096], uv[start : start + 4096]
            miss = m.line_misses(*primary_lines(self.scene, self.rules, idx, pos, SLACK))
            ids = m.ball_ids.tolist()
            for i, (u, v), row in zip(idx, pos, miss.tolist(), strict=True):
                self._near[(int(i), float(u), float(v))] = [k for k, out in zip(ids, row, strict=True) if not out]

    def model(self, bits: int) -> Model:
        set_precision(bits)
        if bits not in self._models:
            self._models[bits] = Model(self.scene, self.rules)
        return self._models[bits]

    def position(self, index: int, u: float, v: float) -> tuple[fmpq, fmpq]:
        """The image-plane position (in pixels) of pixel ``index``'s ray at sub-pixel (u, v), exactly:
        (x + u) + dx, (y + v) + dy (minirt.model.camera's arithmetic, without its rounding)."""
        y, x = divmod(index, self.scene.camera.width)
        sx, sy = self.rules.pixel_shift
        return fmpq(x) + q(u) + q(sx), fmpq(y) + q(v) + q(sy)

    def levels(self, index: int, u: float, v: float, bits: int) -> tuple[Model, list[Level], object]:
        """The ray tree of one ray at one precision (``Uncertain`` where a decision is not certified):
        its model, its levels and its colour."""
        m = self.model(bits)
        return (m, *self.run(m, index, u, v))

    def run(self, m: Model, index: int, u: float, v: float) -> tuple[list[Level], object]:
        """The ray tree of one ray in model ``m``: its levels and its colour."""
        o, d = m.primary(*self.position(index, u, v))
        hit, oa, da = m.closest_primary(o, d, self._near.get((index, u, v)))
        levels: list[Level] = []
        color = m.trace(hit, oa, da, self.depth, levels)
        return levels, color

    def guessed(self, index: int, u: float, v: float) -> tuple[list[Level], object]:
        """A tie's ray tree for the picture: the last precision, every uncertain decision taken by its
        interval's midpoint."""
        set_precision(PRECISIONS[-1])
        return self.run(Model(self.scene, self.rules, guess=True), index, u, v)

    def pixel(self, index: int, u: float, v: float, bounds: bool = True) -> Pixel:
        """One ray, certified: at each precision in turn until every decision is and the colour is known to
        COLOR_ABS; a tie where the last precision still cannot. ``bounds``: its robust bounds too (``robust``;
        more than half a pixel's time); without them the pixel is not robust, so never judged by them."""
        levels, color, bits, tie = self.certify(index, u, v)
        px = self._pixel(index, levels, color, bits, tie)
        return self.robust(px, u, v) if bounds and not tie else px

    def colour(self, index: int, u: float, v: float) -> tuple[tuple[float, float, float], int, str]:
        """One ray's certified colour alone, as ``pixel`` has it, with the precision and the tie ("": none)."""
        _, color, bits, tie = self.certify(index, u, v)
        return _vec(color), bits, tie

    def certify(self, index: int, u: float, v: float) -> tuple[list[Level], object, int, str]:
        """The ray tree at the first precision that certifies every decision and the colour to COLOR_ABS:
        its levels, colour, precision and "" -- or, where none does, a tie's (``guessed``) with the last
        precision and the decision left uncertain."""
        why = ""
        for bits in PRECISIONS:
            try:
                _, levels, color = self.levels(index, u, v, bits)
            except Uncertain as e:
                why = e.what
                continue
            rad = max(float(c.rad()) for c in color)
            if rad <= COLOR_ABS:
                return levels, color, bits, ""
            why = "a colour gate (s·n or r·s under clamp) at its threshold"
        levels, color = self.guessed(index, u, v)
        return levels, color, PRECISIONS[-1], why or "undecided"

    def robust(self, px: Pixel, u: float, v: float) -> Pixel:
        """The pixel's robust bounds (model docstring, ``SLACK``), where its decisions are robust."""
        set_precision(PRECISIONS[0])
        if self._robust is None:
            self._robust = Model(self.scene, self.rules, slack=SLACK)
        m = self._robust
        try:  # the primary ray's decisions: hit, shape, t and normal (the geometry buffers)
            o, d = m.primary(*self.position(px.index, u, v))
            hit, oa, da = m.closest_primary(o, d, self._near.get((px.index, u, v)))
        except Uncertain:
            return px
        px.robust_geometry = True
        if hit is not None:
            lo, hi = _bounds((hit.t,))
            px.t_bounds = (lo[0], hi[0])
            px.normal_bounds = _bounds(m.frame(hit, oa, da)[1])
        try:  # and every decision below it: the colour
            color = m.trace(hit, oa, da, self.depth, [])
        except Uncertain:
            return px
        px.robust = True
        px.color_bounds = _bounds(color)
        return px

    def describe(self, index: int, u: float, v: float) -> dict:
        """One ray's certified ray tree, level by level, as the probe shows it: each level's hit (shape, t as
        an interval, point, normal), lit or not, terms and colour; the precision that certified it, or the
        tie; and whether the pixel is robust, with its colour bounds."""
        px = self.pixel(index, u, v)
        bits = px.bits
        levels, color = self.guessed(index, u, v) if px.tie else self.levels(index, u, v, bits)[1:]
        out_levels = []
        for depth, lvl in enumerate(levels):
            entry: dict = {"depth": depth, "hit": None}
            if lvl.hit is not None:
                lo, hi = _bounds((lvl.hit.t,))
                entry["hit"] = {"id": lvl.hit.shape, "t": _mid(lvl.hit.t), "t_interval": [lo[0], hi[0]],
                                "point": list(_vec(lvl.p)), "normal": list(_vec(lvl.n))}  # fmt: skip
                entry["lit"] = lvl.lit
                entry["terms"] = {k: list(_vec(v)) for k, v in lvl.terms.items()}
                entry["color"] = list(_vec(lvl.color))
            out_levels.append(entry)
        lo, hi = px.color_bounds
        return {
            "bits": bits,
            "tie": px.tie or None,
            "color": list(_vec(color)),
            "color_radius": px.color_rad,
            "robust": px.robust,
            "robust_color": [list(lo), list(hi)] if px.robust else None,
            "levels": out_levels,
        }

    def _pixel(self, index: int, levels: list[Level], color, bits: int, tie: str) -> Pixel:
        first = levels[0]
        px = Pixel(index=index, bits=bits, tie=tie, levels=len(levels))
        px.color = _vec(color)
        px.color_rad = max(float(c.rad()) for c in color)
        if first.hit is not None:
            px.shape_id = first.hit.shape
            px.t = _mid(first.hit.t)
            px.t_rel = float(first.hit.t.rad()) / max(abs(px.t), 1e-300)
            px.position = _vec(first.p)
            px.normal = _vec(first.n)
            px.terms = {k: _vec(v) for k, v in first.terms.items()}
        elif self.rules.background == "on-miss":
            px.terms = {"background": px.color}
        return px


@dataclass
class Pixels:
    """Traced pixels' values as columns, in the order traced: what ``buffers`` reads of each Pixel. A worker
    answers a batch with these few arrays rather than a Pixel object a pixel: pickling, unpickling and
    spreading ~50,000 Pixels into buffers cost a check of the bundled scenes ~0.5 CPU-s of minirt's own
    process, on the threads its checks wait for."""

    index: np.ndarray  # (N,) row-major pixel indices
    shape_id: np.ndarray  # (N,) int32
    t: np.ndarray  # (N,)
    position: np.ndarray  # (N, 3)
    normal: np.ndarray  # (N, 3)
    color: np.ndarray  # (N, 3)
    terms: dict[str, np.ndarray]  # each of TERMS, (N, 3): 0 where a pixel has none
    color_rad: np.ndarray  # (N,)
    t_rel: np.ndarray  # (N,)
    bits: np.ndarray  # (N,) int32
    ties: dict[int, str]  # position in the order -> the decision no precision certified
    robust: np.ndarray  # (N,) bool
    robust_geometry: np.ndarray  # (N,) bool
    t_bounds: np.ndarray  # (N, 2)
    color_lo: np.ndarray  # (N, 3)
    color_hi: np.ndarray  # (N, 3)
    normal_lo: np.ndarray  # (N, 3)
    normal_hi: np.ndarray  # (N, 3)

    @classmethod
    def empty(cls, n: int) -> Pixels:
        return cls(
            np.zeros(n, dtype=np.int64), np.full(n, -1, dtype=np.int32), np.full(n, np.inf), np.zeros((n, 3)),
            np.zeros((n, 3)), np.zeros((n, 3)), {k: np.zeros((n, 3)) for k in TERMS}, np.zeros(n), np.zeros(n),
            np.zeros(n, dtype=np.int32), {}, np.zeros(n, dtype=bool), np.zeros(n, dtype=bool), np.full((n, 2), np.inf),
            np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3)),
        )  # fmt: skip

    @classmethod
    def of(cls, pixels: list[Pixel]) -> Pixels:
        out = cls.empty(len(pixels))
        for k, px in enumerate(pixels):
            out.index[k], out.shape_id[k], out.t[k] = px.index, px.shape_id, px.t
            out.position[k], out.normal[k], out.color[k] = px.position, px.normal, px.color
            for name, v in px.terms.items():
                out.terms[name][k] = v
            out.color_rad[k], out.t_rel[k], out.bits[k] = px.color_rad, px.t_rel, px.bits
            if px.tie:
                out.ties[k] = px.tie
            out.robust[k], out.robust_geometry[k], out.t_bounds[k] = px.robust, px.robust_geometry, px.t_bounds
            (out.color_lo[k], out.color_hi[k]), (out.normal_lo[k], out.normal_hi[k]) = px.color_bounds, px.normal_bounds
        return out

    def put(self, at: slice, part: Pixels) -> None:
        """``part``'s pixels into positions ``at`` of this order."""
        for name, v in vars(part).items():
            if name == "terms":
                for k, col in v.items():
                    self.terms[k][at] = col
            elif name == "ties":
                _ties_into(self.ties, len(self.index), at, v)
            else:
                getattr(self, name)[at] = v


@dataclass(frozen=True)
class Batch:
    """Pixels for one worker: the scene and rules, the pixels' indices and sub-pixel positions."""

    scene: Scene
    rules: Rules
    indices: tuple[int, ...]
    uv: tuple[tuple[float, float], ...]
    bounds: bool = True
    colours: bool = False  # the colours alone (``Colours``), not Pixels
    columns: bool = False  # the pixels as columns (``Pixels``), not a list of Pixel


@dataclass
class Colours:
    """Rays' certified colours alone, in the order asked (``trace_colours``): each ray's colour (N, 3), the
    precision that certified it (N,) and its tie, by position in the order ("": none are)."""

    color: np.ndarray
    bits: np.ndarray
    ties: dict[int, str]

    @classmethod
    def of(cls, tracer: PixelTracer, indices, uv, progress=None) -> Colours:
        n = len(indices)
        tracer.prepare(indices, uv)
        out = cls(np.zeros((n, 3)), np.zeros(n, dtype=np.int32), {})
        for k, (i, (u, v)) in enumerate(zip(indices, uv, strict=True)):
            out.color[k], out.bits[k], tie = tracer.colour(i, u, v)
            if tie:
                out.ties[k] = tie
            if progress and (k + 1) % 256 == 0:
                progress(k + 1, n)
        return out


_KEPT: dict[bytes, PixelTracer] = {}  # the last scenes' tracers by key, the most recent last
KEPT_TRACERS = 4


def tracer_for(scene: Scene, rules: Rules) -> PixelTracer:
    """A PixelTracer of the scene under the rules, the last KEPT_TRACERS kept: its models (a Model per
    precision) take time to build for thousands of balls, and a render asks for the same scene batch after
    batch, sample after sample -- and a check of several scenes renders two at once (the next scene's
    begins while this one's is checked: minirt.harness.run), their batches taking turns on each worker."""
    import hashlib
    import pickle

    key = hashlib.sha256(pickle.dumps((scene, rules), protocol=pickle.HIGHEST_PROTOCOL)).digest()
    tracer = _KEPT.pop(key, None) or PixelTracer(scene, rules)
    _KEPT[key] = tracer
    while len(_KEPT) > KEPT_TRACERS:
        del _KEPT[next(iter(_KEPT))]
    return tracer


def run_batch(batch: Batch) -> list[Pixel] | Pixels | Colours:
    tracer = tracer_for(batch.scene, batch.rules)
    if batch.colours:
        return Colours.of(tracer, batch.indices, batch.uv)
    tracer.prepare(batch.indices, batch.uv)
    got = [tracer.pixel(i, u, v, batch.bounds) for i, (u, v) in zip(batch.indices, batch.uv, strict=True)]
    return Pixels.of(got) if batch.columns else got


def trace_pixels(
    scene: Scene,
    rules: Rules,
    indices: np.ndarray,
    uv: np.ndarray,
    workers: int = 1,
    progress=None,
    bounds: bool = True,
) -> list[Pixel]:
    """Every given pixel (row-major indices, sub-pixel positions (N, 2)), in order: in this process, or in
    ``workers`` processes, the pixels dealt out in interleaved batches (neighbouring pixels cost alike).
    ``bounds``: with their robust bounds (``PixelTracer.pixel``)."""
    idx = [int(i) for i in indices]
    pos = [(float(u), float(v)) for u, v in uv]
    if workers <= 1 or len(idx) < 64:
        tracer = tracer_for(scene, rules)
        tracer.prepare(idx, pos)
        out = []
        for n, (i, (u, v)) in enumerate(zip(idx, pos, strict=True)):
            out.append(tracer.pixel(i, u, v, bounds))
            if progress and (n + 1) % 256 == 0:
                progress(n + 1, len(idx))
        return out
    got: list = [None] * len(idx)
    for at, part in _dealt(scene, rules, idx, pos, workers, progress, bounds):
        got[at] = part
    return got


def trace_columns(scene: Scene, rules: Rules, indices: np.ndarray, uv: np.ndarray, workers: int = 1, progress=None,
                  bounds: bool = True) -> Pixels:  # fmt: skip
    """``trace_pixels``' pixels as columns (``Pixels``), in the same order: each worker process answers with
    its batch's columns."""
    if workers <= 1 or len(indices) < 64:
        return Pixels.of(trace_pixels(scene, rules, indices, uv, 1, progress, bounds))
    idx = [int(i) for i in indices]
    pos = [(float(u), float(v)) for u, v in uv]
    out = Pixels.empty(len(idx))
    for at, part in _dealt(scene, rules, idx, pos, workers, progress, bounds, columns=True):
        out.put(at, part)
    out.ties = dict(sorted(out.ties.items()))
    return out


def trace_colours(scene: Scene, rules: Rules, indices: np.ndarray, uv: np.ndarray, workers: int = 1,
                  progress=None) -> Colours:  # fmt: skip
    """The certified colours alone of the given rays (row-major pixel indices, which may repeat, and sub-pixel
    positions (N, 2)), in order: the later samples of a several-sample render, of which only the colour is
    read. As ``trace_pixels`` deals pixels, but a few numbers a ray come back instead of a Pixel (whose
    building, pickling and reading cost a render of 16 samples more of minirt's time than its workers')."""
    idx = [int(i) for i in indices]
    pos = [(float(u), float(v)) for u, v in uv]
    if workers <= 1 or len(idx) < 64:
        return Colours.of(tracer_for(scene, rules), idx, pos, progress)
    out = Colours(np.zeros((len(idx), 3)), np.zeros(len(idx), dtype=np.int32), {})
    for at, part in _dealt(scene, rules, idx, pos, workers, progress, bounds=False, colours=True):
        out.color[at], out.bits[at] = part.color, part.bits
        _ties_into(out.ties, len(idx), at, part.ties)
    out.ties = dict(sorted(out.ties.items()))
    return out


def _ties_into(ties: dict[int, str], n: int, at: slice, part: dict[int, str]) -> None:
    """A batch's ties, keyed by position in the batch, into ``ties``, keyed by position in the whole order of
    ``n`` rays (the batch holds positions ``at``, ``_dealt``'s slice)."""
    order = range(n)[at]
    ties.update({order[j]: tie for j, tie in part.items()})


def _dealt(scene: Scene, rules: Rules, idx: list[int], pos: list, workers: int, progress, bounds: bool = True,
           colours: bool = False, columns: bool = False):  # fmt: skip
    """The rays dealt out to ``workers`` processes in interleaved batches (neighbouring pixels cost alike), as
    ``trace_pixels``, ``trace_columns`` and ``trace_colours`` trace them: (the slice of the rays' order a batch
    holds, its result) in the batches' order, as each is ready, ``progress`` told of the rays done."""
    parts = workers * 4
    batches = [Batch(scene, rules, tuple(idx[k::parts]), tuple(pos[k::parts]), bounds, colours, columns)
               for k in range(parts)]  # fmt: skip
    done = 0
    for k, part in enumerate(_pool(workers).run(batches)):
        yield slice(k, None, parts), part
        done += len(batches[k].indices)
        if progress:
            progress(done, len(idx))


_POOLS: dict[int, Workers] = {}


def _pool(workers: int) -> Workers:
    """``workers`` worker processes, started once and kept for the process's later renders (a check's
    scenes, a render's samples): each costs ~0.3 s to start."""
    pool = _POOLS.get(workers)
    if pool is None or not pool.alive():
        if pool is not None:
            pool.close()
        pool = _POOLS[workers] = Workers(workers)
    return pool


class Workers:
    """Worker processes of minirt.oracles.exact.worker, each in a session of its own (a terminal's Ctrl-C
    reaches minirt, which kills them: minirt.jobs.processes) and killed by the kernel if minirt is; they
    end when minirt closes their input (at its exit)."""

    def __init__(self, n: int):
        import atexit
        import queue
        import subprocess
        import sys

        from minirt.jobs import processes

        cmd, env = [sys.executable, "-m", "minirt.oracles.exact.worker"], processes.python_env()
        self.procs = [processes.spawn(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env) for _ in range(n)]
        for p in self.procs:
            processes.track(p)
        self.broken = ""  # why the pool can serve no more ("": it can)
        self.free: queue.Queue = queue.Queue()  # idle workers; None once broken
        for p in self.procs:
            self.free.put(p)
        atexit.register(self.close)

    def alive(self) -> bool:
        return not self.broken and all(p.poll() is None for p in self.procs)

    def run(self, batches: list[Batch]):
        """``run_batch(batch)`` for each batch on the workers, the results in order as they are ready."""
        from concurrent.futures import ThreadPoolExecutor

        lanes = ThreadPoolExecutor(len(self.procs))
        try:
            futures = [lanes.submit(self._ask, b) for b in batches]
            for f in futures:
                yield f.result()
        finally:
            lanes.shutdown(wait=True, cancel_futures=True)

    def _ask(self, batch: Batch) -> list[Pixel]:
        import pickle

        from minirt.oracles.exact.channel import read_message, write_message

        p = self.free.get()
        if p is None:  # the pool broke: every batch still waiting fails with the first one's reason
            self.free.put(None)
            raise RuntimeError(self.broken)
        try:
            write_message(p.stdin, pickle.dumps(batch, protocol=pickle.HIGHEST_PROTOCOL))
            data = read_message(p.stdout)
        except (BrokenPipeError, OSError):
            data = None
        if data is None:
            self.broken = f"a worker process of the certified oracle died (status {p.wait()})"
            self.free.put(None)
            raise RuntimeError(self.broken)
        self.free.put(p)
        status, value = pickle.loads(data)
        if status != "ok":
            raise RuntimeError(value)
        return value

    def close(self) -> None:
        import contextlib

        from minirt.jobs import processes

        for p in self.procs:  # every input closed first: they exit together
            with contextlib.suppress(OSError):
                p.stdin.close()
        for p in self.procs:
            processes.stop(p)


def can_spread() -> bool:
    """Whether a check here should start worker processes: not in a daemonic process -- a Dask worker's,
    one of several that share the cores already."""
    import multiprocessing

    return not multiprocessing.current_process().daemon


def buffers(w: int, h: int, pixels: list[Pixel] | Pixels, terms: bool = True) -> dict[str, np.ndarray]:
    """Image buffers (H, W[, 3]) from the traced pixels (a list of Pixel, or their columns); pixels not traced:
    a miss, colour 0, not rendered."""
    px = pixels if isinstance(pixels, Pixels) else Pixels.of(pixels)
    n, i = w * h, px.index
    sid = np.full(n, -1, dtype=np.int32)
    t = np.full(n, np.inf)
    pos, nrm, col = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3))
    rendered, tie, robust = np.zeros(n, dtype=bool), np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
    robust_geometry = np.zeros(n, dtype=bool)
    t_b, c_lo, c_hi = np.full((n, 2), np.inf), np.zeros((n, 3)), np.zeros((n, 3))
    n_lo, n_hi = np.zeros((n, 3)), np.zeros((n, 3))
    bits, crad, trel = np.zeros(n, dtype=np.int32), np.zeros(n), np.zeros(n)
    term = {k: np.zeros((n, 3)) for k in TERMS}
    sid[i], t[i], pos[i], nrm[i], col[i] = px.shape_id, px.t, px.position, px.normal, px.color
    rendered[i], bits[i], crad[i], trel[i] = True, px.bits, px.color_rad, px.t_rel
    tie[i[list(px.ties)]] = True
    for k, v in px.terms.items():
        term[k][i] = v
    robust[i], t_b[i], c_lo[i], c_hi[i], n_lo[i], n_hi[i] = (
        px.robust, px.t_bounds, px.color_lo, px.color_hi, px.normal_lo, px.normal_hi)  # fmt: skip
    robust_geometry[i] = px.robust_geometry
    hit = sid >= 0
    out = {
        "shape_id": sid.reshape(h, w),
        "hit": hit.reshape(h, w),
        "t": np.where(hit, t, np.inf).reshape(h, w),
        "position": pos.reshape(h, w, 3),
        "normal": nrm.reshape(h, w, 3),
        "color": col.reshape(h, w, 3),
        "rendered": rendered.reshape(h, w),
        "exact_tie": tie.reshape(h, w),
        "certified_bits": bits.reshape(h, w),
        "color_rad": crad.reshape(h, w),
        "t_rel_rad": trel.reshape(h, w),
        "robust": robust.reshape(h, w),
        "robust_geometry": robust_geometry.reshape(h, w),
        "t_lo": t_b[:, 0].reshape(h, w),
        "t_hi": t_b[:, 1].reshape(h, w),
        "color_lo": c_lo.reshape(h, w, 3),
        "color_hi": c_hi.reshape(h, w, 3),
        "normal_lo": n_lo.reshape(h, w, 3),
        "normal_hi": n_hi.reshape(h, w, 3),
    }
    if terms:
        out["terms"] = {k: v.reshape(h, w, 3) for k, v in term.items() if v.any()}
    return out
