"""One pixel, traced step by step by the reference tracer itself (not a re-implementation).

The tracer runs on a batch of one ray with recording on; every level of the recursion reports its
ray, each shape's intersection, the closest hit, the shadow ray and what blocked it, the terms (the
specular one under the rules clamp and specular_exponent; secondary rays offset per offset and
offset_along). ``sample`` is where the primary ray crosses the pixel grid (pixel_sample, pixel_shift);
``color8`` is written under the output rules encoding and gamma.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from minirt.errors import MinirtError
from minirt.model import camera
from minirt.model.result import to8
from minirt.model.rules import Rules
from minirt.model.scene import Ball, Scene
from minirt.reference import hazards
from minirt.reference.tracer import Tracer


def _v(a: Any) -> list[float]:
    return [float(np.asarray(a[i])[0]) for i in range(3)]


def _s(a: Any) -> float:
    return float(np.asarray(a)[0])


def _t(x: float) -> float | None:
    return None if math.isinf(x) else x


def probe(scene: Scene, rules: Rules, x: int, y: int, precision: str = "f64") -> dict[str, Any]:
    w, h = scene.camera.width, scene.camera.height
    if not (0 <= x < w and 0 <= y < h):
        raise MinirtError(f"pixel ({x}, {y}) is outside the {w}x{h} image (0 <= X < {w}, 0 <= Y < {h})")
    o_all, d_all = camera.primary_rays(scene, rules)
    i = y * w + x
    tr = Tracer(scene, rules, precision=precision)
    o, d = tr.load(o_all[i : i + 1]), tr.load(d_all[i : i + 1])
    color, levels = tr.trace(o, d, record=True)
    out_levels = []
    for depth, lvl in enumerate(levels):
        shapes = []
        for k, s in enumerate(scene.shapes):
            tk = _s(tr.intersect(s, lvl.o, lvl.d))
            shapes.append({"id": k, "type": "ball" if isinstance(s, Ball) else "plane", "t": _t(tk)})
        sid = int(np.asarray(lvl.shape_id)[0])
        entry: dict[str, Any] = {
            "depth": depth,
            "ray": {"origin": _v(lvl.o), "direction": _v(lvl.d)},
            "shapes": shapes,
            "hit": None,
            "terms": {k: _v(v) for k, v in lvl.terms.items()},
        }
        if sid >= 0:
            rec = lvl.record
            entry["hit"] = {
                "id": sid,
                "material": scene.shapes[sid].material.name,
                "t": _s(lvl.t),
                "point": _v(lvl.p),
                "normal": _v(lvl.n),
                "shading_normal": _v(rec["shading_normal"]),
                "reflection_color": _v(lvl.kr),
            }
            if "shadow_origin" in rec:
                ts = [_s(t) for t in rec["shadow_ts"]]
                dist = _s(rec["light_dist"])
                limit = math.inf if rules.shadow_range == "any" else dist
                entry["shadow"] = {
                    "origin": _v(rec["shadow_origin"]),
                    "direction": _v(rec["shadow_dir"]),
                    "light_distance": dist,
                    "blockers": [{"id": k, "t": t} for k, t in enumerate(ts) if t < limit],
                }
                entry["shadow"]["lit"] = not entry["shadow"]["blockers"]
            if rec.get("error_bound") is not None:
                entry["hit"]["offset_bound"] = _s(rec["error_bound"])
            # the offset's hazards at this point (minirt.reference.hazards): below the point's rounding, gaps jumped
            spawns = depth + 1 < len(levels)
            entry["offset"] = hazards.offset_at(
                scene, rules, entry["hit"]["point"], entry["hit"]["shading_normal"], sid,
                shadow=entry["shadow"]["direction"] if "shadow" in entry else None,
                reflection=_v(rec["reflected"]) if spawns and "reflected" in rec else None,
                precision=precision,
            )  # fmt: skip
        out_levels.append(entry)
    c = _v(color)
    lvl0 = out_levels[0]
    uv = 0.0 if rules.pixel_sample == "corner" else 0.5
    dx, dy = rules.pixel_shift
    return {
        "scene": scene.name,
        "pixel": [x, y],
        # where the primary ray crosses the pixel grid: (x + u + dx, y + v + dy), rules pixel_sample, pixel_shift
        "sample": [x + uv + dx, y + uv + dy],
        "rules": rules.as_dict(),
        "ray": lvl0["ray"],
        "shapes": lvl0["shapes"],
        "hit": None
        if lvl0["hit"] is None
        else {k: lvl0["hit"][k] for k in ("id", "t", "point", "normal", "shading_normal", "material")},
        "shadow": lvl0.get("shadow"),
        "offset": lvl0.get("offset"),
        "terms": lvl0["terms"],
        "levels": out_levels,
        "color": c,
        "color_clamped": [min(max(v, 0.0), 1.0) for v in c],
        "color8": [int(v) for v in _color8(np.array(c), rules)],
    }


def _color8(c: np.ndarray, rules: Rules) -> np.ndarray:
    """The pixel's 8-bit value as the bitmap is written under the output rules encoding and gamma."""
    if rules.encoding == "round" and rules.gamma == "linear":
        return to8(c)
    from minirt.model.bitmap import encode

    return encode(c.reshape(1, 1, 3), rules.encoding, rules.gamma).reshape(3)


def image_pixel(
    scene: Scene, p: dict[str, Any], target: Any, rules: Rules, notes: list[str] | None = None
) -> dict[str, Any]:
    """Another tracer's value at the probed pixel beside the reference's (``p``, from ``probe``).

    ``target`` is a ``minirt.diagnose.target.Target`` (``minirt.grading.grade.load_target``) whose size
    ``minirt.grading.grade.check_size`` has accepted. It is brought back to the scene's layout under the
    layout rules of ``rules`` -- or, when it is stored transposed and the rules do not say so (the
    note ``check_size`` gives), read transposed. An 8-bit image is compared with the reference's
    8-bit value written under the output rules (``color8``), a float image with the clamped colour
    through the gamma rule; ``difference`` is the largest channel's (levels, or float units)."""
    from dataclasses import replace

    from minirt.model.bitmap import transfer

    x, y = p["pixel"]
    shape = (scene.camera.height, scene.camera.width)
    img = target.in_layout(rules)
    transposed = False
    if img.shape[:2] != shape:
        img = target.in_layout(replace(rules, transpose=not rules.transpose))
        transposed = True
    if img.shape[:2] != shape:  # check_size rules this out; say so plainly if a caller skipped it
        raise MinirtError(
            f"{target.name}: the image is {target.shape[1]}x{target.shape[0]}, the scene {shape[1]}x{shape[0]}"
        )
    if target.is_float:
        value = [float(v) for v in img[y, x]]
        ref: list[Any] = [float(v) for v in transfer(np.array(p["color"]), rules.gamma)]
    else:
        value = [int(v) for v in img[y, x]]
        ref = [int(v) for v in p["color8"]]
    diff = max(abs(a - b) for a, b in zip(value, ref, strict=True))
    departs = _departs(p, np.array(value, dtype=np.float64), rules, target.is_float)
    return {
        "departs": departs,
        "file": target.name,
        "format": "float" if target.is_float else "8-bit",
        "value": value,
        "reference": ref,
        "difference": diff,
        "unit": "float" if target.is_float else "levels",
        "read_transposed": transposed,
        "notes": list(notes or []),
    }


# The pseudo-code's order of the first level's terms: the colour is built up in these steps.
STEPS = ("ambient", "diffuse", "specular", "reflection", "background")


def _departs(p: dict[str, Any], value: np.ndarray, rules: Rules, is_float: bool) -> str | None:
    """The step of TraceRay where the image's value leaves the reference's, in words (None when it does not):
    the image matched against the colour built up term by term (ambient, then diffuse, ...), and against the
    colour without one term, and against the colour with one term scaled. Within the grade's tolerance: one
    8-bit level, or FLOAT_TOL for floats."""
    from minirt.model.bitmap import encode, transfer

    tol = 2.0**-10 if is_float else 1  # minirt.diagnose.target's FLOAT_TOL and LEVEL_TOL

    def same(c: np.ndarray) -> bool:
        if is_float:
            return bool(np.abs(transfer(np.clip(c, 0, 1), rules.gamma) - value).max() <= tol)
        return bool(np.abs(encode(c.reshape(1, 1, 3), rules.encoding, rules.gamma).reshape(3) - value).max() <= tol)

    terms = {k: np.array(v, dtype=np.float64) for k, v in p["levels"][0]["terms"].items()}
    steps = [k for k in STEPS if k in terms and np.any(terms[k] != 0)]
    full = np.array(p["color"], dtype=np.float64)
    if same(full):
        return None
    hit = p["hit"]
    where = "the background (no hit)" if hit is None else f"shape {hit['id']} at t = {hit['t']:.6g}"
    total = np.zeros(3)
    for k, name in enumerate(steps):
        if same(total) and k > 0:
            return (
                f"your value is the reference's up to the {steps[k - 1]} term and departs at the {name} term "
                f"({', '.join(steps[k:])} missing or different), on {where}"
            )
        total = total + terms[name]
    for name in steps:
        if same(full - terms[name]):
            return f"your value is the reference's without its {name} term, on {where}"
    # one term scaled: value = (colour - term) + a·term, a fitted on the channels where the term shows
    lin = value if is_float else value / 255.0
    fits = []
    if rules.gamma == "linear":
        for name in steps:
            term = terms[name]
            big = np.abs(term) > 1e-3
            if not big.any():
                continue
            a = float(np.median((lin[big] - (full - term)[big]) / term[big]))
            if abs(a - 1) > 1e-3 and same(full - term + a * term):
                fits.append((abs(math.log(abs(a))) if a else math.inf, name, a))
    if fits:  # several terms can be scaled to the value: the one that needs the least change
        _, name, a = min(fits)
        return f"your {name} term is {a:.3g} times the reference's, on {where}"
    return f"none of the reference's steps gives your value: the hit ({where}) or every term differs"
