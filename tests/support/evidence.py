"""Failing tests leave evidence a person can look at: the images behind each failed check."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from minirt.io.images import write_image, write_json

EVIDENCE = Path(__file__).resolve().parents[1] / "_evidence"


def to8(a: np.ndarray) -> np.ndarray:
    if np.asarray(a).dtype == bool:
        return np.asarray(a).astype(np.uint8) * 255
    a = np.asarray(a, dtype=np.float64)
    if a.max(initial=0) <= 1 and a.min(initial=0) >= 0:
        return (np.clip(a, 0, 1) * 255 + 0.5).astype(np.uint8)
    hi = np.nanmax(np.abs(a)) or 1.0
    return (np.clip(np.abs(a) / hi, 0, 1) * 255 + 0.5).astype(np.uint8)


def dump_check(scene_check, backend: str) -> Path:
    """Write reference, oracle and every evidence image of a backend's checks; return the folder."""
    b = scene_check.backends[backend]
    out = EVIDENCE / scene_check.scene / backend
    if b.reference is not None and b.reference.color is not None:
        write_image(out / "reference.png", b.reference.color8())
    if b.result is not None and b.result.ok:
        from minirt.pages.sheet import preview

        write_image(out / "oracle.png", preview(b.result)[0])
    for cname, c in b.checks.items():
        for iname, img in c.images.items():
            write_image(out / f"{cname}.{iname}.png", to8(img if img.ndim == 2 else img.max(axis=-1)))
    write_json(out / "check.json", b.as_dict())
    return out
