"""What the sweep's rows say: fitted slopes, the Pareto front, the answer, and the files written.

- Fits: least squares of log(error) against log(cost) -- the series' cost axis: samples per pixel,
  rays per pixel, triangles per ball; a series whose cost grows by a fixed factor per knob step
  (``Series.level_factor``: Embree's 4 per subdivision) also gets ``factor_per_level`` = factor^slope --
  and against log(time). Points with error 0 (below measurement) are left out of fits and plots. Pareto
  front: the settings no other setting of the same series beats in both time and error.
- The answer (``answer`` and ``answer_lines`` in sweep.json, printed by ``minirt sweep``, the top of
  sweep.md and of the report's sweep section): per backend, the cheapest setting (shortest median
  time) whose colour RMSE against the converged image is below one 8-bit level (1/255), e.g. "error
  < 1/255 costs 0.055 s with the reference at 16 spp". RMSE, not the largest pixel difference: an
  edge pixel of a finite-sample render stays off by more than a level long after the image as a
  whole has converged. A backend that does not shade (Embree) is judged by its geometry instead: the
  harness's geometry check passing with a mean relative t error below GEOMETRY_T_REL (why at the
  constant). When no setting reaches it the line says so and names the most accurate one tried. A
  series measured against one of its own settings (the reference's precision, against f64 itself) is
  no candidate (``Series.candidate``).

API: :func:`write_outputs` writes ``sweep.csv``, ``sweep.md``, ``sweep.json``, one
``sweep-<backend>.png`` per backend and ``sweep.png`` (all series; minirt.sweep.plots) into a folder.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path
from typing import Any

import numpy as np

from minirt.harness import backends as bk
from minirt.io.atomic import atomic_path
from minirt.io.images import write_json
from minirt.sweep.plots import plot
from minirt.sweep.series import COLOR_LEVEL, GEOMETRY_T_REL, Catalogue, rows_by_series, usable
from minirt.sweep.timing import seconds_text

# ---------------------------------------------------------------------------------------------
# Fits and the Pareto front


def _lsq(x: list[float], y: list[float]) -> tuple[float, float] | None:
    """Least squares y = a + b x; (b, a)."""
    if len(x) < 2 or np.ptp(np.asarray(x, float)) < 1e-9:
        return None
    b, a = np.polyfit(np.asarray(x, float), np.asarray(y, float), 1)
    return float(b), float(a)


def fit_slopes(rows: list[dict[str, Any]], cat: Catalogue) -> dict[str, dict[str, Any]]:
    """Per series: slope of log(error) against log(cost) and against log(seconds), for every metric."""
    out: dict[str, dict[str, Any]] = {}
    for key, rs in rows_by_series(rows).items():
        spec = cat.series.get(key)
        if spec is not None and not spec.fit:
            continue  # e.g. two points, one of them the truth itself: no trend to fit
        metrics = sorted({m for r in rs for m, v in r["error"].items() if isinstance(v, float) and m != "exposure"})
        fits: dict[str, Any] = {}
        for m in metrics:
            pts = [r for r in rs if usable(r, m) and r["cost"]]
            f_cost = _lsq([math.log(r["cost"]) for r in pts], [math.log(r["error"][m]) for r in pts])
            f_time = _lsq([math.log(r["seconds_median"]) for r in pts], [math.log(r["error"][m]) for r in pts])
            if f_cost is None:
                continue
            fit = {"slope_cost": f_cost[0], "slope_time": f_time[0] if f_time else None, "points": len(pts),
                   "values": [r["value"] for r in pts]}  # fmt: skip
            if spec is not None and spec.level_factor:
                fit["factor_per_level"] = spec.level_factor ** f_cost[0]
            fits[m] = fit
        primary = spec.metric if spec else None
        out[key] = {"metric": primary, "cost": spec.cost if spec else None, "theory": spec.theory if spec else None,
                    **(fits.get(primary) or {}), "by_metric": fits}  # fmt: skip
    return out


def mark_pareto(rows: list[dict[str, Any]], cat: Catalogue) -> dict[str, list[Any]]:
    """Mark rows on their series' Pareto front (time, error); return the front's values per series."""
    out: dict[str, list[Any]] = {}
    for key, rs in rows_by_series(rows).items():
        m = cat.series[key].metric if key in cat.series else "rmse"
        pts = [r for r in rs if usable(r, m)]
        front = []
        for r in pts:
            t, e = r["seconds_median"], r["error"][m]
            beaten = any(
                (q["seconds_median"] <= t and q["error"][m] <= e) and (q["seconds_median"] < t or q["error"][m] < e)
                for q in pts
                if q is not r
            )
            r["pareto"] = not beaten
            if not beaten:
                front.append(r["value"])
        out[key] = front
    return out


# ---------------------------------------------------------------------------------------------
# The answer: what an image error below one 8-bit level costs, per backend


def _in_sentence(name: str) -> str:
    """A backend's display name inside a sentence: an article in lower case ("the reference")."""
    return "t" + name[1:] if name.startswith("The ") else name


def _meets(r: dict[str, Any], geometry: bool) -> bool:
    if geometry:
        t = r["error"].get("t_rel_mean")
        return r["error"].get("geometry_check") == "pass" and t is not None and t < GEOMETRY_T_REL
    e = r["error"].get("rmse")
    return e is not None and e < COLOR_LEVEL


def answers(rows: list[dict[str, Any]], cat: Catalogue) -> list[dict[str, Any]]:
    """Per backend (in row order): the cheapest setting (shortest median time; then lowest cost) whose
    colour RMSE against the converged image is below one 8-bit level -- for a backend that does not
    shade, whose geometry passes the harness's own check with a mean relative t error below
    GEOMETRY_T_REL -- with its time and a one-line sentence."""
    out = []
    by_backend: dict[str, list[dict[str, Any]]] = {}
    for r in rows:
        by_backend.setdefault(r["backend"], []).append(r)
    for backend, rs in by_backend.items():
        b = bk.find(backend)
        geometry = b is not None and not b.shades
        display = _in_sentence(bk.display_name(backend))
        criterion = f"t error < {GEOMETRY_T_REL:.2g} (the check's float32 tolerance)" if geometry else "error < 1/255"
        measure = "t_rel_mean" if geometry else "rmse"
        cands = [r for r in rs if r["status"] == "ok" and cat.candidate(f"{backend}/{r['knob']}")
                 and r.get("seconds_median") is not None and r["error"].get(measure) is not None]  # fmt: skip
        a: dict[str, Any] = {"backend": backend, "criterion": criterion, "metric": measure,
                             "threshold": GEOMETRY_T_REL if geometry else COLOR_LEVEL, "met": False, "knob": None,
                             "value": None, "setting": None, "seconds": None, "seconds_setup": None,
                             "error": None}  # fmt: skip
        if not cands:
            why = next((r["reason"] for r in rs if r.get("reason")), "no setting was measured")
            a["line"] = f"{criterion}: not measured with {display} ({why})"
            out.append(a)
            continue
        good = [r for r in cands if _meets(r, geometry)]
        if good:  # the cheapest that reaches it
            best = min(good, key=lambda r: (r["seconds_median"], r["cost"] or 0))
        else:  # none does: the most accurate tried
            best = min(cands, key=lambda r, m=measure: (r["error"][m], r["seconds_median"]))
        label = cat.label(backend, best["knob"], best["value"])
        a.update(met=bool(good), knob=best["knob"], value=best["value"], setting=label, seconds=best["seconds_median"],
                 seconds_setup=best["seconds_setup"], error=best["error"][measure])  # fmt: skip
        err = f"{'mean relative t error' if geometry else 'RMSE'} {best['error'][measure]:.2g}"
        if good:
            a["line"] = f"{criterion} costs {seconds_text(best)} with {label} ({err})"
        else:
            extra = ""
            if geometry:
                extra = f", {best['error'].get('geometry_beyond_tolerance', '?')} pixel(s) beyond tolerance"
            a["line"] = (f"no setting tried reaches {criterion} with {display}; "
                         f"best: {label}, {err}{extra}, {seconds_text(best)}")  # fmt: skip
        out.append(a)
    return out


# ---------------------------------------------------------------------------------------------
# Output files

CSV_ERRORS = ("rmse", "flip", "max_abs", "t_rel_mean", "t_rel_max", "mask_mismatch", "id_mismatch")
CSV_FIELDS = ("backend", "knob", "value", "cost", "status", "seconds_median", "seconds_setup", "seconds_total",
              "repeats", "metric", "error", *CSV_ERRORS, "pareto", "slope_cost", "slope_time", "reason",
              "at_resolution")  # fmt: skip


def _fmt(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "yes" if v else ""
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def _table_rows(result: dict[str, Any]) -> list[dict[str, Any]]:
    out = []
    for r in result["rows"]:
        key = f"{r['backend']}/{r['knob']}"
        fit = result["slopes"].get(key, {})
        e = r["error"]
        out.append({
            "backend": r["backend"], "knob": r["knob"], "value": r["value"], "cost": r["cost"],
            "status": r["status"], "seconds_median": r["seconds_median"], "seconds_setup": r["seconds_setup"],
            "seconds_total": r["seconds_total"], "repeats": len(r["runs"]), "metric": r["metric"],
            "error": e.get(r["metric"]) if r["metric"] else None, **{k: e.get(k) for k in CSV_ERRORS},
            "pareto": r["pareto"], "slope_cost": fit.get("slope_cost"), "slope_time": fit.get("slope_time"),
            "reason": r["reason"], "at_resolution": bool(r.get("seconds_at_resolution")),
        })  # fmt: skip
    return out


def write_csv(result: dict[str, Any], path: Path) -> None:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=CSV_FIELDS, lineterminator="\n")
    w.writeheader()
    for r in _table_rows(result):
        w.writerow({k: ("" if v is None else repr(v) if isinstance(v, float) else v) for k, v in r.items()})
    with atomic_path(path) as tmp:
        tmp.write_text(buf.getvalue())


def _md_table(rows: list[list[Any]], headers: list[str]) -> str:
    """A GitHub-flavoured Markdown table (tabulate's "github" format: pipes, a header rule, aligned
    columns); cells are formatted by _fmt first, so numbers read as in the CSV's short form."""
    from tabulate import tabulate

    cells = [[_fmt(v).replace("|", "/") for v in row] for row in rows]  # a pipe would split a cell
    return tabulate(cells, headers=headers, tablefmt="github", disable_numparse=True)


def markdown(result: dict[str, Any]) -> str:
    w, h = result["size"]
    lines = [f"# Sweep: {result['scene']} at {w}x{h}, {result['repeats']} timed run(s) per setting", ""]
    lines += [f"- {line}" for line in result.get("answer_lines", [])] + [""]
    cols = ["backend", "knob", "value", "cost", "status", "seconds_median", "seconds_setup", "metric", "error",
            "flip", "t_rel_max", "mask_mismatch", "pareto", "reason"]  # fmt: skip
    table = []
    for r in _table_rows(result):
        if r["status"] != "ok":
            r["status"] = r["status"].upper()
        if r["at_resolution"]:
            r["seconds_median"] = f"≤ {_fmt(r['seconds_median'])}"
        table.append([r[c] for c in cols])
    lines += [_md_table(table, cols)]
    lines += ["", "## Fitted slopes (log error against log cost, and against log time)", ""]
    slope_cols = ["series", "metric", "cost", "slope (cost)", "slope (time)", "factor per level", "points", "theory"]
    slope_rows = [[key, f.get("metric"), f.get("cost"), f.get("slope_cost"), f.get("slope_time"),
                   f.get("factor_per_level"), f.get("points"), f.get("theory")]
                  for key, f in result["slopes"].items()]  # fmt: skip
    lines += [_md_table(slope_rows, slope_cols)]
    lines += ["", "## Converged answers", ""]
    for key, c in result["converged"].items():
        desc = ", ".join(f"{k}={v}" for k, v in c.items() if k not in ("rules", "reason"))
        lines.append(f"- {key}: {desc}" + (f" ({c['reason']})" if c.get("reason") else ""))
    lines += ["", "Times in seconds: median of the timed runs after an untimed warm-up; setup = the warm-up's excess",
              "(JIT, caches) or POV-Ray's per-process start-up (not in its median); ≤: below POV-Ray's 1 ms",
              "timer, shown at 1 ms. Errors: colours clipped to [0, 1]; see minirt/sweep.py for what each",
              "backend's converged answer is.", ""]  # fmt: skip
    return "\n".join(lines)


def write_outputs(result: dict[str, Any], out_dir: Path) -> dict[str, Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {"json": out_dir / "sweep.json", "csv": out_dir / "sweep.csv", "md": out_dir / "sweep.md",
             "png": out_dir / "sweep.png"}  # fmt: skip
    write_json(paths["json"], result)
    write_csv(result, paths["csv"])
    with atomic_path(paths["md"]) as tmp:
        tmp.write_text(markdown(result))
    plot(result, paths["png"])
    known = set(bk.all_names())  # a file name never comes from an unknown (user-typed) backend name
    for name in dict.fromkeys(r["backend"] for r in result["rows"] if r["backend"] in known):
        p = out_dir / f"sweep-{name}.png"
        plot(result, p, only=name)
        paths[f"png:{name}"] = p
    return paths
