"""Contact sheet: every backend's picture side by side, labelled, in one PNG.

Backends that shade show their 8-bit colour image; geometry-only backends show their normals
(n/2 + 1/2) on black, so a silhouette or orientation error is visible at a glance. Failed backends
get a grey tile with their verdict. Below, a difference row: each backend's picture minus the
reference's picture of the same kind (colour or normals), largest channel difference in 8-bit levels.
Drawn with matplotlib; PNG metadata is fixed for bit-identical files.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from minirt.harness import backends
from minirt.io.atomic import atomic_path
from minirt.io.untrusted import printable
from minirt.model.result import RenderResult


def preview(r: RenderResult) -> tuple[np.ndarray, str]:
    """An 8-bit RGB picture of a result, and what it shows."""
    if not r.ok:
        return np.full((r.height, r.width, 3), 64, np.uint8), f"{r.status.upper()}"
    if r.color is not None:
        return r.color8(), r.meta.get("image8_shows", "colour")
    return normals8(r), "normals"


def normals8(r: RenderResult) -> np.ndarray:
    """The normals as 8-bit RGB (n/2 + 1/2), black where nothing is hit."""
    n = np.where(r.hit[..., None], r.normal * 0.5 + 0.5, 0.0)
    return (np.clip(n, 0, 1) * 255 + 0.5).astype(np.uint8)


def _difference(r: RenderResult, ref: RenderResult) -> tuple[np.ndarray, str] | None:
    """Per pixel, the largest channel difference in 8-bit levels between what `r` and `ref` show (colour
    against colour, normals against normals), and what was compared; None if nothing can be."""
    if not (r.ok and ref.ok) or (r.width, r.height) != (ref.width, ref.height):
        return None
    img, what = preview(r)
    if what == "normals":
        if ref.hit is None or ref.normal is None:
            return None
        base = (np.clip(np.where(ref.hit[..., None], ref.normal * 0.5 + 0.5, 0.0), 0, 1) * 255 + 0.5).astype(np.uint8)
        vs = "normals"
    elif ref.color is not None:
        base, vs = ref.color8(), "colour"
    else:
        return None
    return np.abs(img.astype(np.int16) - base.astype(np.int16)).max(axis=-1), vs


def contact_sheet(results: list[RenderResult], path: Path) -> Path:
    """Row 1: each backend's picture; row 2 (when a reference is among the results): each other backend's
    8-bit difference from the reference's picture of the same kind, max channel, in levels."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(results)
    ref = backends.reference_result([r for r in results if r.ok])
    rows = 2 if ref is not None and n > 1 else 1
    # constrained layout sizes the figure around the titles, so two-line titles are never cut off
    fig, axes = plt.subplots(rows, n, figsize=(2.6 * n, 3.1 * rows), dpi=100, squeeze=False, layout="constrained")
    for ax, r in zip(axes[0], results, strict=True):
        img, what = preview(r)
        ax.imshow(img, interpolation="nearest")
        # No timings on the sheet: the same command must write the same bytes (they are on stderr).
        ax.set_title(f"{r.backend}\n{what}", fontsize=9)
        if not r.ok:
            # a renderer's own words: control bytes escaped (no "Glyph missing"), '$' not read as mathtext
            ax.text(0.5, 0.5, printable(r.reason, 60), ha="center", va="center", wrap=True, fontsize=6, color="w",
                    transform=ax.transAxes, parse_math=False)  # fmt: skip
    if rows == 2:
        for ax, r in zip(axes[1], results, strict=True):
            d = None if r is ref else _difference(r, ref)
            if d is None:
                note = "differences from\nthe reference" if r is ref else "no difference image"
                ax.text(0.5, 0.5, note, ha="center", va="center", fontsize=8, color="#555555", transform=ax.transAxes)
                ax.axis("off")
                continue
            diff, vs = d
            peak = int(diff.max())
            im = ax.imshow(diff, cmap="magma", vmin=0, vmax=max(peak, 1), interpolation="nearest")
            ax.set_title(f"{r.backend} − reference ({vs})\nmax {peak} level{'s' if peak != 1 else ''}", fontsize=9)
            cb = fig.colorbar(im, ax=ax, fraction=0.046, pad=0.02)
            cb.ax.tick_params(labelsize=6)
    for ax in axes.flat:
        ax.set_xticks([])
        ax.set_yticks([])
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", metadata={"Software": None})
    plt.close(fig)
    return path
