"""Student images for the grading tests, made independently of the fast tracer.

``student_image(scene, rules)`` is what a student's tracer following ``rules`` would store: the colour
from tests/support/plain.py (the recursive pure-Python transcription of the pseudo-code; primary rays from
minirt.model.camera, which carries ray_origin, pixel_sample and pixel_shift; plain carries every other trace
rule), optionally with float32-like noise (each channel times 1 + 2^-22·N(0, 1), a seeded NumPy
Generator: a float32 tracer's relative error is ~2^-24 per rounding, a few dozen of them), written with
the rules' output rules by minirt.model.bitmap (8-bit, as stored). Plain is pure Python: keep scenes small.
Plain renders are cached per (scene, traced rules) for the test session.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from minirt.model import bitmap, camera
from minirt.model.rules import Rules
from minirt.model.scene import Scene, load_scene
from support.plain import render_plain

ROOT = Path(__file__).resolve().parents[2]
NOISE = 2.0**-22

_PLAIN: dict[tuple, np.ndarray] = {}


def small_scene(stem: str = "rules", width: int = 64, height: int = 64) -> Scene:
    """A bundled scene at a small size, one ray per pixel (the exercise traces one)."""
    return load_scene(ROOT / "scenes" / f"{stem}.toml").with_overrides(width=width, height=height, samples=1)


def plain_color(scene: Scene, rules: Rules) -> np.ndarray:
    """(H, W, 3) float64 linear colour from tests/support/plain.py (cached per scene and traced rules)."""
    traced = rules.traced()
    key = (scene.digest, scene.source, scene.camera.width, scene.camera.height, traced)
    if key not in _PLAIN:
        o, d = camera.primary_rays(scene, traced)
        colors, _ = render_plain(scene, traced, o, d)
        h, w = scene.camera.height, scene.camera.width
        _PLAIN[key] = np.array(colors, dtype=np.float64).reshape(h, w, 3)
    return _PLAIN[key]


def noisy(color: np.ndarray, seed: int = 0) -> np.ndarray:
    """The colour with float32-like relative noise on every channel."""
    rng = np.random.Generator(np.random.PCG64(seed))
    return color * (1.0 + NOISE * rng.standard_normal(color.shape))


def student_color(scene: Scene, rules: Rules, noise: bool = True, seed: int = 0) -> np.ndarray:
    """The linear colour a student's tracer following ``rules`` computes (before writing)."""
    c = plain_color(scene, rules)
    return noisy(c, seed) if noise else c.copy()


def student_image(scene: Scene, rules: Rules, noise: bool = True, seed: int = 0) -> np.ndarray:
    """The 8-bit image, as stored, of a student's tracer following ``rules`` (trace and output rules)."""
    return bitmap.bitmap(student_color(scene, rules, noise, seed), rules)


def levels_off(a: np.ndarray, b: np.ndarray, tol: int = 1) -> int:
    """Pixels where two 8-bit images (same shape) differ by more than ``tol`` levels in some channel."""
    assert a.shape == b.shape, (a.shape, b.shape)
    return int((np.abs(a.astype(np.int16) - b.astype(np.int16)) > tol).any(-1).sum())
