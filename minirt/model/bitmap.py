"""The bitmap as a tracer writes it: output encoding and image layout (the output rules).

The exercise's bitmap is the colour clamped to [0, 1] and written as ``floor(c·255 + 0.5)``, no
gamma, rows top-down, channels R G B. Tracers that students write differ here as often as in the
model, so each of these is a rule (minirt.model.rules.OUTPUT_RULES); none of them changes what is traced:

- ``encoding``: ``"round"`` floor(c·255 + 0.5) (ours); ``"floor256"`` min(255, floor(256·c)) (the
  2014 edition's bitmap writer); ``"floor"`` floor(c·255);
- ``gamma``: ``"linear"`` (none), ``"srgb"`` (the sRGB transfer function, IEC 61966-2-1) or ``"2.2"``
  (c^(1/2.2)), applied to the clamped colour before quantising;
- ``transpose``: x and y swapped (the image is H×W for a W×H scene); ``rows``: ``"bottom-up"`` stores
  the last row first (BMP's native order written as if top-down); ``channels``: ``"bgr"`` swaps red
  and blue. Applied in that order: transpose, then rows, then channels.

``bitmap(color, rules)`` is what ``minirt render`` writes as the PNG; ``undo_layout`` brings an image
written with some layout back to the scene's own (row-major, top-down, RGB), which is where the
grader compares.
"""

from __future__ import annotations

from typing import Any

import numpy as np


def channel_max(d: np.ndarray) -> np.ndarray:
    """(..., C) -> (...): each pixel's largest channel, the same values as ``d.max(-1)`` (NaN where a channel
    is). An elementwise maximum of the channel planes: NumPy's reduction over a short last axis takes ~20
    times as long (1.2 ms against 66 us for 256^2 pixels), and a rule diagnosis compares a thousand images."""
    out = d[..., 0]
    for k in range(1, d.shape[-1]):
        out = np.maximum(out, d[..., k])
    return out


def channel_any(m: np.ndarray) -> np.ndarray:
    """(..., C) bool -> (...): whether any channel is set, as ``m.any(-1)`` (``channel_max``'s reason)."""
    out = m[..., 0]
    for k in range(1, m.shape[-1]):
        out = out | m[..., k]
    return out


def transfer(c: np.ndarray, gamma: str) -> np.ndarray:
    """The clamped colour through the gamma rule's transfer function (values stay in [0, 1])."""
    c = np.clip(np.nan_to_num(np.asarray(c, dtype=np.float64), nan=0.0), 0.0, 1.0)
    if gamma == "linear":
        return c
    if gamma == "srgb":
        return np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.power(c, 1 / 2.4) - 0.055)
    if gamma == "2.2":
        return np.power(c, 1 / 2.2)
    raise ValueError(f"unknown gamma {gamma!r}")


def quantise(c: np.ndarray, encoding: str) -> np.ndarray:
    """Values in [0, 1] (after ``transfer``) to 8-bit levels."""
    if encoding == "round":
        q = np.floor(c * 255.0 + 0.5)
    elif encoding == "floor256":
        q = np.minimum(255.0, np.floor(256.0 * c))
    elif encoding == "floor":
        q = np.floor(c * 255.0)
    else:
        raise ValueError(f"unknown encoding {encoding!r}")
    return q.astype(np.uint8)


def encode(color: np.ndarray, encoding: str = "round", gamma: str = "linear") -> np.ndarray:
    """(H, W, 3) linear colour before clamping -> (H, W, 3) uint8 in the scene's layout.

    The same levels as ``quantise(transfer(color, gamma), encoding)`` for every input, in one scratch
    buffer: fmax/fmin clamp as nan_to_num then clip do (NaN -> 0, +inf -> 1, -inf -> 0; only the sign of
    a zero may differ, and every encoding writes either zero as level 0), and the encoding's arithmetic is
    the same float64 operations in place. A grade encodes whole candidate images dozens of times; the
    temporaries of nan_to_num, clip and the encodings were most of that time."""
    c = np.asarray(color, dtype=np.float64)
    if gamma != "linear":
        return quantise(transfer(c, gamma), encoding)
    buf = np.fmax(c, 0.0)
    np.fmin(buf, 1.0, out=buf)
    if encoding == "round":
        buf *= 255.0
        buf += 0.5
    elif encoding == "floor256":
        buf *= 256.0
    elif encoding == "floor":
        buf *= 255.0
    else:
        raise ValueError(f"unknown encoding {encoding!r}")
    if encoding == "floor256":
        np.minimum(buf, 255.0, out=buf)  # min(floor(x), 255) = floor(min(x, 255)): 255 is a level
    # The floor is the cast's: every value is in [0, 255.5] here, and a float's conversion to an integer
    # truncates towards zero, which is the floor of a value >= 0 (one pass fewer over the image).
    return buf.astype(np.uint8)


def apply_layout(img: np.ndarray, rows: str = "top-down", channels: str = "rgb", transpose: bool = False) -> np.ndarray:
    """An image in the scene's layout as a tracer with these layout rules stores it."""
    out = img
    if transpose:
        out = np.swapaxes(out, 0, 1)
    if rows == "bottom-up":
        out = out[::-1]
    if channels == "bgr":
        out = out[..., ::-1]
    return np.ascontiguousarray(out)


def undo_layout(img: np.ndarray, rows: str = "top-down", channels: str = "rgb", transpose: bool = False) -> np.ndarray:
    """The inverse of ``apply_layout``: a stored image back in the scene's layout."""
    out = img
    if channels == "bgr":
        out = out[..., ::-1]
    if rows == "bottom-up":
        out = out[::-1]
    if transpose:
        out = np.swapaxes(out, 0, 1)
    return np.ascontiguousarray(out)


def layout_of(rules: Any) -> dict[str, Any]:
    return {"rows": rules.rows, "channels": rules.channels, "transpose": rules.transpose}


def bitmap(color: np.ndarray, rules: Any) -> np.ndarray:
    """The 8-bit bitmap a tracer following ``rules`` writes for this colour buffer."""
    return apply_layout(encode(color, rules.encoding, rules.gamma), **layout_of(rules))


def is_default(rules: Any) -> bool:
    """Are the output rules the exercise's own (so the bitmap is ``RenderResult.color8()``)?"""
    return (rules.encoding, rules.gamma, rules.rows, rules.channels, rules.transpose) == (
        "round",
        "linear",
        "top-down",
        "rgb",
        False,
    )
