"""Rays through the image's pixels, in Dr.Jit: the camera's primary rays and supersampling's samples.

``primary_rays`` and ``sample_rays`` compute minirt.model.camera's rays with the same IEEE operations in
the same order, so the same bits (tested), without a round trip through NumPy. A supersampled render
(``render_samples``) averages stratified, jittered rays per pixel (camera.sample_offsets), a batch of
samples summed in one kernel, and keeps the per-pixel variances the harness compares with. ``tr``
holds the settings of the tracer whose kernels are being built (minirt.reference.settings.TraceSettings).
"""

from __future__ import annotations

from collections.abc import Collection
from typing import Any

import drjit as dr
import numpy as np

from minirt.jit import arrays as jitmem
from minirt.jit.arrays import aligned
from minirt.model import camera
from minirt.model.result import TERMS
from minirt.reference import film, integrator
from minirt.reference.settings import TraceSettings

# Sub-pixel offsets per kernel of a supersampled render (``_sample_batch``), 16 bytes a ray: 1 Mi rays, 4
# samples of 512^2 a kernel (512^2 at 16 samples, three_balls: 142 ms a sample a kernel; 117, 112, 127 ms
# at 32, 16, 8 MiB a batch -- smaller batches let NumPy draw the next offsets while a kernel runs).
SAMPLE_BATCH_BYTES = 1 << 24


def primary_rays(tr: TraceSettings, pixels: np.ndarray | None = None) -> tuple[Any, Any]:
    """camera.primary_rays computed in Dr.Jit: the same IEEE operations in the same order, so
    the same bits (tested), without a round trip through NumPy. ``pixels``: row-major indices of
    the pixels wanted (default every pixel)."""
    with dr.scoped_set_flag(dr.JitFlag.FastMath, False):  # FastMath turns / w into * (1 / w)
        uv = tr.values.number("pixel_uv") if tr.runtime else 0.0 if tr.rules.pixel_sample == "corner" else 0.5
        return rays(tr, tr.T.Float, tr.T.Array3, uv, uv, pixels)


def rays(tr: TraceSettings, F, A3, u, v, pixels: np.ndarray | None = None) -> tuple[Any, Any]:
    """camera.rays_through in Dr.Jit arithmetic of type F (A3 its 3-vector): the same operations in
    the same order. u, v: sub-pixel offsets, numbers or arrays of F.

    Under ``runtime`` the pixel indices are an input array and the camera rules are values read at
    run time: the shift is always added (x + u >= +0, so adding +0.0 changes no bit) and the
    origin is a select between both rules' origins."""
    sc = tr.scene
    w, h = sc.camera.width, sc.camera.height
    U32 = dr.llvm.UInt32
    if pixels is not None:
        idx = U32(aligned(pixels, np.uint32))
    elif tr.runtime:
        idx = U32(aligned(np.arange(w * h), np.uint32))  # an input, like a subset's: the same kernel
    else:
        idx = dr.arange(U32, w * h)
    n = dr.width(idx)
    # Below LOOP_FIRST_LEVEL_BELOW rays (minirt.reference.integrator), where a kernel's compile outweighs its
    # runs, the width is a value the kernel reads (the height always is), so a scene rendered at another size
    # (a sweep's sizes, a test's) reuses the compiled kernel; the row is then floor(idx / w) in float64 --
    # exact: idx < 2^28 and w <= 2^14, so the quotient is within 2^-25 of idx / w, whose distance below the
    # next integer is at least 1 / w >= 2^-14 -- since a vector integer division by a run-time value is a
    # scalar division per lane. From there the width is compiled in: a run-time width cost the float32 trace
    # of three_balls at 1024^2 0.4 ms of 5.5 (interleaved A/B), float64 nothing. dr.opaque also keeps Dr.Jit
    # from turning the float division by a literal below into a multiplication by its reciprocal (one more
    # rounding), FastMath off or not.
    if integrator.first_level_looped(tr, n):
        wi = dr.opaque(U32, w)
        yi = U32(dr.floor(dr.llvm.Float64(idx) / dr.llvm.Float64(wi)))
    else:
        wi = w
        yi = idx // w
    xi = idx - yi * wi
    fx, fy = F(xi) + u, F(yi) + v
    if tr.runtime:
        fx = fx + tr.values.number("shift_x", F)
        fy = fy + tr.values.number("shift_y", F)
    else:
        sx, sy = tr.rules.pixel_shift
        if sx != 0:  # rule pixel_shift: added only when non-zero, so (0, 0) is the unshifted arithmetic
            fx = fx + float(sx)
        if sy != 0:
            fy = fy + float(sy)
    px = fx / dr.opaque(F, w) - 0.5
    py = -fy / dr.opaque(F, h) + 0.5
    pz = dr.zeros(F, n)
    cz = tr.values.camera_z(F)
    dx, dy, dz = px - 0.0, py - 0.0, pz - cz
    inv = 1.0 / dr.sqrt(dx * dx + dy * dy + dz * dz)  # one division, three products
    d = A3(dx * inv, dy * inv, dz * inv)
    at_camera = A3(0.0, 0.0, cz) + dr.zeros(A3, n)
    if tr.runtime:
        o = dr.select(tr.values.rule("camera_origin"), at_camera, A3(px, py, pz))
    else:
        o = at_camera if tr.rules.ray_origin == "camera" else A3(px, py, pz)
    return o, d


def render_samples(
    tr: TraceSettings,
    progress=None,
    y0: int = 0,
    y1: int | None = None,
    falloff: bool = False,
    terms: Collection[str] = TERMS,
) -> tuple[np.ndarray, dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Average `samples` stratified, jittered rays per pixel (see camera.sample_offsets).

    Also returns the per-pixel sample variance (unbiased, of one sample; divide by n for the
    mean's) of the colour and of the diffuse term (when among ``terms``, the terms summed), for
    statistical comparisons. ``falloff``: also
    the mean and variance of each sample's diffuse term over its squared distance to the light
    (aux diffuse_r2, variance_diffuse_r2) -- what a physical renderer's point light averages over
    the pixel, so the harness compares like with like however much r varies across the pixel.

    Rays (``sample_rays``) and the float64 sums stay in Dr.Jit; only the sub-pixel offsets come
    from NumPy (its seeded PCG64) and the sums go back once. The same additions in the same order
    as summing in NumPy, FastMath off (no fused multiply-adds), so the same bits.
    """
    sc = tr.scene
    w, n = sc.camera.width, sc.samples
    y1 = sc.camera.height if y1 is None else y1
    h = y1 - y0
    pixels = None if (y0, y1) == (0, sc.camera.height) else np.arange(y0 * w, y1 * w, dtype=np.uint32)
    count = w * h
    # Samples per kernel: as many as SAMPLE_BATCH_BYTES of sub-pixel offsets hold (16 bytes a ray), on
    # the one-kernel trace (the wavefront's levels are kernels of their own: a sample each).
    per = max(1, SAMPLE_BATCH_BYTES // (16 * count)) if integrator.choose_path(tr, False) == "fused" else 1
    sums: dict[str, Any] = {}
    with dr.scoped_set_flag(dr.JitFlag.FastMath, False):
        s = 0
        while s < n:
            b = min(per, n - s)
            if per == 1:
                u, v = camera.sample_offsets(n, s, count, start=y0 * w)
                add = _sample_terms(tr, *sample_rays(tr, u, v, pixels), terms, falloff)
                sums = add if s == 0 else {k: sums[k] + add[k] for k in add}
            else:
                uv = jitmem.empty((b, count, 2))
                for j in range(b):
                    camera.sample_offsets_into(uv[j], n, s + j, start=y0 * w)
                sums = _sample_batch(tr, uv, pixels, terms, falloff, sums)
            dr.eval(sums)  # one kernel per batch of samples; the graph never grows
            s += b
            if progress:
                progress(s, n)
    got = {k: v.reshape(h * w, 3) for k, v in film.interleave(tr.T, w, h, sums).items()}
    mean = got["color"] / n
    terms = {k[5:]: (v / n).reshape(h, w, 3) for k, v in got.items() if k.startswith("term.")}
    aux = {"variance": (np.maximum(got["color2"] - n * mean * mean, 0.0) / (n - 1)).reshape(h, w, 3)}
    if "diffuse2" in got:
        dm = got["term.diffuse"] / n
        aux["variance_diffuse"] = (np.maximum(got["diffuse2"] - n * dm * dm, 0.0) / (n - 1)).reshape(h, w, 3)
    if "diffuse_r2" in got:
        fm = got["diffuse_r2"] / n
        aux["diffuse_r2"] = fm.reshape(h, w, 3)
        aux["variance_diffuse_r2"] = (np.maximum(got["diffuse_r2_2"] - n * fm * fm, 0.0) / (n - 1)).reshape(h, w, 3)
    return mean.reshape(h, w, 3), terms, aux


def _sample_terms(tr: TraceSettings, o, d, terms: Collection[str], falloff: bool) -> dict[str, Any]:
    """What one sample adds to ``render_samples``' sums (Dr.Jit float64 3-vectors, lazy)."""
    A64 = dr.llvm.Array3f64
    c, levels = integrator.trace(tr, o, d)
    add = {"color": A64(c)} | {"term." + k: A64(v) for k, v in levels[0].terms.items() if k in terms}
    add["color2"] = add["color"] * add["color"]
    if "term.diffuse" in add:
        add["diffuse2"] = add["term.diffuse"] * add["term.diffuse"]
    if falloff and "term.diffuse" in add:
        lvl = levels[0]
        to_light = A64(lvl.p) - tr.values.k("light64", tr.scene.light.position, dr.llvm.Float64)
        r2 = dr.squared_norm(to_light)
        add["diffuse_r2"] = dr.select((lvl.shape_id >= 0) & (r2 > 0), add["term.diffuse"] / r2, 0.0)
        add["diffuse_r2_2"] = add["diffuse_r2"] * add["diffuse_r2"]
    return add


def _sample_names(tr: TraceSettings, terms: Collection[str], falloff: bool) -> list[str]:
    """The names of the sums ``_sample_terms`` adds to, known before any sample is traced."""
    names = ["color"] + ["term." + k for k in integrator.term_names(tr, terms)] + ["color2"]
    if "term.diffuse" in names:
        names += ["diffuse2"] + (["diffuse_r2", "diffuse_r2_2"] if falloff else [])
    return names


def _sample_batch(
    tr: TraceSettings, uv: np.ndarray, pixels, terms: Collection[str], falloff: bool, sums: dict[str, Any]
):
    """``sums`` plus the samples whose sub-pixel offsets are ``uv`` ((samples, rays, 2) float64, from
    ``camera.sample_offsets_into``), summed in a Dr.Jit loop in one kernel: the sums stay in registers
    from one sample to the next instead of a kernel per sample reading and writing them (240 bytes a
    ray), and Python builds the trace's graph once. Sums start from +0.0 (``sums`` empty): 0 + x is x
    but for the sign of a zero, which ``film.interleave`` makes canonical anyway, so the same bits as a
    kernel per sample."""
    F64, U32, A64 = dr.llvm.Float64, dr.llvm.UInt32, dr.llvm.Array3f64
    count = uv.shape[1]
    flat = F64(uv.reshape(-1))
    i = dr.arange(U32, count)
    if not sums:
        sums = {
            k: A64(dr.zeros(F64, count), dr.zeros(F64, count), dr.zeros(F64, count))
            for k in _sample_names(tr, terms, falloff)
        }
    names = list(sums)

    stride = dr.opaque(U32, count)  # a value, not a constant: one kernel for every image size

    def body(j, *acc):
        at = 2 * (j * stride + i)
        o, d = sample_rays(tr, dr.gather(F64, flat, at), dr.gather(F64, flat, at + 1), pixels)
        add = _sample_terms(tr, o, d, terms, falloff)
        assert set(add) == set(names), (sorted(add), names)  # _sample_names says what _sample_terms adds
        return (j + 1, *(a + add[k] for a, k in zip(acc, names, strict=True)))

    state = dr.while_loop(
        (dr.zeros(U32, count), *sums.values()),
        lambda j, *_: j < dr.opaque(U32, uv.shape[0]),
        body,
        label="samples",
    )
    return dict(zip(names, state[1:], strict=True))


def sample_rays(tr: TraceSettings, u, v, pixels: np.ndarray | None = None) -> tuple[Any, Any]:
    """camera.rays_through(scene, rules, u, v) in Dr.Jit: float64 like NumPy (so the same bits), then
    rounded to the tracer's precision as ``load`` would. u, v: NumPy or Dr.Jit float64 arrays."""
    F64 = dr.llvm.Float64
    with dr.scoped_set_flag(dr.JitFlag.FastMath, False):
        u, v = (aligned(x, np.float64) if isinstance(x, np.ndarray) else x for x in (u, v))
        o, d = rays(tr, F64, dr.llvm.Array3f64, F64(u), F64(v), pixels)
        return tr.T.Array3(o), tr.T.Array3(d)


def load(tr: TraceSettings, a: np.ndarray) -> Any:
    """Rays' origins or directions, (N, 3) NumPy float64, as a Dr.Jit 3-vector of the tracer's precision."""
    return tr.T.Array3(*(tr.T.Float(aligned(a[:, i], tr.T.np_dtype)) for i in range(3)))
