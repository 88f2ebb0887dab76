"""The recursion of TraceRay: levels of reflected rays, traced and combined back to front.

TraceRay's recursion runs in one kernel: the reflections in a Dr.Jit loop, the first level before it in
straight-line code (from ``LOOP_FIRST_LEVEL_BELOW`` rays) or as its first iteration (the shading code
compiled once), each packet of rays skipping what none of its rays needs (``trace_fused``). Above
``WAVEFRONT_MIN_BALLS`` balls, and for recorded levels, it is traced as a wavefront instead: one kernel
per reflection level over all rays of that level, then only the rays that hit something reflective are
compacted (``dr.compress``) into the next level. Either way colours are combined back to front,
``c = local + kr * c_child``, which is exactly the recursive form's arithmetic, and the two give the
same bits. Each level is shaded by minirt.reference.shading (``shade_level``); the first level's
outputs are written into the film's buffers (minirt.reference.film) by the kernel that computes them.
``tr`` holds the settings of the tracer whose kernel is being built (minirt.reference.settings.TraceSettings).
"""

from __future__ import annotations

from collections.abc import Collection
from typing import Any

import drjit as dr

from minirt.model.result import TERMS
from minirt.reference import film, shading
from minirt.reference.settings import TraceSettings
from minirt.reference.shading import Level

# Below this many rays a trace runs its first level as the loop's first iteration (``_levels_looped``): the
# kernel holds the intersection and shading code once, not twice (three_balls: ~910 Dr.Jit operations
# instead of ~1,380; LLVM's compile ~100 instead of ~150 ms), and at 256^2 it also runs faster (render
# 2.3 against 2.5 ms; with diagnostics 2.7 against 3.3). At 1024^2 the straight-line first level wins
# (f64 trace 9.6 against 10.0 ms, render 15.4 against 16.8: a first level before the loop folds the
# camera's constant origin into its arithmetic), so from 2^18 rays -- where a launch costs milliseconds
# and the kernel is compiled once for many -- the trace keeps it.
LOOP_FIRST_LEVEL_BELOW = 1 << 18


def first_level_looped(tr: TraceSettings, rays: int) -> bool:
    """Whether a trace of this many rays runs its first level as the loop's first iteration (and its
    primary rays read the image's width at run time): below ``LOOP_FIRST_LEVEL_BELOW`` rays, or always
    where the tracer says so (``Tracer(looped=True)``: a rule diagnosis, whose whole images then share the
    kernel its subsets compile -- an 800² grade compiled ~0.4 CPU-s less -- at a run time within a few
    per cent)."""
    return tr.looped or rays < LOOP_FIRST_LEVEL_BELOW


# From this many balls (through the shape table) Tracer.trace runs as a wavefront: the one-kernel trace's
# packets carry rays that stopped reflecting through every later level's tree traversal, which costs more
# than compacting them away once traversal dominates. Measured, 512^2, max_depth 3, warm trace, fused /
# wavefront: 16 balls 24.8 / 30.9 ms, 128: 84 / 92, 256: 134 / 140, 512: 188 / 177, 1,024: 285 / 247,
# 10,000: 804 / 597.
WAVEFRONT_MIN_BALLS = 384


def trace(
    tr: TraceSettings,
    o,
    d,
    record: bool = False,
    tree: bool = False,
    out: dict[str, Any] | None = None,
    terms: Collection[str] | None = None,
    path: str = "auto",
) -> tuple[Any, list[Level]]:
    """TraceRay for a batch: returns the colour of each ray and its levels (the first level's rays,
    hits and terms first).

    ``path`` "fused": every level in one kernel (``trace_fused``); "wavefront": each level a kernel
    of its own, the rays that go on compacted between them; "auto": the wavefront with ``record``
    (whose levels keep every ray's values) and from ``WAVEFRONT_MIN_BALLS`` balls (a tree's traversal
    then costs most, and runs faster over compacted, coherent packets), else fused. The same
    operations on the same values either way, so the same bits (tested).

    Memory traffic is what limits a wavefront, so each level writes only what is read later:
    every level its hit ids and local colour (the reflection colour and the background are
    re-derived from the ids in the combining pass); the first level, or every level when
    ``record``, also its terms, t, hit points and normals.

    ``out`` (a dict to fill): the first level's outputs are written by the kernels that compute
    them, straight into the buffers NumPy reads (minirt.reference.film), instead of being stored per
    component and copied by a read-out kernel afterwards. ``out`` then holds "color", "position",
    "normal", "term.<name>" (``film.read`` reads either layout) and "t" (N, float64);
    the first level's colour, terms, hit points and normals are not kept per component (unless
    ``record``). ``terms``: the names of the terms written to ``out`` (default every term the
    effects compute); the others still add to the colour, but their 32 bytes a ray are never written.
    """
    if path not in ("auto", "fused", "wavefront"):
        raise ValueError(f"unknown path {path!r} (auto, fused, wavefront)")
    if path == "auto":
        path = choose_path(tr, record, tree)
    if path == "fused":
        if record:
            raise ValueError("record needs the wavefront path")
        return trace_fused(tr, o, d, out, terms, tree)
    return _wavefront(tr, o, d, record, tree, out, terms)


def _wavefront(
    tr: TraceSettings, o, d, record: bool, tree: bool, out: dict[str, Any] | None, terms: Collection[str] | None
) -> tuple[Any, list[Level]]:
    """``trace`` as a wavefront: each level a kernel of its own, the rays that go on compacted between them."""
    with dr.scoped_set_flag(dr.JitFlag.FastMath, False):
        levels: list[Level] = []
        parent = None
        depth = tr.effects.reflection_depth if tr.effects.reflection else 0
        for level in range(depth + 1):
            lvl, spawn = shading.shade_level(tr, o, d, parent, depth - level, record, margins=tree and level == 0)
            levels.append(lvl)
            # One fused kernel per level: everything later steps read is evaluated together, so
            # nothing (intersection, shadow rays) is recomputed when it is read back.
            outputs = [lvl.shape_id, lvl.local]
            if tree:
                outputs.append(lvl.code)
                if "shadow_margin" in lvl.record:
                    outputs.append(lvl.record["shadow_margin"])
            if level == 0 and out is not None:
                vectors = {"position": lvl.p, "normal": lvl.n} | {
                    "term." + k: v for k, v in lvl.terms.items() if terms is None or k in terms
                }
                outputs += film.planar_out(out, vectors, lvl.shape_id >= 0, masked=("position", "normal"))
                out["t"] = dr.llvm.Float64(lvl.t)
                outputs.append(out["t"])
                if record:
                    outputs += [lvl.t, lvl.p, lvl.n, lvl.terms]
            elif level == 0 or record:
                outputs += [lvl.t, lvl.p, lvl.n, lvl.terms]
            if spawn is None:
                dr.eval(*outputs)
                break
            ro, rd = lvl.record["next"]
            dr.eval(*outputs, spawn, ro, rd)
            idx = dr.compress(spawn)
            if dr.width(idx) == 0:
                break
            lvl.spawn, lvl.slot = spawn, dr.prefix_sum(tr.T.UInt(spawn))
            o, d, parent = dr.gather(tr.T.Array3, ro, idx), dr.gather(tr.T.Array3, rd, idx), idx
        # Back to front: c = ambient + diffuse + specular + kr * trace(reflected) + background.
        # A ray's reflected colour is gathered from the next level through its slot (0 where it
        # spawned none): fused into this level's kernel, where a scatter into zeros would cost a
        # memset and a kernel of its own per level.
        child = child_tree = None
        for k in range(len(levels) - 1, -1, -1):
            lvl = levels[k]
            c = lvl.local
            if tree:  # the decisions of the whole ray tree below this ray, hashed (collisions only hide)
                below = tr.T.UInt(0)
                if child_tree is not None:
                    below = dr.gather(tr.T.UInt, child_tree, lvl.slot, active=lvl.spawn)
                lvl.record["tree"] = _tree_hash(tr.T.UInt(lvl.code), below)
                child_tree = lvl.record["tree"]  # evaluated with this level's colour, in one kernel
            if tr.effects.reflection:
                refl = tr.T.zero3()
                if child is not None:
                    refl = dr.gather(tr.T.Array3, child, lvl.slot, active=lvl.spawn)
                lvl.terms["reflection"] = lvl.kr * refl
                c = c + lvl.terms["reflection"]
            if tr.effects.background:
                lvl.terms["background"] = lvl.bg
                c = c + lvl.bg
            extra = [lvl.record["tree"]] if tree else []
            if k == 0 and out is not None:
                late = [k for k in ("reflection", "background") if k in lvl.terms and (terms is None or k in terms)]
                vectors = {"color": c} | {"term." + name: lvl.terms[name] for name in late}
                written = film.planar_out(out, vectors)
                dr.eval(*extra, *written, *([c, lvl.terms] if record else []))
            elif k == 0 or record:
                dr.eval(c, lvl.terms, *extra)
            else:
                dr.eval(c, *extra)
            child = c
        return child, levels


def choose_path(tr: TraceSettings, record: bool, tree: bool = False) -> str:
    """The path ``trace(path="auto")`` takes. With ``tree`` (each pixel's decisions and shadow margins, what a
    check's reference and the rule diagnosis trace) the fused path, whatever the balls: the wavefront then
    stores and compacts those per level too, and ran 3x slower (warm, tree, fused / wavefront: 1,024 balls
    at 128² 36 / 62 ms, at 512² 294 / 646; 10,000 balls at 128² 78 / 238, at 512² 757 / 2,386)."""
    many = tr.values.tabled_balls >= WAVEFRONT_MIN_BALLS
    return "wavefront" if record or (many and not tree) else "fused"


def trace_fused(
    tr: TraceSettings, o, d, out: dict[str, Any] | None, terms: Collection[str] | None, tree: bool = False
) -> tuple[Any, list[Level]]:
    """``trace`` in one kernel: the first level in straight-line code, the deeper ones in a Dr.Jit loop
    (one iteration per reflection), then the colours combined back to front. Below
    ``LOOP_FIRST_LEVEL_BELOW`` rays the first level is the loop's first iteration instead
    (``_levels_looped``): the same operations, the shading code in the kernel once.

    A wavefront stores each level's rays, ids and colours and compacts the rays that go on; here a
    ray's levels stay in registers and a packet of rays leaves the loop when its last ray stops
    reflecting (three_balls 1024^2, f64: 21.6 -> 16.1 ms; f32 13.2 -> 8.5 ms). What the combination
    needs of each deeper level is carried through the loop: its local colour and its hit id, from
    which the reflection colour and the background are re-derived as the wavefront's combining pass
    does (an id of -2: the level was not reached, its colour 0 -- what the wavefront gathers for a
    ray that spawned none). Every level computes what ``shade_level`` computes, in the same order.

    The first level's outputs (``out``, ``terms``: as for ``trace``) are written by this kernel. Without
    ``out`` nothing is evaluated: the colour and the first level's arrays are Dr.Jit expressions, and
    what the caller evaluates together runs as one kernel (``dr.eval(c, levels[0].t)``); each array
    evaluated on its own would run a kernel of its own (the same bits, more time); a component that is
    one constant for every ray (a lone plane's normal) may be an array of width 1. Evaluating only
    the colour skips the 160 bytes a ray of first-level arrays: 18.2 -> 14.7 ms on three_balls 1024^2.

    ``tree``: as for ``trace``, the first level's record holds "tree" (each deeper level's decision code
    is carried through the loop like its id and hashed back to front as the wavefront does) and
    "shadow_margin" (a miss's is shadow_margin's 1e30, which the shading's conditional gives it)."""
    fx = tr.effects
    depth = fx.reflection_depth if fx.reflection else 0
    with dr.scoped_set_flag(dr.JitFlag.FastMath, False):
        rays = max(dr.width(a[k]) for a in (o, d) for k in range(3))
        if depth > 0 and first_level_looped(tr, rays):
            return _trace_looped(tr, o, d, rays, depth, out, terms, tree)
        lvl, spawn = shading.shade_level(tr, o, d, None, depth, False, margins=tree, gate=True)
        refl, below = None, tr.T.UInt(0)
        if fx.reflection:
            refl = tr.T.zero3()
            if spawn is not None:
                refl, below = _reflected(tr, spawn, *lvl.record.pop("next"), depth, tree)
        c = _first_colour(tr, lvl, refl)
        if tree:
            lvl.record["tree"] = _tree_hash(tr.T.UInt(lvl.code), below)
        if out is None:  # lazy: the caller evaluates what it reads with the colour, in one kernel
            return c, [lvl]
        # The first level is straight-line code here: its buffers are the kernel's own outputs (``film.
        # planar_out``), in the order the packet buffers of the loop's path are made.
        wanted = term_names(tr, terms)
        vectors = {"color": c, "position": lvl.p, "normal": lvl.n} | {"term." + k: lvl.terms[k] for k in wanted}
        written = film.planar_out(out, vectors, lvl.shape_id >= 0, masked=("position", "normal"))
        out["t"] = dr.llvm.Float64(lvl.t)
        extra = [lvl.record[k] for k in ("tree", "shadow_margin") if k in lvl.record]
        dr.eval(out["t"], lvl.shape_id, *extra, *written)
        return c, [lvl]


def _trace_looped(tr: TraceSettings, o, d, rays: int, depth: int, out, terms, tree: bool) -> tuple[Any, list[Level]]:
    """``trace_fused`` with the first level as the loop's first iteration (``_levels_looped``)."""
    if out is None:
        lvl, c = _levels_looped(tr, o, d, rays, depth, tree)
        return c, [lvl]
    wanted = term_names(tr, terms)
    bufs = film.out_buffers(["color", "position", "normal"] + ["term." + k for k in wanted], rays)
    lvl, c = _levels_looped(tr, o, d, rays, depth, tree, bufs, wanted)
    late = {"term." + k: lvl.terms[k] for k in ("reflection", "background") if k in wanted}
    film.queue_out(bufs, late, rays)
    return _write_first(tr, out, bufs, lvl, c, rays)


def term_names(tr: TraceSettings, terms: Collection[str] | None) -> list[str]:
    """The terms a first level has (those the effects compute), among ``terms`` (None: all), in TERMS' order."""
    return [k for k in TERMS if getattr(tr.effects, k) and (terms is None or k in terms)]


def _first_colour(tr: TraceSettings, lvl: Level, refl) -> Any:
    """The first level's colour: its local colour, plus kr times the reflected colour ``refl`` (None: no
    reflection effect) and the background, each also kept as a term."""
    c = lvl.local
    if refl is not None:
        lvl.terms["reflection"] = lvl.kr * refl
        c = c + lvl.terms["reflection"]
    if tr.effects.background:
        lvl.terms["background"] = lvl.bg
        c = c + lvl.bg
    return c


def _write_first(
    tr: TraceSettings, out: dict[str, Any], bufs: dict[str, Any], lvl: Level, c, rays: int
) -> tuple[Any, list[Level]]:
    """The end of a fused trace with ``out``: the colour's writes queued after the first level's, the
    buffers into ``out`` with t, and the one kernel run (with the diagnostics, when recorded)."""
    film.queue_out(bufs, {"color": c}, rays)
    del bufs["zero"]
    out.update(bufs)
    out["t"] = dr.llvm.Float64(lvl.t)
    extra = [lvl.record[k] for k in ("tree", "shadow_margin") if k in lvl.record]
    dr.eval(out["t"], lvl.shape_id, *extra)  # runs the scatters too
    return c, [lvl]


def _levels_looped(
    tr: TraceSettings, o, d, rays: int, depth: int, tree: bool = False, bufs: dict[str, Any] | None = None, wanted=()
) -> tuple[Level, Any]:
    """Levels 0 .. depth in one Dr.Jit loop, the first level its first iteration: the shading code is
    in the kernel once (a third less to compile), and what later steps read of the first level (t,
    hit point, normal, terms) is carried through the loop like every level's colour and id -- or,
    with ``bufs`` (``film.out_buffers``), its hit point, normal and the ``wanted`` terms among ambient,
    diffuse and specular are written there by the first iteration and not carried (the level's p, n
    and those terms are then absent): carried, they cost an f64 render a fifth more time. ``tree``:
    each level's decision code is carried too, and the first level's shadow margins (computed in the
    first iteration only). Returns the first level and the colour, combined back to front
    as ``_reflected`` does (and with ``tree`` the ray-tree hash in its record)."""
    T, fx = tr.T, tr.effects
    shaded = [k for k in ("ambient", "diffuse", "specular") if getattr(fx, k)]
    carried = shaded if bufs is None else []
    zf = dr.zeros(T.Float, rays)

    def z3():
        return T.Array3(dr.zeros(T.Float, rays), dr.zeros(T.Float, rays), dr.zeros(T.Float, rays))

    o, d = T.Array3(o) + z3(), T.Array3(d) + z3()  # every loop variable as wide as the rays
    margins = tree and shading.has_margins(tr)
    first = [zf] + ([zf] if margins else []) + ([z3(), z3()] if bufs is None else []) + [z3() for _ in carried]
    local = [z3() for _ in range(depth + 1)]
    ids = [dr.full(T.Int, -2, rays) for _ in range(depth + 1)]
    codes = [dr.zeros(T.Int, rays) for _ in range(depth + 1)] if tree else []
    nf, m = len(first), depth + 1

    def body(k, active, ro, rd, *state):
        first, local = list(state[:nf]), list(state[nf : nf + m])
        ids, codes = list(state[nf + m : nf + 2 * m]), list(state[nf + 2 * m :])
        at0 = k == 0
        lvl, spawn = shading.shade_level(tr, ro, rd, None, 1, False, margins=at0 if tree else False, gate=True)
        new = [lvl.t] + ([lvl.record["shadow_margin"]] if margins else [])
        new += ([lvl.p, lvl.n] if bufs is None else []) + [lvl.terms[name] for name in carried]
        first = [dr.select(at0, a, b) for a, b in zip(new, first, strict=True)]
        if bufs is not None:
            vectors = {"position": lvl.p, "normal": lvl.n} | {"term." + k: lvl.terms[k] for k in shaded if k in wanted}
            hit = lvl.shape_id >= 0

            def write(vectors, hit):
                film.queue_out(bufs, vectors, rays, hit, ("position", "normal"))

            dr.if_stmt((vectors, hit), at0, write, lambda vectors, hit: None, label="first level")
        _keep_level(k, lvl, local, ids, codes)
        k = k + 1
        return (k, spawn & (k <= depth), *lvl.record["next"], *first, *local, *ids, *codes)

    state = dr.while_loop(
        (dr.zeros(T.UInt, rays), dr.full(T.Bool, True, rays), o, d, *first, *local, *ids, *codes),
        lambda k, active, *_: active,
        body,
        label="levels",
    )
    first, local = state[4 : 4 + nf], state[4 + nf : 4 + nf + m]
    ids, codes = state[4 + nf + m : 4 + nf + 2 * m], state[4 + nf + 2 * m :]
    refl, below = _combine(tr, local[1:], ids[1:], codes[1:])
    shape_id = ids[0]
    t, rest = first[0], first[2:] if margins else first[1:]
    p, n = rest[:2] if bufs is None else (None, None)
    kr = tr.values.material(shape_id, "reflection")
    terms = dict(zip(carried, first[nf - len(carried) :], strict=True))
    lvl = Level(None, o, d, shape_id, t, p, n, local[0], kr, shading.background(tr, shape_id >= 0), terms)
    if tree:
        lvl.code = codes[0]
        lvl.record["tree"] = _tree_hash(T.UInt(codes[0]), below)
        if margins:
            lvl.record["shadow_margin"] = first[1]
    return lvl, _first_colour(tr, lvl, refl)


def _reflected(tr: TraceSettings, active, ro, rd, depth: int, tree: bool = False) -> tuple[Any, Any]:
    """The colour ``trace`` gives the reflected rays (ro, rd) where ``active``, 0 elsewhere: levels 1 ..
    depth in a Dr.Jit loop (see ``trace_fused``); and, with ``tree``, the hash of their ray trees (0
    where not active; without ``tree`` a constant 0)."""
    T = tr.T
    n = dr.width(active)
    local = [T.Array3(dr.zeros(T.Float, n), dr.zeros(T.Float, n), dr.zeros(T.Float, n)) for _ in range(depth)]
    ids = [dr.full(T.Int, -2, n) for _ in range(depth)]
    codes = [dr.zeros(T.Int, n) for _ in range(depth)] if tree else []
    k = dr.zeros(T.UInt, n)

    def body(k, active, ro, rd, *levels):
        local, ids, codes = list(levels[:depth]), list(levels[depth : 2 * depth]), list(levels[2 * depth :])
        # depth_left 1: the next rays are made at every level (the last one's go unused)
        lvl, spawn = shading.shade_level(tr, ro, rd, None, 1, False, gate=True)
        _keep_level(k, lvl, local, ids, codes)
        k = k + 1
        return (k, spawn & (k < depth), *lvl.record["next"], *local, *ids, *codes)

    state = dr.while_loop(
        (k, active, ro, rd, *local, *ids, *codes), lambda k, active, *_: active, body, label="reflection levels"
    )
    return _combine(tr, state[4 : 4 + depth], state[4 + depth : 4 + 2 * depth], state[4 + 2 * depth :])


def _combine(tr: TraceSettings, local, ids, codes) -> tuple[Any, Any]:
    """The colour of the first of these levels (each level's local colour and hit id, as a loop
    carried them; id -2: not reached), combined back to front as the wavefront's combining pass
    does, and the hash of their ray trees (``codes``: each level's decisions; none: a constant 0)."""
    T, zero3 = tr.T, tr.T.zero3()
    c = None
    below = T.UInt(0)
    for j in range(len(local) - 1, -1, -1):
        shape_id = ids[j]
        reached = shape_id != -2
        cj = local[j] + tr.values.material(shape_id, "reflection") * (zero3 if c is None else c)
        if tr.effects.background:
            cj = cj + shading.background(tr, shape_id >= 0)
        c = dr.select(reached, cj, zero3)
        if codes:
            below = dr.select(reached, _tree_hash(T.UInt(codes[j]), below), T.UInt(0))
    return c, below


def _keep_level(k, lvl: Level, local: list, ids: list, codes: list) -> None:
    """In a loop over levels: slot k of the per-level lists (local colour, hit id, and with ``codes`` the
    decision code) takes this iteration's level's values, the other slots keep theirs."""
    for j in range(len(local)):
        here = k == j
        local[j] = dr.select(here, lvl.local, local[j])
        ids[j] = dr.select(here, lvl.shape_id, ids[j])
        if codes:
            codes[j] = dr.select(here, lvl.code, codes[j])


def _tree_hash(code, below) -> Any:
    """A ray's decisions (its level's code) and those of the tree below it (0: none), hashed (UInt32)."""
    return code * 0x9E3779B1 ^ (below * 0x85EBCA6B + 0x27D4EB2F)
