"""Hard cases through the student's code: a program's numerical failures on the fuzz campaign's scenes.

``grade --program SPEC --fuzz N`` first grades the program over the suite (minirt.grading.program), which
says which rule settings it follows. Then each of N scenes of the campaign's families (rays starting on
surfaces, grazing rays, contacts, far and huge shapes, scaled scenes, detail below float32's spacing;
drawn by minirt.campaign, seeded) is rendered by the program and compared with the reference under *those*
rules -- the scene's rules with the suite's diagnosis applied -- so a rule the program follows everywhere
(pixel centres, another offset) is not a failure here; what is left is what the hard scene does to it.

When a pixel is a failure (``FAILURE RULE``)
-------------------------------------------
A pixel fails when the program's value is NaN or infinite (any channel of a float image; an 8-bit image
cannot hold one), or when it differs from the reference beyond the grade's own tolerance -- more than one
8-bit level, or more than ``FLOAT_TOL`` for a float image (minirt.diagnose.target: a float32 tracer's
colour error is ~150x below it, a level's rounding step is the one-level allowance) -- *and* the reference's
answer there is robust: neither its primary ray (the hit, the nearest shape, the start inside a ball) nor its
shadow ray is within ``EPS_REL`` of deciding otherwise (minirt.reference.band: the relative rounding of a
float32 tracer, ~1e-6, times the condition of the test). Such a pixel means the same for every tracer whose
arithmetic is at least float32's: the program decided a well-conditioned question differently. Pixels the
reference cannot decide robustly are counted apart (``ill_conditioned``), never as failures.

A program found to start its secondary rays with no offset at all (offset 0) is compared under offset
"error-bound" instead. In exact arithmetic a ray started on a surface does not meet that surface again
(t > 0 excludes the start), so offset 0's exact answer has no self-shadowing; a float64 render of offset 0
has some anyway, wherever rounding put the hit point under the surface -- pixels whose answer is the
rounding's, not the rule's, and which the ill-conditioned flags (silhouettes, the primary band) do not
cover. "error-bound" (pbrt's: the start moved off by the hit point's own error bound) is the robust stand-in
for that exact answer: where the two could differ, the rounding decides, and such a program's acne is
reported as acne, not as shadows the reference lost.

Each failing pixel is named by what the reference knows of it (its primary level's trace, under the same
rules), in this order:

- ``nan``: a NaN or infinite value;
- ``acne``: the reference's primary hit is lit (its shadow ray reaches the light) and the program's pixel is
  darker -- no channel brighter beyond the tolerance, one darker beyond it: the program's shadow test hit
  something the reference's does not, typically the surface its shadow ray starts on (self-shadowing);
- ``lost_shadow``: the reference's primary hit is in shadow and the program's pixel is brighter (the mirror
  condition): its shadow test missed what blocks the light;
- ``other``: any other difference -- a hit lost or gained (a grazing ray, a far or huge ball), what a
  reflection shows.

The classification reads the primary level only: acne seen in a reflection is ``other``. ``float32_pixels``
counts the failing pixels that a float32 render of the reference (same rules) also draws otherwise: there
float32's precision alone may be the cause (a far scene's detail below its spacing), which is still a
failure of the program -- the exercise's arithmetic is double -- but one a float32 tracer cannot avoid.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from minirt import diagnose as dg
from minirt.model import bitmap
from minirt.model.rules import Rules
from minirt.model.scene import Scene

KINDS = ("nan", "acne", "lost_shadow", "other")
OK, FAILS, ERROR = "ok", "fails", "error"
SENTENCES = {
    "nan": "{n} pixels are NaN or infinite",
    "acne": "{n} pixels lit in the reference are darker (the shadow test hits the surface it starts on: acne)",
    "lost_shadow": "{n} pixels in shadow in the reference are brighter (the shadow test misses what blocks the light)",
    "other": "{n} pixels differ otherwise (a hit lost or gained: grazing rays, far or huge shapes, reflections)",
}


@dataclass
class HardCase:
    """One hard scene through the program: its verdict (``ok``, ``fails``, ``error``: no image), the failing
    pixels by kind, those left out as ill-conditioned, and where its file was written (failures only)."""

    scene: str
    family: str
    verdict: str
    pixels: dict[str, int] = field(default_factory=lambda: dict.fromkeys(KINDS, 0))
    ill_conditioned: int = 0
    float32_pixels: int = 0
    example: tuple[int, int] | None = None  # (x, y) of one failing pixel, of the largest kind
    error: str = ""
    scene_file: str = ""

    @property
    def failures(self) -> int:
        return sum(self.pixels.values())

    def sentence(self) -> str:
        if self.verdict == ERROR:
            return self.error
        parts = [SENTENCES[k].format(n=n) for k, n in self.pixels.items() if n]
        return "; ".join(parts) if parts else "no numerical failure"

    def as_dict(self) -> dict[str, Any]:
        return {
            "scene": self.scene,
            "family": self.family,
            "verdict": self.verdict,
            "failures": self.failures,
            "pixels": dict(self.pixels),
            "ill_conditioned": self.ill_conditioned,
            "float32_pixels": self.float32_pixels,
            "example": list(self.example) if self.example else None,
            "sentence": self.sentence(),
            "error": self.error,
            "scene_file": self.scene_file,
        }


def _signed(target: dg.Target, color: np.ndarray, rules: Rules) -> np.ndarray:
    """(H, W, 3) the program's value minus the reference's, in the units the tolerance is in (levels, or
    float units after the gamma rule), in the scene's layout."""
    img = target.in_layout(rules)
    if target.is_float:
        return np.nan_to_num(img.astype(np.float64) - bitmap.transfer(color, rules.gamma))
    return img.astype(np.int16) - bitmap.encode(color, rules.encoding, rules.gamma).astype(np.int16)


def _nonfinite(target: dg.Target, rules: Rules) -> np.ndarray:
    """(H, W) pixels with a NaN or infinite channel, in the scene's layout."""
    if not target.is_float:
        return np.zeros(target.model_shape, dtype=bool)
    bad = (~np.isfinite(target.pixels)).astype(np.float32)
    return bitmap.undo_layout(bad, **bitmap.layout_of(rules)).max(-1) > 0


def classify(scene: Scene, rules: Rules, target: dg.Target, cache: dg.VariantCache) -> dict[str, Any] | None:
    """The failing pixels of ``target`` against the reference under ``rules`` (the module's rule): per kind,
    the ill-conditioned count, the float32 count and an example pixel; None when the image's layout under
    ``rules`` does not fit the scene."""
    from minirt.diagnose.rest import primary

    h, w = scene.camera.height, scene.camera.width
    target.model_shape = (h, w)
    v = cache.get(scene, rules, f32=True)
    d = target.difference(v.color, rules)
    if d is None:  # a transposed layout the suite found, on a scene that is not square
        return None
    nonfinite = _nonfinite(target, rules).reshape(-1)
    beyond = target.beyond(np.nan_to_num(d, nan=0.0)).reshape(-1) & ~nonfinite
    at = np.flatnonzero(beyond)
    ill = v.shadow_ill.reshape(-1)[at] | cache.band(scene, rules, at)
    failing = np.union1d(at[~ill], np.flatnonzero(nonfinite))
    kind = np.full(failing.size, KINDS.index("other"))
    if failing.size:
        tol = dg.FLOAT_TOL if target.is_float else dg.LEVEL_TOL
        diff = _signed(target, v.color, rules).reshape(-1, 3)[failing]
        darker = (diff <= tol).all(-1) & (diff < -tol).any(-1)
        brighter = (diff >= -tol).all(-1) & (diff > tol).any(-1)
        facts = primary(scene, rules.traced(), failing)
        kind = np.where(facts["hit"] & facts["lit"] & darker, KINDS.index("acne"), kind)
        kind = np.where(facts["hit"] & ~facts["lit"] & brighter, KINDS.index("lost_shadow"), kind)
        kind = np.where(nonfinite[failing], KINDS.index("nan"), kind)
    counts = {k: int((kind == i).sum()) for i, k in enumerate(KINDS)}
    example = None
    if failing.size:
        top = max(range(len(KINDS)), key=lambda i: (counts[KINDS[i]], -i))
        first = int(failing[kind == top][0])
        example = (first % w, first // w)
    flips = v.f32_flips.reshape(-1)[failing] if v.f32_flips is not None else np.zeros(failing.size, dtype=bool)
    return {"pixels": counts, "ill": int(ill.sum()), "f32": int(flips.sum()), "example": example}


def grade_hard_case(
    oracle, name: str, family: str, scene: Scene, rules: Rules, cache: dg.VariantCache, timeout: float | None
) -> HardCase:
    """One hard scene through the program (``oracle``: minirt.oracles.program.ProgramOracle), classified."""
    from minirt.grading.program import run_program

    scene, run, _ = run_program(oracle, scene, rules, timeout, nonfinite=True)
    if run.error:
        return HardCase(name, family, ERROR, error=run.error)
    c = classify(scene, rules, dg.Target(run.pixels, run.is_float, run.image_name), cache)
    if c is None:
        return HardCase(name, family, ERROR, error="the image does not fit the layout the suite found (transposed)")
    verdict = FAILS if sum(c["pixels"].values()) else OK
    return HardCase(name, family, verdict, c["pixels"], c["ill"], c["f32"], c["example"])


def grade_hard_cases(
    spec,
    cases: list[tuple[str, str, str, Scene, Rules]],
    out_dir: Path,
    timeout: float | None = None,
    on_case=None,
) -> list[HardCase]:
    """Every (name, family, text, scene, rules) of ``cases`` through the program ``spec``, compared under
    ``rules`` (the suite's, with its diagnosis: ``hard_rules``); the text of each scene that fails or
    errs is written to ``out_dir/<name>.toml`` (atomically) and named in its entry. ``on_case(HardCase)``
    as each is done."""
    from minirt.io.atomic import write_text
    from minirt.oracles.program import ProgramOracle

    oracle = ProgramOracle(spec)
    oracle.require_sandbox()
    oracle.build()
    out = []
    for name, family, text, scene, rules in cases:
        cache = dg.VariantCache(share=False)  # one scene each: nothing to share
        case = grade_hard_case(oracle, name, family, scene, rules, cache, timeout)
        if case.verdict != OK:
            path = Path(out_dir) / f"{name}.toml"
            write_text(path, text)
            case.scene_file = str(path)
        out.append(case)
        if on_case is not None:
            on_case(case)
    return out


def hard_rules(given: Rules, changes: dict[str, Any]) -> Rules:
    """The rules a program is compared under on a hard scene: those of its suite (``given``), with the
    suite's diagnosis (``changes``) -- what the program was found to follow everywhere -- except an offset
    of 0, which is compared under "error-bound" (see the module's docstring)."""
    from dataclasses import replace

    rules = replace(given, **changes)
    if rules.offset == 0.0:
        rules = replace(rules, offset="error-bound", offset_along="normal")
    return rules


def scene_with_rules(doc: dict[str, Any], rules: Rules) -> str:
    """A campaign scene's document as TOML text whose own rules are ``rules``: profile "exercise" and a
    [model] table of every rule that differs from it -- so the written file, rendered by minirt or graded
    again, is compared under exactly the rules the program was (the campaign draws a profile per scene)."""
    from minirt.model.rules import PROFILES
    from minirt.model.toml_out import dump_toml

    base = PROFILES["exercise"]
    doc = dict(doc)
    doc["render"] = {**doc.get("render", {}), "profile": "exercise", "samples": 1}  # one ray a pixel, as graded
    doc["model"] = {n: list(v) if isinstance(v, tuple) else v for n in base.differs(rules) if (v := getattr(rules, n))
                    is not None}  # fmt: skip
    return dump_toml(doc)
