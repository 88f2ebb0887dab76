"""A program's grade as one page: ``write_program_page(grade, FILE)`` writes FILE, a single HTML file
with its pictures inside it (``data:`` URIs, minirt.pages.assets.InlineAssets), to mail to a student or
attach to a submission.

It shows the program (the SPEC, the edition, the compile result with the compiler's own message), the
program's one diagnosis over the suite (minirt.grading.program: the rules named with their evidence, the
"one of" sentence where the images cannot decide, the rules the search took that the images do not bear
out, the pixels broken, those no rule explains grouped by scene, the pairs no scene tells apart), and
every scene of the suite: the program's image, the exercise's model of the scene under the diagnosed
rules, and the difference between the two (magma, as the one-image page draws it: minirt.grading.page),
with the scene's verdict -- or its error, with the reason.

Like the one-image page: every string from the program, its messages or a scene is text (escaped), the
page loads nothing from the network (its Content Security Policy), and the same grade writes the same
bytes (no dates, no timings); the file is written atomically (minirt.io.atomic), so a failing run
leaves no half-written page.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from minirt import diagnose as dg
from minirt.grading import grade as grading
from minirt.grading.page import CLIP, TILE, VERDICT_CLASS, as8, colorbar, grade_parts, heat_map
from minirt.grading.program import ProgramGrade, SceneGrade
from minirt.model import bitmap
from minirt.model import rules as rules_mod
from minirt.pages.assets import InlineAssets, display, write_page

# The compiler's message on the page: its first lines (a template error can run to thousands of lines;
# the first error is what the student fixes first).
COMPILE_LINES = 60


def _picture(assets: InlineAssets, pixels, disp: dict[str, Any], **extra: Any) -> dict[str, Any]:
    size = {"w": max(1, round(pixels.shape[1] * disp["scale"])), "h": max(1, round(pixels.shape[0] * disp["scale"]))}
    return {"src": assets.image8("picture.png", pixels), **size, **extra}


def scene_view(s: SceneGrade, changes: dict[str, Any], unexplained: int, assets: InlineAssets) -> dict[str, Any]:
    """One scene of the suite as the page shows it: its verdict and error, and where the program drew an
    image, that image beside the model under the diagnosed rules (``changes``, the joint diagnosis's
    overrides of the scene's rules) and the difference picture. ``unexplained``: the pixels of this scene
    the joint diagnosis leaves beyond tolerance."""
    w, h = s.scene.camera.width, s.scene.camera.height
    v: dict[str, Any] = {
        "scene": s.scene.name,
        "scene_file": s.scene_file,
        "size": f"{w}×{h}",
        "verdict": s.verdict,
        "vclass": VERDICT_CLASS.get(s.verdict, "v-skip"),
        "error": s.error,
        "pictures": [],
    }
    if s.target is None or s.diagnosis is None:
        return v
    rules = replace(s.rules, **changes)
    cache = dg.VariantCache(share=False)
    color = cache.get(s.scene, rules).color
    disp = display(w, h, TILE)
    fmt = "float" if s.target.is_float else "8-bit"
    levels = grading.difference_levels(s, color, rules)
    named = ", ".join(f"{k}={rules_mod.format_rule_value(k, x)}" for k, x in sorted(changes.items()))
    v.update(
        pixelated=disp["pixelated"],
        image_format=fmt,
        as_given=s.diagnosis.as_given_pixels,
        unexplained=unexplained,
        pixels=w * h,
        peak=_levels(levels),
        fits=s.target.difference(color, rules) is not None,
    )
    v["pictures"] = [
        _picture(assets, as8(s.target.pixels, s.target.is_float), disp, title="the program's image",
                 what=f"{s.image} ({fmt})"),
        _picture(assets, bitmap.bitmap(color, rules), disp, title="the model, diagnosed rules",
                 what=named or "the scene's own rules"),
        _picture(assets, heat_map(levels, None), disp, title="difference",
                 what=f"the image − the model, diagnosed rules: at most {_levels(levels)} levels"),
    ]  # fmt: skip
    if changes:  # where the diagnosed rules show: the difference from the scene's own model
        before = grading.difference_levels(s, cache.get(s.scene, s.rules).color, s.rules)
        v["pictures"].append(
            _picture(
                assets,
                heat_map(before, None),
                disp,
                title="before the diagnosis",
                what=f"the image − {model_name(s.rules)}: at most {_levels(before)} levels",
            )
        )
    return v


def model_name(rules) -> str:
    """What the page calls the model a program is graded against: the 2014 edition's for a 2014 source
    (``grading.given_rules``), else the exercise's (the scene's rules). One of these two constants: the
    page's template writes it unescaped, its apostrophe as the rest of the page's text."""
    from minirt.model.rules import PROFILES

    return "the 2014 edition's model" if rules == PROFILES["eth2014"] else "the exercise's model"


def _levels(levels) -> str:
    """The largest difference, in levels, as the caption says it (whole levels exactly, else two decimals)."""
    finite = levels[np.isfinite(levels)]
    m = float(finite.max()) if finite.size else 0.0
    said = f"{m:.0f}" if m == int(m) else f"{m:.2f}"
    return said if finite.size == levels.size else f"{said} (and NaN or infinite pixels)"


def _group(u: dict[str, Any]) -> dict[str, Any]:
    """A group of unexplained pixels (minirt.diagnose.rest), with its scene and its fit's sentence."""
    return {"scene": u["scene"], "pixels": u["pixels"], "sentence": u["sentence"],
            "fit": (u.get("fit") or {}).get("sentence")}  # fmt: skip


def _diagnosis_view(g: ProgramGrade) -> dict[str, Any]:
    d = g.as_dict()["diagnosis"]
    return {
        "explained": [
            {**e, "per_scene": ", ".join(f"{k} {n}" for k, n in e["per_scene"].items())} for e in d["explained"]
        ],
        "undetermined": d["undetermined_sentence"] or "",
        "rejected": d["rejected"],
        "broken": d["broken_pixels"],
        "mismatch": d["mismatch_pixels"],
        "unexplained": [_group(u) for u in d["unexplained"]],
        "indistinguishable": [
            {"rule": str(i.get("rule")), "value": str(i.get("value")), "as": str(i.get("as")), "why": str(i.get("why"))}
            for i in g.diagnosis.indistinguishable
        ],
    }


def program_view(g: ProgramGrade, assets: InlineAssets) -> dict[str, Any]:
    """The page's content: the program, its diagnosis, its scenes."""
    spec = g.spec.describe()
    compiled = None
    if g.compile is not None:
        lines = str(g.compile.get("message") or "").splitlines()
        more = len(lines) - COMPILE_LINES
        compiled = {
            "ok": bool(g.compile.get("ok")),
            "message": "\n".join(lines[:COMPILE_LINES]) + (f"\n… {more} more line(s)" if more > 0 else ""),
        }
    per_scene: dict[str, int] = {}
    for u in g.diagnosis.unexplained:
        per_scene[u["scene"]] = per_scene.get(u["scene"], 0) + int(u["pixels"])
    return {
        "verdict": g.verdict,
        "vclass": VERDICT_CLASS.get(g.verdict, "v-skip"),
        "summary": g.summary(),
        "spec": spec,
        "compile": compiled,
        "diagnosis": _diagnosis_view(g),
        "scenes": [scene_view(s, g.diagnosis.changes, per_scene.get(s.scene.name, 0), assets) for s in g.scenes],
        "drawn": sum(s.target is not None for s in g.scenes),
        "colorbar": colorbar(assets),
        "clip": CLIP,
        "notes": list(g.notes),
        "model": model_name(g.scenes[0].rules) if g.scenes else "the exercise's model",
    }


def write_program_page(g: ProgramGrade, path: Path) -> Path:
    """Write the program's page to ``path`` (one file, atomically); return its path."""
    path = Path(path)
    view = program_view(g, InlineAssets())
    write_page(path, "grade_program.html", grade_parts(), p=view)
    return path
