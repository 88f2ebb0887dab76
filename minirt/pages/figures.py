"""The comparison report's figures: the mismatch overlay on the darkened reference and the difference heat maps.

The overlay paints each kind of boolean evidence the harness keeps (hit/miss inside or outside the
silhouette band, shape id, lit or shadowed) in its own Okabe-Ito colour; a heat map is one per-pixel
difference with a colour bar (matplotlib, Agg), its colour scale that of the pixels the check judges,
the others hatched grey. minirt.pages.report writes them beside the page as it builds its view."""

from __future__ import annotations

from typing import Any

import numpy as np

from minirt.pages.assets import BLUE, ORANGE, PURPLE, YELLOW

# Boolean evidence drawn on the darkened reference: harness image key -> (label, colour).
OVERLAY = {
    "mask_inside_band": ("hit/miss differs inside the silhouette band (allowed)", BLUE),
    "mask_outside_band": ("hit/miss differs outside the band (defect)", ORANGE),
    "id_mismatch": ("shape id differs (defect)", PURPLE),
    "lit_mismatch": ("lit on one side, shadowed on the other", YELLOW),
}

# Difference maps: harness image key -> (title, colour-bar label, colormap, threshold key for a line on the bar).
HEATMAPS = {
    "depth_rel_err": ("t: relative error |Δt| / t", "relative", "viridis", None),
    "normal_deg": ("normal: angle between normals", "degrees", "viridis", None),
    "color8_diff": ("colour: 8-bit difference (max channel)", "levels", "magma", "color8_levels"),
    "delta_e": ("colour: CIEDE2000 ΔE", "ΔE00", "magma", None),
    "flip": ("colour: FLIP error", "FLIP", "magma", None),
    "diffuse_rel_err": ("diffuse: relative error / (lc·dc)", "relative", "magma", "diffuse_rel"),
    "p_value": ("Z-test: −log10 p (per pixel, min over RGB)", "−log10 p", "magma", None),
}

# What each check leaves unjudged (its image "not_judged"): hatched grey on its maps, named in the caption.
NOT_JUDGED = {
    "geometry": "the silhouette band",
    "shading": "edges (silhouettes, shadow and reflection boundaries)",
    "samples": "edges (silhouettes, shadow and reflection boundaries, over every sample's ray)",
    "stochastic": "edges and pixels not fully covered",
}
NOT_JUDGED_DEFAULT = "pixels this check does not judge"
HATCH = "#9a9a9a"


def heatmap(
    data: np.ndarray, title: str, unit: str, cmap: str, line: float | None = None, excluded: np.ndarray | None = None
):
    """A difference map with a colour bar; `excluded` pixels (not judged by the check) are drawn grey and
    hatched, and the colour scale is that of the judged pixels, so an edge pixel cannot wash them out."""
    import matplotlib
    from matplotlib.figure import Figure

    fig = Figure(figsize=(2.9, 2.45), dpi=100, facecolor="#24262a")
    ax = fig.add_axes((0.04, 0.05, 0.66, 0.78))
    ex = excluded if excluded is not None and excluded.shape == data.shape and excluded.any() else None
    judged = data[~ex] if ex is not None else data
    vmax = float(np.nanmax(judged)) if judged.size and np.isfinite(judged).any() else 1.0
    vmax = vmax if vmax > 0 else 1.0
    if line is not None:
        vmax = max(vmax, line * 1.25)
    cm = matplotlib.colormaps[cmap].with_extremes(bad=HATCH)
    shown = np.ma.masked_array(data, mask=ex) if ex is not None else data
    im = ax.imshow(shown, cmap=cm, vmin=0.0, vmax=vmax, interpolation="nearest")
    if ex is not None:
        # one hatched region per connected run of excluded pixels, on pixel edges (contourf on corners)
        h, w = ex.shape
        grid = np.pad(ex.astype(float), 1)
        ys, xs = np.arange(-1, h + 1), np.arange(-1, w + 1)
        with matplotlib.rc_context({"hatch.color": "#3a3a3a", "hatch.linewidth": 0.6}):
            ax.contourf(xs, ys, grid, levels=[0.5, 1.5], colors="none", hatches=["/////"])
        ax.set_xlim(-0.5, w - 0.5)
        ax.set_ylim(h - 0.5, -0.5)
    ax.set_xticks([])
    ax.set_yticks([])
    for s in ax.spines.values():
        s.set_color("#55585e")
    fig.suptitle(title, fontsize=7.5, color="#e8e8e8", x=0.04, ha="left", y=0.97)
    cax = fig.add_axes((0.74, 0.05, 0.05, 0.78))
    cb = fig.colorbar(im, cax=cax)
    cb.set_label(unit, fontsize=7, color="#d0d0d0")
    cb.ax.tick_params(labelsize=6.5, colors="#d0d0d0")
    cb.ax.yaxis.get_offset_text().set(size=6.5, color="#d0d0d0")
    cb.outline.set_edgecolor("#55585e")
    if line is not None:
        cb.ax.axhline(line, color="#ffffff", lw=1.2, ls="--")
    return fig


def overlay(base: np.ndarray, images: dict[str, np.ndarray]) -> tuple[np.ndarray, list[dict[str, Any]]]:
    """Reference darkened to a third, band pixels lifted a little, mismatches painted in solid colours."""
    out = base.astype(np.float64) * 0.3
    band = images.get("band")
    if band is not None and band.shape == out.shape[:2]:
        out[band] = out[band] * 0.5 + 70.0
    legend = []
    if band is not None:
        legend.append(
            {"label": "silhouette band (tolerance zone)", "rgb": "#7a7a7a", "count": int(band.sum()), "key": "band"}
        )
    for key, (label, rgb) in OVERLAY.items():
        m = images.get(key)
        if m is None or m.dtype != bool or m.shape != out.shape[:2]:
            continue
        out[m] = rgb
        legend.append({"label": label, "rgb": "#{:02x}{:02x}{:02x}".format(*rgb), "count": int(m.sum()), "key": key})
    return np.clip(out + 0.5, 0, 255).astype(np.uint8), legend
