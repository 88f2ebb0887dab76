"""``minirt probe``: one pixel traced step by step -- its ray, every shape's intersection, the shadow ray,
the shading terms, the reflections and the secondary rays' offset -- and, with --image, another tracer's
value there beside the reference's; with --certified, the exact model's (a certified oracle's).

minirt.reference.probe does the tracing; this module prints what it found.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from minirt.cli.console import emit_json, out
from minirt.cli.options import HeightOpt, Precision, ProfileOpt, RuleOpt, WidthOpt, load
from minirt.io.untrusted import terminal_text


def probe(
    scene_path: Annotated[
        str,
        typer.Argument(
            metavar="SCENE", help="A scene file or a bundled scene's name, e.g. exercise.", show_default=False
        ),
    ],
    x: Annotated[int, typer.Argument(help="Pixel column (0 = left).", show_default=False)],
    y: Annotated[int, typer.Argument(help="Pixel row (0 = top).", show_default=False)],
    as_json: Annotated[
        bool, typer.Option("--json", help="Write the probe as JSON to standard output (strict JSON, nothing else).")
    ] = False,
    image: Annotated[
        Path | None,
        typer.Option(
            "--image", metavar="IMAGE", help="Another tracer's image of the scene: show its value at the pixel too."
        ),
    ] = None,
    width: WidthOpt = None,
    height: HeightOpt = None,
    precision: Annotated[Precision, typer.Option("--precision")] = Precision.f64,
    profile: ProfileOpt = None,
    rule: RuleOpt = None,
    certified: Annotated[
        bool, typer.Option("--certified", help="Also the certified (exact arithmetic) values of the pixel.")
    ] = False,
) -> None:
    """Trace one pixel step by step: ray, every shape's intersection, shadow ray, terms, reflections.

    With --image, the other tracer's value at that pixel beside the reference's (read as `grade` reads it).
    """
    from minirt.model.bundled import find_scene
    from minirt.reference.probe import image_pixel
    from minirt.reference.probe import probe as run_probe

    scene, rules = load(find_scene(scene_path), width, height, None, profile, rule)
    target = notes = None
    if image is not None:
        from minirt.grading.grade import check_size, load_target

        target = load_target(image, scene, resize="probe with --width {w} --height {h}")  # size checked first
        notes = check_size(scene, target, str(image))
    p = run_probe(scene, rules, x, y, precision.value)
    if target is not None:
        p["image"] = image_pixel(scene, p, target, rules, notes)
    if certified:
        from minirt.cli.certified import certified_probe

        p["certified"] = certified_probe(scene, rules, x, y)
    if as_json:
        emit_json("-", p)
        return
    _print_probe(p)


def _fmt(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, list):
        return "(" + ", ".join(f"{c:.9g}" for c in v) + ")"
    return f"{v:.12g}" if isinstance(v, float) else str(v)


def _offset_text(off: dict[str, Any]) -> str:
    """probe's line on the secondary rays' offset at a hit (minirt.reference.hazards.offset_at)."""
    if off["offset"] == "error-bound":
        return "offset: error-bound (secondary rays start the hit point's error bound away)"
    text = f"offset {_fmt(off['offset'])} along the {'new ray' if off['along'] == 'ray' else 'normal'}"
    notes = []
    if off["below_rounding"]:
        notes.append(
            f"below the hit point's rounding {off['rounding']:.3g}: the ray may start behind the surface (acne risk)"
        )
    for j in off["jumps"]:
        notes.append(
            f"the {j['ray']} ray's origin jumps over shape {j['shape']}'s surface, {j['gap']:.3g} from the point "
            "(a near contact): it starts beyond it"
        )
    return text + (": " + "; ".join(notes) if notes else f" (the hit point's rounding is {off['rounding']:.3g}: safe)")


def _print_probe(p: dict[str, Any]) -> None:
    x, y = p["pixel"]
    out.print(f"pixel ({x}, {y}) of {terminal_text(p['scene'])}")
    for lvl in p["levels"]:
        ind = "  " * lvl["depth"]
        head = "primary ray" if lvl["depth"] == 0 else f"reflection {lvl['depth']}"
        out.print(f"{ind}{head}: origin {_fmt(lvl['ray']['origin'])} direction {_fmt(lvl['ray']['direction'])}")
        for s in lvl["shapes"]:
            out.print(f"{ind}  shape {s['id']} ({s['type']}): " + ("miss" if s["t"] is None else f"t = {_fmt(s['t'])}"))
        hit = lvl["hit"]
        if hit is None:
            out.print(f"{ind}  -> no hit")
        else:
            out.print(
                f"{ind}  -> hit shape {hit['id']} ({terminal_text(hit['material'])}) at t = {_fmt(hit['t'])}, "
                f"point {_fmt(hit['point'])}, normal {_fmt(hit['normal'])}"
            )
            sh = lvl.get("shadow")
            if sh:
                blk = ", ".join(f"shape {b['id']} at t = {_fmt(b['t'])}" for b in sh["blockers"]) or "nothing"
                out.print(
                    f"{ind}  shadow ray from {_fmt(sh['origin'])} towards the light "
                    f"({_fmt(sh['light_distance'])} away): blocked by {blk}"
                )
            off = lvl.get("offset")
            if off:
                out.print(f"{ind}  {_offset_text(off)}", markup=False)
        for k, v in lvl["terms"].items():
            out.print(f"{ind}  {k:<10} {_fmt(v)}")
    out.print(f"colour {_fmt(p['color'])} -> clamped {_fmt(p['color_clamped'])} -> 8-bit {tuple(p['color8'])}")
    im = p.get("image")
    if im:
        for note in im["notes"]:
            out.print(f"note: {terminal_text(note)}")
        if im["format"] == "float":
            yours, ref = _fmt(im["value"]), _fmt(im["reference"])
            diff = "the same" if im["difference"] == 0 else f"differs by {im['difference']:.6g}"
        else:
            yours, ref = str(tuple(im["value"])), str(tuple(im["reference"]))
            n = im["difference"]
            diff = "the same" if n == 0 else f"differs by {n} level{'s' if n != 1 else ''}"
        out.print(terminal_text(f"your image: {yours} [{im['format']}]  reference: {ref} -> {diff}"))
        if im.get("departs"):
            out.print(terminal_text(f"where it departs: {im['departs']}"))
    if p.get("certified"):
        from minirt.cli.certified import print_certified

        print_certified(p["certified"])
