"""Hostile images for the tests of the image reader and of `minirt grade` (tests/io/test_images_hostile.py,
tests/cli/test_grade_hostile.py): a PNG whose header claims any size, RGBA files that store exactly the
bytes given, and hypothesis's garbling of small valid images of every supported type."""

from __future__ import annotations

import struct
import tempfile
import zlib
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
from hypothesis import strategies as st

from minirt.io.images import write_image

W, H = 8, 6
PIXELS = (np.arange(H * W * 3).reshape(H, W, 3) * 7 % 256).astype(np.uint8)
FORMATS = {".png": 3, ".bmp": 3, ".ppm": 3, ".pgm": 1, ".tga": 3, ".tif": 3, ".exr": 3}  # extension: channels


def png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def claiming_png(width: int, height: int, padding: int = 1_200_000) -> bytes:
    """A 1-bit grey PNG whose header claims ``width`` x ``height``, with 16 rows of real data and
    ``padding`` bytes of an ancillary chunk: as large as the 1.2 MB zlib bomb of the issue, so
    OpenImageIO's own sanity check (it refuses an image of 9536 MB from a file of a few kB) lets it
    through to minirt's."""
    row = b"\x00" + bytes((width + 7) // 8)
    return (
        b"\x89PNG\r\n\x1a\n"
        + png_chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 1, 0, 0, 0, 0))
        + png_chunk(b"zzZz", bytes(padding))  # private and ancillary: readers skip it
        + png_chunk(b"IDAT", zlib.compress(row * 16, 9))
        + png_chunk(b"IEND", b"")
    )


def write_unassociated(path: Path, rgba: np.ndarray) -> None:
    """An RGBA file storing exactly these bytes (OpenImageIO's writers would otherwise divide the colour
    by alpha, taking it for premultiplied)."""
    h, w, c = rgba.shape
    spec = oiio.ImageSpec(w, h, c, oiio.UINT8)
    spec.attribute("oiio:UnassociatedAlpha", 1)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec) and out.write_image(np.ascontiguousarray(rgba)) and out.close()


def stored_rgba(path: Path) -> np.ndarray:
    """What the file stores, read independently of minirt (unassociated)."""
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)
    inp = oiio.ImageInput.open(str(path), config)
    try:
        return np.asarray(inp.read_image(oiio.UINT8))
    finally:
        inp.close()


_VALID: dict[str, bytes] = {}


def valid_bytes(ext: str) -> bytes:
    """A small valid image of type ``ext``: PIXELS (grey for .pgm, float for .exr), made once."""
    if ext not in _VALID:
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / f"valid{ext}"
            c = FORMATS[ext]
            write_image(path, PIXELS[..., :c].astype(np.float32) / 255 if ext == ".exr" else PIXELS[..., :c])
            _VALID[ext] = path.read_bytes()
    return _VALID[ext]


@st.composite
def garbled(draw, least: int = 0) -> tuple[str, bytes]:
    """(extension, bytes): a valid image with bytes overwritten, inserted or removed (at least ``least``
    times), cut short -- or all of these, or none."""
    ext = draw(st.sampled_from(sorted(FORMATS)))
    data = bytearray(valid_bytes(ext))
    for _ in range(draw(st.integers(least, 4))):
        at = draw(st.integers(0, max(0, len(data) - 1)))
        how = draw(st.sampled_from(["set", "insert", "delete"]))
        chunk = draw(st.binary(min_size=1, max_size=8))
        if how == "set":
            data[at : at + len(chunk)] = chunk
        elif how == "insert":
            data[at:at] = chunk
        else:
            del data[at : at + len(chunk)]
    if draw(st.booleans()):
        data = data[: draw(st.integers(0, len(data)))]
    return ext, bytes(data)
