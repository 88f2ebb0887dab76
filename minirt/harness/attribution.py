"""Rules, two ways.

Rule effects (``attribute_rules``): per rule the oracle cannot follow, the pixels of the scene-rules
reference image that flipping that rule alone changes (a mask per rule) -- what the rule does in the
reference, not what the oracle did.

Rule diagnosis (``diagnose_oracle``; oracles that shade the exercise's model, shading_model "exercise"):
minirt.diagnose searches rule space from the scene's rules for the settings whose reference render
reproduces the oracle's 8-bit image, and reports them, the pixels each explains and the pixels (beyond one
8-bit level) that nothing explains.
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Any

import numpy as np

from minirt.harness.references import ReferenceCache
from minirt.harness.results import RuleDiagnosis
from minirt.model.result import RenderResult
from minirt.model.rules import Rules
from minirt.model.scene import Scene


def attribute_rules(
    refs: ReferenceCache, rules: Rules, followed: Rules
) -> tuple[dict[str, int], dict[str, np.ndarray]]:
    """Rule effects: pixels of the scene-rules image that each rule the oracle cannot follow changes,
    singly (what the rule does in the reference; ``diagnose_oracle`` says what explains the oracle)."""
    from minirt.model import bitmap

    base = refs.get(rules)
    counts, masks = {}, {}
    for name in rules.differs(followed):
        alt = refs.get(replace(rules, **{name: getattr(followed, name)}))
        m = bitmap.channel_any(alt.color8() != base.color8()) | (alt.hit != base.hit)
        counts[name], masks[name] = int(m.sum()), m
    return counts, masks


# One render cache for the diagnoses of a check run (a process runs one check; minirt.harness.run and the
# sample report pass their own). Bounded: the diagnosis keeps full renders, least recently used out.
VARIANT_CACHE_BYTES = 1 << 30
_variants: Any = None


def check_variants():
    """A VariantCache for a check run's diagnoses. A check searches one image a scene for each oracle of the
    exercise's model (POV-Ray's among the built-in ones), so no other image asks for the same candidates as
    a class's do: the cache is not shared (``share=False``), and the search traces a candidate on the pixels
    it asks about rather than in full and kept -- the same colours there, so the same findings, in less time
    (the bundled rules scene's diagnosis: 2.4 -> 2.0 s; its ``renders``, in whole images, 399 -> 227)."""
    from minirt.diagnose import VariantCache

    return VariantCache(VARIANT_CACHE_BYTES, share=False)


def shared_variants():
    """The process's VariantCache for check's diagnoses (``check_variants``), made on first use."""
    global _variants
    if _variants is None:
        _variants = check_variants()
    return _variants


def diagnose_oracle(scene: Scene, rules: Rules, followed: Rules, res: RenderResult, variants=None) -> RuleDiagnosis:
    """Which rule settings explain the oracle's 8-bit colour image, searched from the scene's rules.

    The search starts from the scene's traced rules with the output rules at their defaults -- the
    oracle's image is ``color8()``, written as floor(c·255 + 0.5) in the scene's layout whatever the
    scene's own output rules say -- on one ray per pixel, the rays the oracle cast. Where the oracle's
    image is the scene's rules' image within one level on every pixel, nothing needs explaining and
    no search runs (one render)."""
    from minirt import diagnose as dg
    from minirt.model import bitmap
    from minirt.model import rules as rules_mod

    h, w = scene.camera.height, scene.camera.width
    if res.traced is not None:  # a rule setting explains an image, not a sample of its pixels
        n = int(res.traced.sum())
        return RuleDiagnosis(reason=f"{res.backend} traced {n} of the {h * w} pixels: no image to search rules for")
    t0 = time.perf_counter()
    variants = variants if variants is not None else shared_variants()
    one = scene.with_overrides(samples=1)
    given = rules.traced()
    declared = {n: rules_mod.format_rule_value(n, getattr(followed, n)) for n in rules.differs(followed)}
    img = res.color8()
    out = RuleDiagnosis(ran=True, declared=declared, pixels=h * w)
    before = variants.renders
    base = variants.get(one, given)
    d8 = bitmap.channel_max(np.abs(bitmap.encode(base.color).astype(np.int16) - img.astype(np.int16)))
    if not (d8 > dg.LEVEL_TOL).any():
        out.reason = "no search needed: the image is the scene's rules' within one 8-bit level on every pixel"
        out.unexplained_mask = np.zeros((h, w), dtype=bool)
    else:
        # the oracle's image is color8(): written floor(c·255 + 0.5) in the scene's layout, output rules known
        d = dg.diagnose(
            one, given, dg.Target(img, False, name=res.backend), variants, alternatives=False, outputs=False
        )
        pixels = {e.rule: e.pixels for e in d.explained}
        out.rules_explaining = {k: v for k, v in d.changed.items() if pixels.get(k, 0) > 0}
        out.cannot_tell = {k: v for k, v in d.changed.items() if pixels.get(k, 0) == 0}
        out.explained = {k: pixels[k] for k in out.rules_explaining}
        out.explained_masks = {e.rule: e.mask for e in d.explained if e.rule in out.rules_explaining}
        out.mismatch_pixels = d.mismatch_pixels
        out.as_given_pixels = d.as_given_pixels
        out.ill_conditioned_pixels = int(d.ill.sum())
        out.unexplained_mask = d.best_mask
    out.renders = round(variants.renders - before, 2)
    out.seconds = time.perf_counter() - t0
    return out
