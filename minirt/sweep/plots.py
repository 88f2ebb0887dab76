"""The sweep's plots: log-log error against time, one line per series.

Colour error and t error have different units and go on separate axes (side by side in ``sweep.png``);
each series keeps its colour and marker in every plot (Okabe & Ito's colour-blind-safe palette, in the
order of sweep.json's ``series``: the registry's backends, each's series in its own order).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from minirt.io.atomic import atomic_path
from minirt.sweep.series import COLOR_LEVEL, GEOMETRY_T_REL, rows_by_series, usable

# Okabe & Ito's colour-blind-safe palette and a marker, one per series in the order of result["series"]
# (the reference's precision and samples, Mitsuba's samples, POV-Ray's antialiasing and samples, Embree's
# subdivisions); more series than colours cycle.
PALETTE = ("#56B4E9", "#0072B2", "#E69F00", "#009E73", "#CC79A7", "#D55E00")
MARKERS = ("D", "o", "s", "^", "P", "v")


METRIC_LABELS = {"rmse": "colour RMSE (values in [0, 1])", "t_rel_mean": "mean relative t error"}
AXES = {"rmse": "colour", "t_rel_mean": "geometry"}  # each metric on its own axes: the units differ


def plot(result: dict[str, Any], path: Path, only: str | None = None) -> None:
    """Log-log error against time: colour error and t error on separate axes (side by side when both
    occur), one line per series in knob order, Pareto front circled and dashed, one 8-bit level as a
    line on the colour axes, each backend's answer starred; only=backend keeps that backend's series.
    Times below the timer's resolution are drawn hollow at the resolution, with a left arrow."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [r for r in result["rows"] if only is None or r["backend"] == only]
    series = result.get("series", {})
    order = {key: k for k, key in enumerate(series)}
    groups: dict[str, list[tuple[str, str, list[dict[str, Any]]]]] = {}
    for key, rs in rows_by_series(rows).items():
        m = series.get(key, {}).get("metric", "rmse")
        pts = [r for r in rs if usable(r, m)]  # in knob order
        if pts:
            groups.setdefault(AXES.get(m, m), []).append((key, m, pts))
    panels = [g for g in ("colour", "geometry") if g in groups] + [g for g in groups if g not in AXES.values()]
    n = max(len(panels), 1)
    fig, axes = plt.subplots(1, n, figsize=(6.4 * n, 5.4), dpi=100, squeeze=False)
    chosen = {(a.get("backend"), a.get("knob"), a.get("value")) for a in result.get("answer") or [] if a.get("met")}
    w, h = result["size"]
    for ax, panel in zip(axes[0], panels or [None], strict=True):
        if panel is None:
            ax.text(0.5, 0.5, "no measurements", ha="center", va="center", transform=ax.transAxes)
            ax.set_title(f"{result['scene']} {w}x{h}" + (f" ({only})" if only else ""), fontsize=10)
            continue
        _draw_panel(ax, panel, groups[panel], order, result, chosen, only)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", metadata={"Software": None})
    plt.close(fig)


def _draw_panel(
    ax,
    panel: str,
    group: list[tuple[str, str, list[dict[str, Any]]]],
    order: dict[str, int],
    result: dict[str, Any],
    chosen: set,
    only: str | None,
) -> None:
    """One panel of ``plot``: its series (key, metric, points), their Pareto fronts, the goal's line, the
    legend and the axes."""
    from matplotlib.ticker import NullFormatter

    w, h = result["size"]
    metrics = []
    floored: float | None = None  # the timer's resolution a time was drawn at
    starred = False
    for key, m, pts in group:
        metrics.append(m)
        x = [r["seconds_median"] for r in pts]
        y = [r["error"][m] for r in pts]
        k = order.get(key)
        c = "#000000" if k is None else PALETTE[k % len(PALETTE)]
        fit = result["slopes"].get(key, {})
        label = key
        if fit.get("slope_cost") is not None:
            label += f": ∝ cost^{fit['slope_cost']:.2f}"
        mk = "o" if k is None else MARKERS[k % len(MARKERS)]
        ax.plot(x, y, marker=mk, color=c, lw=1.2, ms=5, label=label)
        for r, xi, yi in zip(pts, x, y, strict=True):
            ax.annotate(str(r["value"]), (xi, yi), textcoords="offset points", xytext=(4, 3), fontsize=7, color=c)
            if r.get("seconds_at_resolution"):
                floored = r.get("timer_resolution") or xi
                ax.plot([xi], [yi], marker=mk, ms=5, color="#ffffff", mec=c, ls="none")
                ax.annotate("", (xi * 0.6, yi), xytext=(xi, yi), arrowprops={"arrowstyle": "->", "color": c,
                                                                               "lw": 0.8})  # fmt: skip
            if (r["backend"], r["knob"], r["value"]) in chosen:
                starred = True
                ax.plot([xi], [yi], marker="*", ms=15, color=c, mec="#000000", mew=0.6, ls="none", zorder=5)
        front = sorted((r for r in pts if r["pareto"]), key=lambda r: r["seconds_median"])
        if front:
            ax.plot([r["seconds_median"] for r in front], [r["error"][m] for r in front], ls="--", lw=0.8,
                    color="#000000", marker="o", ms=11, mfc="none", mec="#000000", mew=1.0)  # fmt: skip
    ax.plot([], [], ls="--", lw=0.8, color="#000000", marker="o", ms=11, mfc="none", label="Pareto front")
    if panel == "colour":
        ax.axhline(COLOR_LEVEL, color="#555555", lw=0.9, ls=":", label="one 8-bit level (1/255)")
    elif panel == "geometry":
        ax.axhline(GEOMETRY_T_REL, color="#555555", lw=0.9, ls=":",
                   label=f"the check's float32 t tolerance ({GEOMETRY_T_REL:.2g})")  # fmt: skip
    if starred:
        goal = "below 1/255" if panel == "colour" else f"below {GEOMETRY_T_REL:.2g}"
        ax.plot([], [], marker="*", ms=12, color="#bbbbbb", mec="#000000", ls="none", label=f"cheapest {goal}")
    if floored:
        note = f"below the timer's {floored * 1e3:g} ms: drawn at it (an upper bound)"
        ax.plot([], [], marker="o", ms=5, color="#ffffff", mec="#000000", ls="none", label=note)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.xaxis.set_minor_formatter(NullFormatter())  # a span under a decade would label every minor tick
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=2, frameon=False)
    names = [METRIC_LABELS.get(m, m) for m in dict.fromkeys(metrics)]
    ax.set_xlabel("time per render, median of the timed runs [s]")
    ax.set_ylabel("error vs converged answer: " + "; ".join(names), fontsize=8)
    title = f"{result['scene']} {w}x{h}: {panel} error against time" + (f" ({only})" if only else "")
    ax.set_title(title, fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
