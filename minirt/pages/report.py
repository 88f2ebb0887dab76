"""Comparison report: one static HTML page, its JSON, and the evidence images beside it.

``write_report(result, DIR, command=...)`` writes

- ``DIR/index.html``: opens from disk, no server and no network (inline CSS and JS only, a Content
  Security Policy that allows images from the page's own folder and nothing else, and only the
  page's own script, by hash);
- ``DIR/report.json``: ``result.as_dict()`` plus a ``report`` block (command, date, machine,
  versions) and the sweep when one was run;
- ``DIR/assets/*.png``: 8-bit images at the renders' own resolution (written by
  ``minirt.pages.assets``; the page scales them up without smoothing) and matplotlib figures
  (``minirt.pages.figures``: heat maps with colour bars, Agg, fixed PNG metadata). File names come
  from the scene's index, the backend's registry name and the harness's own buffer names, never from
  a scene file.

The page follows Blender's render_report.py: failures and errors first; per scene the backends'
pictures side by side at one scale, per oracle new | reference (hover or toggle swaps them in
place) | mismatch overlay | difference heat maps, the rule diagnosis (which rule settings explain
the oracle's image) and the rule effects (what each rule it cannot follow changes in the reference,
with masks), every figure and threshold with its reason, and the command that reproduces the report.
Everything that comes from a scene file (names, descriptions, reasons) is escaped by Jinja2's
autoescape; the CSP blocks any script that is not the page's own even if something slipped through.

The date is only in the page and the JSON: images carry no timestamp, so the same check gives
bit-identical assets.
"""

from __future__ import annotations

import json
import math
import os
import platform
import re
import sys
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from minirt.harness import backends
from minirt.harness.results import ORDER, BackendCheck, Check, CheckResult, SceneCheck, worst
from minirt.harness.tolerances import THRESHOLDS
from minirt.io.images import write_json
from minirt.model.result import to8
from minirt.pages.assets import Assets, display, highlight, page_parts, write_page
from minirt.pages.figures import HEATMAPS, NOT_JUDGED, NOT_JUDGED_DEFAULT, heatmap, overlay
from minirt.pages.sheet import normals8, preview

Progress = Callable[[int, int, str], None]

# Most severe first: the order of scenes and backends on the page.
SEVERITY = ["error", "fail", "warn", "pass", "skip"]


# Figures that count defects: highlighted in the table when non-zero.
DEFECT_COUNTS = {
    "mask_mismatch_outside_band",
    "id_mismatch",
    "depth_violations",
    "normal_violations",
    "color8_over_1",
    "diffuse_over_tolerance",
    "lit_mismatch",
}

TILE = 192  # target display size of the longest image side, CSS pixels

SAMPLE_COMMAND = '.venv/bin/python -c "from minirt.pages.report import refresh_sample; refresh_sample()"'
GOLDENS_COMMAND = "make goldens"


# ---------------------------------------------------------------------------------------------
# Small helpers


def _rank(verdict: str) -> int:
    return SEVERITY.index(verdict) if verdict in SEVERITY else len(SEVERITY)


def _fmt(v: Any) -> str:
    if v is None:
        return "–"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, float):
        if not math.isfinite(v):
            return str(v)
        return "0" if v == 0 else f"{v:.4g}"
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    return str(v)


def _flatten(d: dict[str, Any], prefix: str = "") -> list[tuple[str, Any]]:
    out: list[tuple[str, Any]] = []
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out += _flatten(v, key + ".")
        else:
            out.append((key, v))
    return out


def _version(meta: dict[str, Any] | None) -> str:
    v = (meta or {}).get("version")
    if v is None:
        return "unknown"
    if isinstance(v, dict):
        return ", ".join(f"{k} {x}" for k, x in v.items())
    return str(v)


def _slug(name: str, fallback: str) -> str:
    """A file-name part from a name the code defines; anything else falls back to an index."""
    return name if re.fullmatch(r"[a-z][a-z0-9_]{0,23}", name) else fallback


def _split_threshold(text: str) -> tuple[str, str]:
    """The harness writes thresholds as 'value: why'."""
    value, sep, why = str(text).partition(": ")
    return (value, why) if sep else ("", value)


def _machine() -> dict[str, Any]:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {
        "platform": platform.platform(),
        "cpu": cpu,
        "cpu_count": os.cpu_count(),
        "python": sys.version.split()[0],
    }


# ---------------------------------------------------------------------------------------------
# View models: plain dicts and strings for the template (which escapes every string)


def _check_view(name: str, c: Check) -> dict[str, Any]:
    figures = []
    for k, v in _flatten(c.figures):
        defect = k in DEFECT_COUNTS and isinstance(v, int | float) and v > 0
        figures.append({"name": k, "value": _fmt(v), "defect": defect})
    thresholds = []
    for k, text in c.thresholds.items():
        value, why = _split_threshold(text)
        thresholds.append({"name": k, "value": value, "why": why})
    return {
        "name": name,
        "verdict": c.verdict,
        "label": _label(c.verdict, c.inconclusive),
        "reason": c.reason,
        "figures": figures,
        "thresholds": thresholds,
    }


def _label(verdict: str, inconclusive: bool) -> str:
    """A badge's text: the verdict, or INCONCLUSIVE for a WARN whose checks could not have failed."""
    return "INCONCLUSIVE" if inconclusive else verdict.upper()


def _backend_view(si: int, bj: int, sc: SceneCheck, bc: BackendCheck, assets: Assets, base8: np.ndarray | None):
    b = _slug(bc.backend, f"b{bj}")
    stem = f"s{si:02d}-{b}"
    res, ref = bc.result, bc.reference
    v: dict[str, Any] = {
        "name": bc.backend,
        "anchor": f"scene-{si}-{b}",
        "verdict": bc.verdict,
        "label": _label(bc.verdict, bc.inconclusive),
        "reason": bc.reason,
        "seconds": f"{bc.seconds:.2f}",
        "version": _version(res.meta if res else None),
        "rules_followed": [(k, _fmt(x)) for k, x in bc.rules_followed.items()],
        "swap": None,
        "overlay": None,
        "heatmaps": [],
        "zero_maps": [],
        "rule_effects": [],
        "diagnosis": _diagnosis_view(stem, bc, assets, base8),
        "checks": [_check_view(k, c) for k, c in bc.checks.items()],
        "open": bc.verdict in ("fail", "error", "warn"),
    }
    if res is not None and res.ok and ref is not None and res.hit is not None:
        if "diffuse_exercise" in res.aux and "diffuse" in ref.terms:
            # A physical renderer: its diffuse term in the exercise's units is what the shading check compares.
            new8, old8, what = to8(res.aux["diffuse_exercise"]), to8(ref.terms["diffuse"]), "diffuse term"
        elif res.color is not None and ref.color is not None:
            new8, old8, what = res.color8(), ref.color8(), "colour"
        else:
            new8, old8, what = normals8(res), normals8(ref), "normals"
        part = what.replace(" ", "_")  # asset names stay [a-z0-9_-]: no spaces in URLs
        v["swap"] = {
            "new": assets.image8(f"{stem}-{part}.png", new8),
            "ref": assets.image8(f"{stem}-reference-{part}.png", old8),
            "what": what,
        }
        geom = bc.checks.get("geometry")
        if geom is not None and geom.images:
            img, legend = overlay(ref.color8() if ref.color is not None else normals8(ref), geom.images)
            v["overlay"] = {"src": assets.image8(f"{stem}-mismatch.png", img), "legend": legend}
    for cname, c in bc.checks.items():
        for key, (title, unit, cmap, tkey) in HEATMAPS.items():
            data = c.images.get(key)
            if data is None or data.ndim != 2:
                continue
            data = np.nan_to_num(np.asarray(data, dtype=np.float64), nan=0.0, posinf=0.0)
            line = None
            if key == "p_value":
                data = -np.log10(np.clip(data, 1e-300, 1.0))
                alpha = c.figures.get("alpha_sidak")
                line = -math.log10(alpha) if isinstance(alpha, float) and 0 < alpha < 1 else None
            elif tkey in THRESHOLDS:
                line = float(THRESHOLDS[tkey].value)
            peak = float(data.max()) if data.size else 0.0
            if peak <= 0:
                v["zero_maps"].append(title)
                continue
            ex = c.images.get("not_judged")
            ex = ex if isinstance(ex, np.ndarray) and ex.dtype == bool and ex.shape == data.shape else None
            n_ex = int(ex.sum()) if ex is not None else 0
            judged_peak = float(data[~ex].max()) if n_ex and (~ex).any() else (0.0 if n_ex else peak)
            fig = heatmap(data, title, unit, cmap, line, ex)
            v["heatmaps"].append({
                "src": assets.figure(f"{stem}-{_slug(key, 'map')}.png", fig), "title": title, "check": cname,
                "max": _fmt(judged_peak), "max_all": _fmt(peak), "excluded": n_ex,
                "excluded_why": NOT_JUDGED.get(cname, NOT_JUDGED_DEFAULT),
            })  # fmt: skip
    for k, (rule, count) in enumerate(bc.rules.items()):
        mask = bc.rule_masks.get(rule)
        src = None
        if base8 is not None and mask is not None and mask.shape == base8.shape[:2]:
            src = assets.image8(f"s{si:02d}-rule-{_slug(rule, f'r{k}')}.png", highlight(base8, mask))
        v["rule_effects"].append({"name": rule, "count": count, "src": src})
    return v


def _diagnosis_view(stem: str, bc: BackendCheck, assets: Assets, base8: np.ndarray | None) -> dict[str, Any]:
    """The rule diagnosis as one sentence ("POV-Ray's image is explained by: …"), the pixels each setting
    explains, how it compares with the rules the oracle declares, and the unexplained pixels' mask."""
    d = bc.rule_diagnosis
    who = backends.display_name(bc.backend)
    v: dict[str, Any] = {"ran": d.ran, "line": "", "explained": [], "undeclared": [], "not_needed": [],
                         "cannot_tell": [f"{k}={x}" for k, x in d.cannot_tell.items()], "src": None}  # fmt: skip
    if not d.ran:
        v["line"] = f"No rule diagnosis: {d.reason}."
        return v
    if d.rules_explaining:
        order = sorted(d.rules_explaining, key=lambda k: (-d.explained.get(k, 0), k))
        settings = ", ".join(f"{k}={d.rules_explaining[k]}" for k in order)
        n = d.mismatch_pixels
        v["line"] = f"{who}'s image is explained by: {settings} ({n} pixel{'s' if n != 1 else ''} unexplained)"
        v["explained"] = [(k, d.rules_explaining[k], d.explained.get(k, 0)) for k in order]
    elif d.as_given_pixels:
        v["line"] = (
            f"No rule setting explains {who}'s image: {d.as_given_pixels} pixels differ from the scene's rules' "
            "image by more than one level"
        )
    else:
        v["line"] = f"{who}'s image is the scene's rules' image: nothing to explain (every pixel within one level)"
    v["undeclared"] = [f"{k}={x}" for k, x in d.undeclared.items()]
    v["not_needed"] = [f"{k}={x}" for k, x in d.not_needed.items()]
    m = d.unexplained_mask
    if d.mismatch_pixels and base8 is not None and m is not None and m.shape == base8.shape[:2]:
        v["src"] = assets.image8(f"{stem}-unexplained.png", highlight(base8, m))
    return v


def _scene_view(si: int, sc: SceneCheck, assets: Assets) -> dict[str, Any]:
    ref = sc.reference
    w = ref.width if ref else next((b.result.width for b in sc.backends.values() if b.result), 1)
    h = ref.height if ref else next((b.result.height for b in sc.backends.values() if b.result), 1)
    tiles = []
    base8 = None
    if ref is not None and ref.ok:
        base8 = ref.color8() if ref.color is not None else normals8(ref)
        tile = {"label": "reference", "what": "colour, scene rules", "verdict": None, "badge": None}
        tile["version"] = _version(ref.meta)
        tile["src"] = assets.image8(f"s{si:02d}-reference.png", base8)
        tiles.append(tile)
    order = sorted(enumerate(sc.backends.values()), key=lambda jb: (_rank(jb[1].verdict), jb[0]))
    for j, bc in enumerate(sc.backends.values()):
        r = bc.result
        tile = {"label": bc.backend, "verdict": bc.verdict, "src": None, "version": _version(r.meta if r else None)}
        tile["badge"] = _label(bc.verdict, bc.inconclusive)
        if r is not None and r.ok and (r.color is not None or r.hit is not None):
            img, what = preview(r)
            tile["what"] = "normals (geometry only)" if what == "normals" else what
            tile["src"] = assets.image8(f"s{si:02d}-{_slug(bc.backend, f'b{j}')}-tile.png", img)
        else:
            tile["what"] = (bc.reason or (r.reason if r else "") or bc.verdict)[:200]
        tiles.append(tile)
    verdicts = sorted({b.verdict for b in sc.backends.values()} | {sc.verdict}, key=_rank)
    return {
        "index": si,
        "anchor": f"scene-{si}",
        "name": sc.scene,
        "file": sc.file,
        "description": sc.description,
        "verdict": sc.verdict,
        "verdicts": " ".join(verdicts),
        "reason": sc.reason,
        "size": f"{w}×{h}",
        "display": display(w, h, TILE),
        "tiles": tiles,
        "backends": [_backend_view(si, j, sc, bc, assets, base8) for j, bc in order],
    }


def _sweep_view(sweep: dict[str, Any] | None, sweep_dir: Path | None, assets: Assets) -> dict[str, Any] | None:
    if sweep is None and sweep_dir is not None and (Path(sweep_dir) / "sweep.json").is_file():
        try:
            sweep = json.loads((Path(sweep_dir) / "sweep.json").read_text())
        except (OSError, ValueError):
            sweep = None
    if not isinstance(sweep, dict):
        return None
    plots = []
    if sweep_dir is not None and Path(sweep_dir).is_dir():
        files = sorted(Path(sweep_dir).glob("sweep*.png"), key=lambda p: (p.name != "sweep.png", p.name))
        for k, p in enumerate(files):
            m = re.fullmatch(r"sweep(?:-([a-z][a-z0-9_]{0,23}))?\.png", p.name)
            if m is None:
                continue
            name = "sweep.png" if m.group(1) is None else f"sweep-{m.group(1)}.png"
            plots.append({"src": assets.copy(name if k < 64 else f"sweep-{k}.png", p),
                          "title": m.group(1) or "all series"})  # fmt: skip
    slopes = sweep.get("slopes") if isinstance(sweep.get("slopes"), dict) else {}
    rows = []
    for r in sweep.get("rows") or []:
        if not isinstance(r, dict):
            continue
        err = r.get("error") if isinstance(r.get("error"), dict) else {}
        metric = r.get("metric")
        rows.append({
            "backend": _fmt(r.get("backend")), "knob": _fmt(r.get("knob")), "value": _fmt(r.get("value")),
            "cost": _fmt(r.get("cost")), "status": str(r.get("status", "?")),
            "seconds_median": _fmt(r.get("seconds_median")), "seconds_setup": _fmt(r.get("seconds_setup")),
            "metric": _fmt(metric), "error": _fmt(err.get(metric) if metric else None),
            "pareto": bool(r.get("pareto")), "reason": str(r.get("reason") or ""),
        })  # fmt: skip
    slope_rows = []
    for key, f in slopes.items():
        f = f if isinstance(f, dict) else {}
        slope_rows.append({
            "series": str(key), "metric": _fmt(f.get("metric")), "cost": _fmt(f.get("cost")),
            "slope_cost": _fmt(f.get("slope_cost")), "slope_time": _fmt(f.get("slope_time")),
            "factor_per_level": _fmt(f.get("factor_per_level")), "points": _fmt(f.get("points")),
            "theory": _fmt(f.get("theory")),
        })  # fmt: skip
    pareto = sweep.get("pareto") if isinstance(sweep.get("pareto"), dict) else {}
    size = sweep.get("size")
    answer = sweep.get("answer_lines") if isinstance(sweep.get("answer_lines"), list) else []
    return {
        "answer": [str(a) for a in answer],
        "scene": _fmt(sweep.get("scene")),
        "size": "×".join(str(s) for s in size) if isinstance(size, list | tuple) else _fmt(size),
        "repeats": _fmt(sweep.get("repeats")),
        "plots": plots,
        "rows": rows,
        "slopes": slope_rows,
        "pareto": [(str(k), _fmt(v)) for k, v in pareto.items()],
    }


# ---------------------------------------------------------------------------------------------
# The page


def _counts(result: CheckResult) -> dict[str, dict[str, int]]:
    backends = {v: 0 for v in SEVERITY}
    scenes = {v: 0 for v in SEVERITY}
    for s in result.scenes:
        scenes[s.verdict] = scenes.get(s.verdict, 0) + 1
        for b in s.backends.values():
            backends[b.verdict] = backends.get(b.verdict, 0) + 1
    return {"backends": backends, "scenes": scenes}


def _versions(result: CheckResult) -> list[tuple[str, str]]:
    seen: dict[str, list[str]] = {}
    for s in result.scenes:
        if s.reference is not None:
            seen.setdefault("reference", []).append(_version(s.reference.meta))
        for b in s.backends.values():
            if b.result is not None and b.result.meta.get("version") is not None:
                seen.setdefault(b.backend, []).append(_version(b.result.meta))
            else:
                seen.setdefault(b.backend, [])
    out = []
    for name, vs in seen.items():
        uniq = list(dict.fromkeys(vs))
        out.append((name, "; ".join(uniq) if uniq else "not run"))
    return out


def _matrix_row(i: int, sc: SceneCheck, names: list[str]) -> dict[str, Any]:
    keys = list(sc.backends)
    cells = []
    for n in names:
        if n in sc.backends:
            b = sc.backends[n]
            anchor = f"scene-{i}-{_slug(n, f'b{keys.index(n)}')}"
            cells.append({"verdict": b.verdict, "label": _label(b.verdict, b.inconclusive), "anchor": anchor})
        else:
            cells.append(None)
    return {"anchor": f"scene-{i}", "name": sc.scene, "verdict": sc.verdict, "cells": cells}


def write_report(
    result: CheckResult,
    out_dir: Path,
    *,
    command: str,
    sweep: dict | None = None,
    sweep_dir: Path | None = None,
    progress: Progress | None = None,
    date: str | None = None,
) -> Path:
    """Write DIR/index.html, DIR/report.json and DIR/assets/; return the index.html path.

    ``command`` is the exact command that reproduces the report (shown on the page). ``sweep`` is
    minirt.sweep.run.run_sweep's dict (or None; if None and ``sweep_dir`` holds a sweep.json, that is
    read); its PNGs are copied from ``sweep_dir``. ``progress(done, total, label)`` is called
    before each step and once at the end with done == total. ``date`` defaults to now (UTC).
    """
    out_dir = Path(out_dir)
    assets = Assets(out_dir / "assets")
    assets.folder.mkdir(parents=True, exist_ok=True)
    date = date or datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    total = len(result.scenes) + 2
    done = 0

    def step(label: str) -> None:
        nonlocal done
        if progress:
            progress(done, total, label)
        done += 1

    scene_order = sorted(enumerate(result.scenes), key=lambda ip: (_rank(ip[1].verdict), ip[0]))
    scenes = []
    for i, sc in scene_order:
        step(f"scene {i + 1}/{len(result.scenes)}")
        scenes.append(_scene_view(i, sc, assets))
    step("sweep")
    sweep_view = _sweep_view(sweep, sweep_dir, assets)
    step("page")
    meta = {
        "command": command,
        "date": date,
        "machine": _machine(),
        "versions": dict(_versions(result)),
        "assets": sorted(assets.written),
    }
    backend_names = list(dict.fromkeys(b for s in result.scenes for b in s.backends))
    index = out_dir / "index.html"
    write_page(
        index,
        "report.html",
        page_parts("report.js", "report.css"),
        verdict=result.verdict,
        counts=_counts(result),
        order=SEVERITY,
        meta=meta,
        versions=_versions(result),
        scenes=scenes,
        backend_names=backend_names,
        matrix=[_matrix_row(i, s, backend_names) for i, s in scene_order],
        thresholds=[(k, _fmt(t.value), t.why) for k, t in THRESHOLDS.items()],
        filter_counts={v: sum(v in sv["verdicts"].split() for sv in scenes) for v in SEVERITY},
        sweep=sweep_view,
        sample_command=SAMPLE_COMMAND,
        goldens_command=GOLDENS_COMMAND,
        verdict_order=ORDER,
    )
    data = {**result.as_dict(), "report": meta}
    if sweep is not None:
        data["sweep"] = sweep
    write_json(out_dir / "report.json", data)
    assets.prune()
    if progress:
        progress(total, total, "done")
    return index


def refresh_sample(out: Path = Path("reports/sample"), size: int = 64, backends: str = "all") -> Path:
    """Check the bundled scenes at size x size with every backend and write the committed sample report.

    Run from the repository root: ``make sample``.
    """
    from minirt.harness import backends as bk
    from minirt.harness.attribution import check_variants
    from minirt.harness.run import check_scene

    root = Path(__file__).resolve().parents[2]  # the repository: minirt/pages/report.py
    paths = sorted((root / "scenes").glob("*.toml"))
    names = bk.parse_backends(backends)
    here = Path.cwd().resolve() == root  # relative paths on the page when run from the repository root
    variants = check_variants()  # one for the run's rule diagnoses
    scenes = [check_scene(p.relative_to(root) if here else p, names, (size, size), variants=variants)
              for p in paths]  # fmt: skip
    result = CheckResult(verdict=worst([s.verdict for s in scenes]), scenes=scenes)
    return write_report(result, out, command=SAMPLE_COMMAND)
