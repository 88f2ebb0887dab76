"""The grade as a page: one static HTML page per graded image, and a class index.

``write_grade_page(grade, DIR)`` writes ``DIR/index.html`` (or ``DIR/<stem>.html``) and its images in
``DIR/assets/``: the verdict, the image as stored beside the exercise's model and the best-matching
variant (one scale, no smoothing), difference heat maps before and after the diagnosis, one block per
rule that explains pixels (with the sentence a student understands and the pixels it explains drawn on
the image), the rules this scene cannot tell apart, and the command that reproduces the image.

``write_class_page(rows, summary, DIR)`` writes one such page per graded row into ``DIR/pages/`` and a
class table (students x scenes) with the most common mistakes in ``DIR/index.html``.

Like minirt.pages.report (the parts both share are in minirt.pages.assets): the pages open from disk
and load nothing from the network (a Content Security Policy allows images from the page's folder,
inline styles, and only the page's own script, by hash); every string from a scene, an image's path or
a student's folder is text (its control characters written as escapes, minirt.io.untrusted.page_text, then
Jinja2's autoescape); file names are made from a sanitised stem and
fixed words only; every file is written atomically; and the same grade writes the same bytes (no
dates, no timings).

Cheap per page, since a class has hundreds: the heat maps are NumPy-coloured PNGs at the scene's own
size (magma, clipped at ``CLIP`` levels) with one small colour-bar image shared by every page in the
folder, and images with the same pixels (the exercise's model of a scene, shared by every student)
are written once per run.
"""

from __future__ import annotations

import functools
import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from minirt import diagnose as dg
from minirt.grading import grade as grading
from minirt.grading.grade import ClassRow, Grade
from minirt.model import bitmap
from minirt.model import rules as rules_mod
from minirt.model.result import to8
from minirt.pages.assets import SKY, YELLOW, Assets, display, highlight, page_parts, write_page

MASK_RGB = YELLOW  # pixels a rule explains, on the darkened image
ILL_RGB = SKY  # ill-conditioned pixels on the heat maps (not in the magma colour map)
CLIP = 32  # heat maps: 8-bit levels 0..CLIP, larger differences drawn as CLIP
TILE = 320  # target display size of the longest image side, CSS pixels
COLORBAR = "levels-colorbar.png"  # the one shared file in an assets folder (a fixed name)

VERDICT_CLASS = {grading.MATCH: "v-pass", grading.DIFFERS: "v-warn", grading.ERROR: "v-fail"}
VERDICTS = (grading.MATCH, grading.DIFFERS, grading.ERROR)

# ---------------------------------------------------------------------------------------------
# Names


def safe_stem(text: str, fallback: str = "page") -> str:
    """A file-name part: [A-Za-z0-9._-] only, no leading dot, at most 80 characters."""
    s = re.sub(r"[^A-Za-z0-9._-]+", "_", str(text)).strip("_")[:80]
    if not s or s.startswith("."):
        s = f"_{s}" if s else fallback
    return s


def _unique(stem: str, used: set[str]) -> str:
    """``stem``, or stem-2, stem-3, ... when taken (compared case-insensitively: macOS, Windows)."""
    cand, k = stem, 1
    while cand.lower() in used:
        k += 1
        cand = f"{stem}-{k}"
    used.add(cand.lower())
    return cand


# ---------------------------------------------------------------------------------------------
# Images


def colorbar(assets: Assets) -> str:
    """The heat maps' colour bar, under its fixed name (the same pixels on every page)."""
    return assets.shared(COLORBAR, _lut()[None, :, :])


@functools.cache
def _lut() -> np.ndarray:
    """Magma at the levels 0..CLIP, (CLIP + 1, 3) uint8."""
    import matplotlib

    rgba = np.asarray(matplotlib.colormaps["magma"](np.linspace(0.0, 1.0, CLIP + 1)))
    return np.floor(rgba[:, :3] * 255.0 + 0.5).astype(np.uint8)


def heat_map(levels: np.ndarray, ill: np.ndarray | None) -> np.ndarray:
    """A difference picture: per pixel its level (0..CLIP, larger drawn as CLIP) in magma, ``ill`` in SKY."""
    idx = np.clip(np.rint(np.nan_to_num(levels, nan=CLIP, posinf=CLIP)), 0, CLIP).astype(np.intp)
    img = _lut()[idx]
    if ill is not None and ill.shape == levels.shape:
        img[ill] = ILL_RGB
    return img


def as8(pixels: np.ndarray, is_float: bool) -> np.ndarray:
    """An image as a page shows it: 8-bit (a float image written as the exercise's bitmap would)."""
    return to8(pixels) if is_float else np.asarray(pixels, dtype=np.uint8)


def _size(shape: tuple[int, ...], disp: dict[str, Any]) -> dict[str, int]:
    return {"w": max(1, round(shape[1] * disp["scale"])), "h": max(1, round(shape[0] * disp["scale"]))}


# ---------------------------------------------------------------------------------------------
# View models


def _tolerance(g: Grade) -> str:
    return f"{dg.FLOAT_TOL:g} per channel (float image)" if g.target.is_float else "1 level per channel (8-bit image)"


def rule_sentence(rule: str, yours: Any, given: Any) -> str:
    """grading.sentence for a rule's value (yours) against the given one; "" where it has none to say."""
    try:
        return grading.sentence(rule, yours, given)
    except (KeyError, TypeError, ValueError, IndexError):
        return ""


def _picture(assets: Assets, name: str, pixels: np.ndarray, disp: dict[str, Any], **extra: Any) -> dict[str, Any]:
    return {"src": assets.image8(name, pixels), **_size(pixels.shape, disp), **extra}


def _grade_view(g: Grade, stem: str, assets: Assets) -> dict[str, Any]:
    v: dict[str, Any] = {
        "verdict": g.verdict,
        "vclass": VERDICT_CLASS.get(g.verdict, "v-skip"),
        "scene": g.scene.name if g.scene is not None else "",
        "scene_file": g.scene_file,
        "image": g.image,
        "summary": g.summary(),
        "reason": g.reason,
        "notes": list(g.notes),
    }
    d = g.diagnosis
    if d is None or g.target is None:
        v["error"] = True
        return v
    w, h = g.scene.camera.width, g.scene.camera.height
    disp = display(w, h, TILE)
    fmt = "float" if g.target.is_float else "8-bit"
    v.update(
        error=False,
        size=f"{w}×{h}",
        pixels=d.pixels,
        image_format=fmt,
        tolerance=_tolerance(g),
        ill=int(d.ill.sum()),
        pixelated=disp["pixelated"],
        pictures=_pictures(g, stem, assets, disp),
    )
    heat = []
    for name, title, color, rules, count in (
        ("diff-given", "before: image − exercise's model", d.given_color, d.given, d.as_given_pixels),
        ("diff-best", "after: image − best-matching variant", d.best_color, d.best, d.mismatch_pixels),
    ):
        lv = grading.difference_levels(g, color, rules)
        fits = g.target.difference(color, rules) is not None
        heat.append(
            _picture(
                assets,
                f"{stem}-{name}.png",
                heat_map(lv, d.ill),
                disp,
                title=title,
                mismatch=count,
                peak=_peak(lv),
                fits=fits,
            )
        )
    v["heatmaps"] = heat
    v["colorbar"] = colorbar(assets)
    v["clip"] = CLIP
    v["explained"], v["groups"] = _explained_and_groups(g, stem, assets, disp)
    v["mask_rgb"] = "#{:02x}{:02x}{:02x}".format(*MASK_RGB)
    v["ill_rgb"] = "#{:02x}{:02x}{:02x}".format(*ILL_RGB)
    v["indistinguishable"] = [
        {"rule": str(i.get("rule")), "value": str(i.get("value")), "as": str(i.get("as")),
         "scene": i.get("scene_that_tells")}
        for i in d.indistinguishable
    ]  # fmt: skip
    v["undetermined"] = d.one_of.sentence if d.one_of else ""
    v["rejected"] = [r.as_dict() for r in d.rejected]
    v["broken"] = d.broken_pixels
    v["changed"] = bool(d.reproducing)
    v["unexplained"] = d.mismatch_pixels
    v["as_given"] = d.as_given_pixels
    v["reproduce"] = g.reproduce()
    v["steps"] = [
        {"rules": ", ".join(map(str, s.get("rules", []))), "gain": s.get("gain", 0),
         "gain_one_level": s.get("gain_one_level", 0)}
        for s in d.steps
    ]  # fmt: skip
    v["renders"] = f"{d.renders:g}"
    return v


def _pictures(g: Grade, stem: str, assets: Assets, disp: dict[str, Any]) -> list[dict[str, Any]]:
    """The image as stored, the exercise's model of the scene, and the best-matching variant, side by side."""
    d = g.diagnosis
    fmt = "float" if g.target.is_float else "8-bit"
    student8 = as8(g.target.pixels, g.target.is_float)
    given8 = bitmap.bitmap(d.given_color, d.given)
    best8 = bitmap.bitmap(d.best_color, d.best)
    return [
        _picture(
            assets,
            f"{stem}-image.png",
            student8,
            disp,
            title="the image, as stored",
            what=f"{student8.shape[1]}×{student8.shape[0]}, {fmt}",
        ),
        _picture(
            assets,
            f"{stem}-given.png",
            given8,
            disp,
            title="the exercise's model",
            what="the scene's rules, written the exercise's way",
        ),
        _picture(
            assets,
            f"{stem}-best.png",
            best8,
            disp,
            title="best-matching variant",
            what=", ".join(f"{k}={x}" for k, x in sorted(d.changed.items())) or "the scene's rules",
        ),
    ]


def _explained_and_groups(g: Grade, stem: str, assets: Assets, disp: dict[str, Any]) -> tuple[list, list]:
    """The page's rules (each with its evidence, its sentence and the pixels it explains over the image) and
    its unexplained groups (each with its mask, its fit and the probe command for one of its pixels)."""
    d = g.diagnosis
    w, h = g.scene.camera.width, g.scene.camera.height
    explained = []
    base = g.target.in_layout(d.best)
    base8 = as8(base, g.target.is_float) if base is not None and base.shape[:2] == (h, w) else None
    for k, e in enumerate(d.explained):
        yours, given = getattr(d.best, e.rule), getattr(d.given, e.rule)
        item = {
            "rule": e.rule,
            "value": e.value,
            "given": rules_mod.format_rule_value(e.rule, given),
            "pixels": e.pixels,
            "against": e.against,
            "neither": e.neither,
            "decided": e.rule not in d.undetermined,
            "sentence": rule_sentence(e.rule, yours, given),
            "picture": None,
        }
        if base8 is not None and e.mask is not None and e.mask.shape == (h, w):
            rule_part = e.rule if re.fullmatch(r"[a-z][a-z0-9_]{0,31}", e.rule) else "rule"
            shown = highlight(base8, e.mask, MASK_RGB)
            item["picture"] = _picture(assets, f"{stem}-rule{k}-{rule_part}.png", shown, disp)
        explained.append(item)
    groups = []
    for k, u in enumerate(d.unexplained):
        item = {"pixels": u.pixels, "sentence": u.sentence, "example": u.example, "picture": None,
                "probe": g.probe_command(*u.example),
                "fit": u.fit.sentence if u.fit is not None else None,
                "fit_reproduces": bool(u.fit is not None and u.fit.reproduces)}  # fmt: skip
        if base8 is not None and u.mask.shape == (h, w):
            item["picture"] = _picture(assets, f"{stem}-rest{k}.png", highlight(base8, u.mask, MASK_RGB), disp)
        groups.append(item)
    return explained, groups


def _peak(levels: np.ndarray) -> str:
    if not levels.size:
        return "0"
    m = float(np.nanmax(levels))
    return f"{m:.0f}" if m == int(m) else f"{m:.2f}"


# ---------------------------------------------------------------------------------------------
# Pages


def grade_parts() -> dict[str, Any]:
    """The grade pages' style (the report's, and their own) and their only script, a self-check for the
    browser test (and anyone who opens the console)."""
    return page_parts("grade.js", "report.css", "grade.css")


def _write_page(g: Grade, out_dir: Path, stem: str, assets: str, by_content: bool, back: str | None) -> Path:
    out_dir = Path(out_dir)
    stem = safe_stem(stem, "index")
    href = "/".join(safe_stem(p, "assets") for p in Path(assets).parts) or "assets"
    folder = out_dir / href
    folder.mkdir(parents=True, exist_ok=True)
    view = _grade_view(g, stem, Assets(folder, href, by_content))
    page = out_dir / f"{stem}.html"
    write_page(page, "grade.html", grade_parts(), g=view, back=back)
    return page


def write_grade_page(g: Grade, out_dir: Path, stem: str = "index", assets: str = "assets") -> Path:
    """Write ``out_dir/<stem>.html`` and its images in ``out_dir/<assets>/``; return the page's path."""
    return _write_page(g, out_dir, stem, assets, False, None)


@dataclass
class _Cell:
    verdict: str
    vclass: str
    page: str
    reason: str
    rules: str


@dataclass
class _Table:
    students: list[str]
    scenes: list[str]
    cells: dict[tuple[str, str], _Cell] = field(default_factory=dict)


def _mistake_views(rows: list[ClassRow], mistakes: Iterable[dict[str, Any]]) -> list[dict[str, Any]]:
    """The summary's common mistakes with a sentence: from a row that has the mistake (the sentences kept
    with it, or its grade's), else parsed back from the text against the rule's listed values and the
    first grade's given rules."""
    graded = [r.grade for r in rows if r.grade is not None and r.grade.diagnosis is not None]
    said: dict[tuple[str, str], str] = {}
    for r in rows:
        said.update({(k, r.rules[k]): text for k, text in r.sentences.items() if k in r.rules})
    for g in graded:
        d = g.diagnosis
        for k, value in d.changed.items():
            said.setdefault((k, value), rule_sentence(k, getattr(d.best, k), getattr(d.given, k)))
    out = []
    for m in mistakes:
        rule, value = str(m.get("rule")), str(m.get("value"))
        s = said.get((rule, value), "")
        if not s and graded and rule in rules_mod.TRACE_RULES + rules_mod.OUTPUT_RULES:
            given = getattr(graded[0].diagnosis.given, rule)
            typed = [x for x in rules_mod.values(rule) if rules_mod.format_rule_value(rule, x) == value]
            if typed:
                s = rule_sentence(rule, typed[0], given)
        out.append({"rule": rule, "value": value, "students": m.get("students", 0), "images": m.get("images", 0),
                    "differing": m.get("differing_images", 0), "sentence": s})  # fmt: skip
    return out


def page_stems(keys: Iterable[tuple[str, str]]) -> list[str]:
    """The page stem of each (student, scene), in order: sanitised, and unique case-insensitively (a
    class's pages are named before any is graded, so every worker writes the name the index links)."""
    used: set[str] = set()
    return [_unique(f"{safe_stem(student, 'student')}-{safe_stem(scene, 'scene')}", used) for student, scene in keys]


def write_row_page(row: ClassRow, out_dir: Path, stem: str) -> None:
    """Write the page of one graded row of a class into ``out_dir/pages/<stem>.html`` (its pictures in
    ``pages/assets/``) and set ``row.page`` to its link; a row without a grade (an error) gets none."""
    if row.grade is None:
        row.page = ""
        return
    page = _write_page(row.grade, Path(out_dir) / "pages", stem, "assets", True, "../index.html")
    row.page = f"pages/{page.name}"


def _unexplained_view(m: dict[str, Any]) -> dict[str, Any]:
    """A common group of unexplained pixels (classroom.common_unexplained) as the class page shows it."""
    return {
        "scene": str(m.get("scene")),
        "shapes": ", ".join(map(str, m.get("shapes", []))),
        "students": int(m.get("students", 0)),
        "images": int(m.get("images", 0)),
        "pixels": int(m.get("pixels", 0)),
        "sentence": str(m.get("sentence", "")),
    }


def write_class_page(rows: list[ClassRow], summary: dict, out_dir: Path, quiet: bool = True) -> Path:
    """Write a page per graded row that has none yet into ``out_dir/pages/`` (setting ``row.page`` to its
    link; a class graded by ``classroom.grade_class`` arrives with its pages written) and the class table
    ``out_dir/index.html``, with the class folder's entries that were skipped (``summary["skipped"]``) and
    why; return the index's path."""
    out_dir = Path(out_dir)
    (out_dir / "pages").mkdir(parents=True, exist_ok=True)
    stems = page_stems((r.student, r.scene) for r in rows)
    todo = [(r, stem) for r, stem in zip(rows, stems, strict=True) if r.grade is not None and not r.page]
    progress = None if quiet or not todo else _progress(len(todo))
    try:
        for r, stem in todo:
            write_row_page(r, out_dir, stem)
            if progress:
                progress.advance(r.student, r.scene)
    finally:
        if progress:
            progress.close()

    students = [str(s) for s in summary.get("students") or sorted({r.student for r in rows})]
    scenes = [str(s) for s in summary.get("scenes") or sorted({r.scene for r in rows})]
    table = _Table(students, scenes)
    for r in rows:
        table.cells[(r.student, r.scene)] = _Cell(
            r.verdict, VERDICT_CLASS.get(r.verdict, "v-skip"), r.page, r.reason,
            " ".join(f"{k}={x}" for k, x in sorted(r.rules.items())),
        )  # fmt: skip
    counts = {v: int((summary.get("verdicts") or {}).get(v, 0)) for v in VERDICTS}
    per_scene = {s: {v: 0 for v in VERDICTS} for s in scenes}
    for r in rows:
        if r.scene in per_scene and r.verdict in VERDICTS:
            per_scene[r.scene][r.verdict] += 1
    index = out_dir / "index.html"
    write_page(
        index,
        "grade_class.html",
        grade_parts(),
        table=table,
        counts=counts,
        per_scene=per_scene,
        verdicts=VERDICTS,
        vclass=VERDICT_CLASS,
        mistakes=_mistake_views(rows, summary.get("common_mistakes") or []),
        unexplained=[_unexplained_view(m) for m in summary.get("common_unexplained") or []],
        total=len(rows),
        skipped=[(str(k.get("folder", "")), str(k.get("reason", ""))) for k in summary.get("skipped") or []],
    )
    return index


class _progress:
    """A progress line on standard error while the pages are written (the CLI's --quiet turns it off)."""

    def __init__(self, total: int):
        from rich.console import Console
        from rich.progress import Progress

        self.bar = Progress(console=Console(stderr=True), transient=True)
        self.bar.start()
        self.task = self.bar.add_task("pages", total=total)

    def advance(self, student: str, scene: str) -> None:
        from rich.markup import escape

        self.bar.update(self.task, advance=1, description=escape(f"page {student[:16]:<16} {scene[:12]:<12}"))

    def close(self) -> None:
        self.bar.stop()
