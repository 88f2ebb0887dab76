"""Contact sheet: every backend's picture side by side, labelled, in one PNG.

Backends that shade show their 8-bit colour image; geometry-only backends show their normals
(n/2 + 1/2) on black, so a silhouette or orientation error is visible at a glance. Failed backends
get a grey tile with their verdict. Drawn with matplotlib; PNG metadata is fixed for bit-identical files.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from minirt.imageio import atomic_path
from minirt.result import RenderResult


def preview(r: RenderResult) -> tuple[np.ndarray, str]:
    """An 8-bit RGB picture of a result, and what it shows."""
    if not r.ok:
        return np.full((r.height, r.width, 3), 64, np.uint8), f"{r.status.upper()}"
    if r.color is not None:
        return r.color8(), r.meta.get("image8_shows", "colour")
    n = np.where(r.hit[..., None], r.normal * 0.5 + 0.5, 0.0)
    return (np.clip(n, 0, 1) * 255 + 0.5).astype(np.uint8), "normals"


def contact_sheet(results: list[RenderResult], path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(results)
    fig, axes = plt.subplots(1, n, figsize=(2.6 * n, 3.0), dpi=100, squeeze=False)
    for ax, r in zip(axes[0], results, strict=True):
        img, what = preview(r)
        ax.imshow(img, interpolation="nearest")
        # No timings on the sheet: the same command must write the same bytes (they are on stderr).
        ax.set_title(f"{r.backend}\n{what}", fontsize=9)
        if not r.ok:
            ax.text(0.5, 0.5, r.reason[:60], ha="center", va="center", wrap=True, fontsize=6, color="w",
                    transform=ax.transAxes)  # fmt: skip
        ax.set_xticks([])
        ax.set_yticks([])
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", metadata={"Software": None})
    plt.close(fig)
    return path
