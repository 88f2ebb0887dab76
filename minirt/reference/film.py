"""The film: the buffers a render writes and NumPy reads, and the assembly of an image from its tiles.

A render's buffers -- colour, hit points, normals, terms -- are written by the kernels that compute
them, in one of two layouts. Where the first level is straight-line code (large renders), each
component is one of the kernel's own outputs (``planar_out``), which NumPy reads as three (h, w) arrays
(``read``: ``Planes``, stacked only if a reader asks for the (h, w, 3) array; an EXR writes the
components). Where the first level runs inside a loop (small renders) its values are not the kernel's
outputs; they are written from the loop as float64 (x, y, z, 0) packets, one per ray (``queue_out``),
viewed by NumPy as (h, w, 3) without a copy (``view3``). The two hold the same bits. What is read back
later goes through ``interleave``, one kernel over 3 N lanes. Zeros
are canonical (+0.0) in every buffer, so a skipped term and a computed zero carry the same bits. A
large image is rendered in tiles of whole rows (minirt.reference.tracer.Tracer.tiles), pasted into one
image here (``empty_like``, ``paste``).
"""

from __future__ import annotations

from typing import Any

import drjit as dr
import numpy as np

from minirt.model.result import Planes, RenderResult


def out_buffers(names, n: int) -> dict[str, Any]:
    """New float64 buffers of 4 n for ``queue_out`` (and "zero", an opaque 0.0), allocated now:
    allocating one later would run the kernel of the writes queued before it."""
    F64 = dr.llvm.Float64
    bufs = {name: dr.empty(F64, 4 * n) for name in names}
    bufs["zero"] = dr.opaque(F64, 0.0)
    dr.eval(bufs)
    return bufs


def queue_out(bufs: dict[str, Any], vectors: dict[str, Any], n: int, hit=None, masked=(), active=True) -> None:
    """Queue the writes of 3-vectors (width n, or 1: a constant) into buffers from ``out_buffers`` (where
    ``active``), (x, y, z, 0) per ray: they run in the next kernel, the one that computes them. NumPy views
    them as (n, 4)[:, :3] (``view3``). The same values as ``interleave``: the names in ``masked`` are 0 where
    ``hit`` is false, zeros canonical. This is how a loop writes its first level (its values are not the
    kernel's outputs; ``planar_out`` is the straight-line code's way).

    Four, not three, per ray: Dr.Jit writes a power-of-two packet from a vector register with contiguous
    stores, where a 3-vector is three scattered stores per lane -- slow on x86 (AVX-512 scatters): on
    three_balls 1024^2 one 3-vector buffer cost ~1.5 ms of scatters, a 4-packet ~0.25 ms, for a third
    more bytes. Every buffer is allocated before the first write is queued (``out_buffers``)."""
    A64, A4 = dr.llvm.Array3f64, dr.llvm.Array4f64
    zero = bufs["zero"]
    i = dr.arange(dr.llvm.UInt32, n)
    for name, v in vectors.items():
        x = A64(v)
        if name in masked:
            x = dr.select(hit, x, 0.0)
        x = x + zero
        # One packet per ray: element j at 4 j + k, in one scatter. Three scalar scatters into one
        # buffer would each run the kernel of the writes queued before them.
        dr.scatter(bufs[name], A4(x[0], x[1], x[2], zero), i, active)


def planar_out(out: dict[str, Any], vectors: dict[str, Any], hit=None, masked=()) -> list[Any]:
    """The 3-vectors as float64 Dr.Jit arrays in out[name], for the caller to evaluate as its kernel's own
    outputs (returned, in order): one array a component, written with the kernel's streaming stores -- a
    render's buffers in 1.1x the time of its trace, where 4-packet scatters (``queue_out``) took 2.1x
    (three_balls 1024^2, f64: benchmarks/bench.py, "planar_outputs"). The same values as ``queue_out``'s:
    the names in ``masked`` are 0 where ``hit`` is false, zeros canonical. A component that is one constant
    for every ray may stay an array of width 1 (``read`` widens it)."""
    A64 = dr.llvm.Array3f64
    zero = dr.opaque(dr.llvm.Float64, 0.0)
    written = []
    for name, v in vectors.items():
        x = A64(v)
        if name in masked:
            x = dr.select(hit, x, 0.0)
        out[name] = x + zero
        written.append(out[name])
    return written


def read(buf, h: int, w: int) -> np.ndarray | Planes:
    """A buffer of either layout as NumPy, without a copy: ``Planes`` of a ``planar_out`` vector (a
    width-1 component widened), the (h, w, 3) view of a ``queue_out`` packet buffer."""
    if not isinstance(buf, dr.llvm.Array3f64):
        return view3(buf, h, w)
    comps = (np.asarray(c) for c in buf)
    return Planes(c.reshape(h, w) if c.size == h * w else np.full((h, w), c[0]) for c in comps)


def view3(buf, h: int, w: int) -> np.ndarray:
    """A buffer written by ``queue_out`` as an (h, w, 3) NumPy view (no copy; strides 32 w, 32, 8)."""
    return np.asarray(buf).reshape(h, w, 4)[..., :3]


def interleave(T, w: int, h: int, vectors: dict[str, Any], shape_id=None, masked=(), also=()) -> dict[str, np.ndarray]:
    """3-vectors (Dr.Jit, any float type) to (h, w, 3) float64 NumPy arrays in one kernel over 3 N
    lanes; the names in ``masked`` are 0 where ``shape_id`` (ids of T.Int) < 0. ``also`` (arrays of width
    N) are evaluated with the vectors, in the kernel that computes them.

    Zeros are made canonical, x + 0.0 (-0.0 + 0.0 = +0.0), so a skipped term (exactly +0.0) and a
    computed zero (0 * negative = -0.0) give the same bits; the zero is opaque, or Dr.Jit's constant
    propagation would fold x + 0.0 into x."""
    F64, U32 = dr.llvm.Float64, dr.llvm.UInt32
    n = w * h
    with dr.scoped_set_flag(dr.JitFlag.FastMath, False):
        # What is read is evaluated first, together: a gather from an unevaluated expression evaluates
        # that expression alone, and a lazy trace's colour read component by component ran the whole
        # trace three times (and a fourth for ``also``'s shadow margins).
        dr.eval(*vectors.values(), *also, *([shape_id] if masked else []))
        zero = dr.opaque(F64, 0.0)
        j = dr.arange(U32, 3 * n)
        i = j // 3
        comp = j - 3 * i
        hit = dr.gather(T.Int, shape_id, i) >= 0 if masked else None
        bufs = {}
        for name, v in vectors.items():
            ftype = type(v[0])
            # A component that is one constant (the normal of a scene without shapes) is broadcast:
            # a gather from a width-1 array would read past its end.
            comps = [v[k] if dr.width(v[k]) == n else dr.full(ftype, v[k][0], n) for k in range(3)]
            x, y, z = (F64(dr.gather(ftype, c, i)) for c in comps)
            val = dr.select(comp == 0, x, dr.select(comp == 1, y, z))
            if name in masked:
                val = dr.select(hit, val, 0.0)
            bufs[name] = val + zero
        dr.eval(bufs)
        dr.sync_thread()
    return {k: np.asarray(b).reshape(h, w, 3) for k, b in bufs.items()}


def to_numpy3(T, a, also=()) -> np.ndarray:
    """(N, 3) float64 from a Dr.Jit 3-vector of N rays, zeros canonical (see ``interleave``); ``also``
    (arrays the caller reads next) evaluated in the same kernel as ``a``."""
    n = max(dr.width(a[k]) for k in range(3))
    return interleave(T, n, 1, {"v": a}, also=also)["v"].reshape(n, 3)


def empty_like(tile: RenderResult, height: int) -> RenderResult:
    """A whole image's RenderResult with the buffers of ``tile`` (uninitialised, then pasted)."""

    def big(a):
        return None if a is None else np.empty((height, *a.shape[1:]), dtype=a.dtype)

    def big3(name):
        comps = tile.components(name)
        return None if comps is None else np.empty((height, tile.width, 3), dtype=comps[0].dtype)

    return RenderResult(
        backend=tile.backend, width=tile.width, height=height, color=big3("color"),
        terms={k: big3(k) for k in tile.terms_names()}, aux={k: big(v) for k, v in tile.aux.items()},
        meta=dict(tile.meta), hit=big(tile.hit), shape_id=big(tile.shape_id), t=big(tile.t),
        position=big3("position"), normal=big3("normal"),
    )  # fmt: skip


def paste(full: RenderResult, tile: RenderResult, y0: int) -> None:
    """A tile's rows into the whole image's buffers, from row y0 (a vector's components one by one: a
    tile's may be ``Planes``, never stacked)."""
    y1 = y0 + tile.height
    for name in ("hit", "shape_id", "t"):
        if getattr(tile, name) is not None:
            getattr(full, name)[y0:y1] = getattr(tile, name)
    for name in ("color", "position", "normal", *tile.terms_names()):
        comps = tile.components(name)
        if comps is not None:
            into = full.held(name)  # the whole image's: arrays (empty_like)
            for k, c in enumerate(comps):
                into[y0:y1, :, k] = c
    for k, v in tile.aux.items():
        full.aux[k][y0:y1] = v
