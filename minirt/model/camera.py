"""Primary rays, exactly as the exercise builds them, shared by the tracer and every oracle.

Pixel (x, y), y = 0 the top row, sub-pixel position (u, v) in [0, 1)^2 measured from the pixel's
top-left corner: image-plane point ``((x + u)/W - 0.5, -(y + v)/H + 0.5, 0)``. The exercise's own
ray is (u, v) = (0, 0), the corner (rule ``pixel_sample = "corner"``); ``"center"`` is (0.5, 0.5).
Rule ``pixel_shift = (dx, dy)`` (pixels) shifts the whole grid: ``((x + u + dx)/W - 0.5, -(y + v +
dy)/H + 0.5, 0)``, computed as ``(x + u) + dx``, the addition only when the shift is non-zero.
Direction: normalise(point - camera); origin: the image-plane point (rule ``ray_origin =
"image-plane"``) or the camera (``"camera"``). Rays are returned row-major, (H*W, 3) float64.

Several samples per pixel (``samples = n > 1``) use a stratified, jittered pattern: a grid of
gx = ceil(sqrt(n)) columns and gy = ceil(n / gx) rows over the pixel, sample s in cell
(s mod gx, s div gx), jittered uniformly inside its cell by NumPy's PCG64 seeded with (seed, s).
Each sample index draws its own stream, so the pattern does not depend on batching.
"""

from __future__ import annotations

import math

import numpy as np

from minirt.model.rules import Rules
from minirt.model.scene import Scene

SAMPLE_SEED = 13_1  # fixed: renders are bit-reproducible


def pixel_grid(width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Row-major pixel coordinates (x, y) as float64 arrays of length W*H."""
    y, x = np.divmod(np.arange(width * height, dtype=np.int64), width)
    return x.astype(np.float64), y.astype(np.float64)


def rays_through(
    scene: Scene, rules: Rules, u: np.ndarray | float, v: np.ndarray | float, pixels: np.ndarray | None = None
):
    """Origins and unit directions of the rays through sub-pixel positions (u, v) of every pixel, or of
    the row-major pixel indices ``pixels`` only (each ray the same bits as in the whole image's)."""
    w, h = scene.camera.width, scene.camera.height
    if pixels is None:
        x, y = pixel_grid(w, h)
    else:
        yi, xi = np.divmod(np.asarray(pixels, dtype=np.int64), w)
        x, y = xi.astype(np.float64), yi.astype(np.float64)
    sx, sy = rules.pixel_shift
    fx, fy = x + u, y + v
    if sx != 0:  # rule pixel_shift: added only when non-zero, so (0, 0) is the unshifted arithmetic
        fx = fx + float(sx)
    if sy != 0:
        fy = fy + float(sy)
    px = fx / w - 0.5
    py = -fy / h + 0.5
    pz = np.zeros_like(px)
    cz = -scene.camera.distance
    # direction = point - camera, camera at (0, 0, -d); written out so the rounding is the exercise's
    dx, dy, dz = px - 0.0, py - 0.0, pz - cz
    inv = 1.0 / np.sqrt(dx * dx + dy * dy + dz * dz)  # one division, three products (the tracer's too)
    d = np.stack([dx * inv, dy * inv, dz * inv], axis=1)
    if rules.ray_origin == "camera":
        o = np.tile(np.array([0.0, 0.0, cz]), (x.size, 1))
    else:
        o = np.stack([px, py, pz], axis=1)
    return o, d


def primary_rays(scene: Scene, rules: Rules, pixels: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The one-ray-per-pixel rays (the rule ``pixel_sample`` says corner or centre), of every pixel or
    of the row-major indices ``pixels``."""
    uv = 0.0 if rules.pixel_sample == "corner" else 0.5
    return rays_through(scene, rules, uv, uv, pixels)


def stratified_grid(n: int) -> tuple[int, int]:
    gx = math.ceil(math.sqrt(n))
    return gx, math.ceil(n / gx)


def sample_offsets(
    n: int, s: int, count: int, seed: int = SAMPLE_SEED, start: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel positions (u, v) of sample s (of n) for `count` pixels from pixel `start` on (row-major):
    stratified and jittered. Pixel i takes the stream's draws 2i and 2i + 1 (one 64-bit output per
    double), so a tile skips 2 start draws (PCG64.advance) and gets exactly the whole image's values."""
    uv = sample_offsets_into(np.empty((count, 2)), n, s, seed, start)
    return uv[:, 0].copy(), uv[:, 1].copy()


def sample_offsets_into(out: np.ndarray, n: int, s: int, seed: int = SAMPLE_SEED, start: int = 0) -> np.ndarray:
    """``sample_offsets`` written into ``out`` ((count, 2) float64: u, v per pixel) in place, no temporaries:
    the same draws, then (c + j) / g as j + c (addition commutes exactly) and the division."""
    gx, gy = stratified_grid(n)
    bits = np.random.PCG64([seed, s])
    if start:
        bits.advance(2 * start)
    np.random.Generator(bits).random(out=out)
    u, v = out[:, 0], out[:, 1]  # column by column: NumPy broadcasts a pair over rows ~6x slower
    u += s % gx
    v += s // gx
    u /= gx
    v /= gy
    return out
