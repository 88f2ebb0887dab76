"""The image to explain (``Target``) and how a render is scored against it.

How an image is compared with a render (``Target.difference``, ``Target.score``)
-------------------------------------------------------------------------------
- An 8-bit image: the render's colour is written as the candidate's output rules say (gamma,
  encoding, layout; minirt.model.bitmap) and a pixel matches when every channel is within one level: a
  student's float32 arithmetic or another rounding order moves a value across a quantisation step,
  never by two levels (relative error ~1e-6 of a value <= 255 is ~3e-4 of a level).
- A float image (EXR, float TIFF, 16-bit): both are clamped to [0, 1], put through the gamma rule,
  and a pixel matches when every channel is within ``FLOAT_TOL``.
- Ill-conditioned pixels never count: a primary ray whose hit, closest shape or start inside a ball
  is within ``EPS_REL`` (a float32 tracer's rounding; minirt.diagnose.variants) of flipping
  (minirt.reference.band), a shadow ray that close to a ball's silhouette, a pixel whose float32 render
  differs from its float64 one (minirt.diagnose.search's ``Search.ill_at``, ``flips``). Comparing two
  candidates, a pixel ill-conditioned in either is left out of both scores, so such a pixel never
  decides between them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from minirt.model import bitmap
from minirt.model.rules import Rules

# Float images: half an 8-bit level (1/510 = 2.0e-3) is where the 8-bit image of the same values
# could first differ by a level; 2^-10 = 9.8e-4 sits below it and ~150x above a float32 tracer's
# colour error (~100 roundings of 2^-24 on values <= 1, 6e-6).
FLOAT_TOL = 2.0**-10


# Levels an 8-bit channel may differ by: one (a value on the other side of a rounding step).
LEVEL_TOL = 1


# ---------------------------------------------------------------------------------------------
@dataclass
class Target:
    """The image to explain, as stored (any layout), 8-bit levels or floats, three channels."""

    pixels: np.ndarray  # (rows, columns, 3) uint8 or float32
    is_float: bool
    name: str = ""
    _layouts: dict = field(default_factory=dict, repr=False)

    @property
    def shape(self) -> tuple[int, int]:
        return self.pixels.shape[0], self.pixels.shape[1]

    def in_layout(self, rules: Rules) -> np.ndarray:
        """The image brought back to the scene's layout under the candidate's layout rules (int16
        levels, or float32 clamped to [0, 1]); computed once per layout."""
        key = (rules.rows, rules.channels, rules.transpose)
        if key not in self._layouts:
            img = bitmap.undo_layout(self.pixels, **bitmap.layout_of(rules))
            self._layouts[key] = np.clip(img, 0.0, 1.0) if self.is_float else img.astype(np.int16)
        return self._layouts[key]

    def difference(self, color: np.ndarray, rules: Rules, idx: np.ndarray | None = None) -> np.ndarray | None:
        """Per pixel, the largest channel difference (levels, or float units) between the image and the
        colour written under ``rules``' output rules; None when the layout does not fit the size.
        ``color`` is (H, W, 3), or (N, 3) for the pixels ``idx``."""
        img = self.in_layout(rules)
        h, w = (color.shape[0], color.shape[1]) if idx is None else (None, None)
        if idx is None and img.shape[:2] != (h, w):
            return None
        if idx is not None:
            if img.shape[:2] != self.model_shape:
                return None
            img = img.reshape(-1, 3)[idx]
        if self.is_float:
            return bitmap.channel_max(np.abs(img - bitmap.transfer(color, rules.gamma)))
        enc = bitmap.encode(color, rules.encoding, rules.gamma)
        return bitmap.channel_max(np.abs(enc.astype(np.int16) - img))

    model_shape: tuple[int, int] = (0, 0)

    def score(self, d: np.ndarray, keep: np.ndarray | None = None) -> tuple[int, int]:
        """(pixels beyond tolerance, pixels exactly one level off), among ``keep``. The second breaks
        ties: encodings differ by at most one level, so only exact matches tell them apart, and a
        float32 tracer lands a level off only where a value sits on a rounding step (rare)."""
        if keep is not None:
            d = d[keep]
        if self.is_float:
            return int((d > FLOAT_TOL).sum()), 0
        return int((d > LEVEL_TOL).sum()), int((d == 1).sum())

    def off(self, d: np.ndarray) -> np.ndarray:
        """Pixels that are not an exact match: any level off (8-bit), beyond FLOAT_TOL (float)."""
        return d > FLOAT_TOL if self.is_float else d >= 1

    def beyond(self, d: np.ndarray) -> np.ndarray:
        """Pixels beyond tolerance: more than one level (8-bit), more than FLOAT_TOL (float)."""
        return d > (FLOAT_TOL if self.is_float else LEVEL_TOL)


def coded_levels(color: np.ndarray, rules: Rules, is_float: bool) -> np.ndarray:
    """A render's colour as an image of the target's kind holds it under ``rules``' output rules: 8-bit
    levels (int16) or the gamma's floats -- what ``Target.difference`` compares, without the layout."""
    if is_float:
        return bitmap.transfer(color, rules.gamma)
    return bitmap.encode(color, rules.encoding, rules.gamma).astype(np.int16)
