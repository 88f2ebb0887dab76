"""One diagnosis for several images of one tracer: a program graded over a suite of scenes.

Each image alone is searched first (minirt.diagnose.search); the rule changes their answers propose are
then weighed on *every* image at once, so a setting that fits one scene by accident and breaks another is
never chosen:

- a greedy descent from the scenes' own rules takes, one at a time, the proposed change (a coupled pair
  together) that leaves the fewest pixels beyond tolerance summed over the images (then the fewest a
  level off, then the fewest rules), while it removes some;
- every rule of that answer is put back in turn and weighed by its evidence summed over the images
  (minirt.diagnose.evidence: pixels for, against, matching neither); the weakest that fails is put back
  and the rest weighed again;
- a named rule whose other values fit every image exactly as well is undecided ("one of");
- a single change of the answer that draws every image the same (on every pixel not ill-conditioned) is
  what no scene of the suite tells apart: ``indistinguishable``, with the reason where it is known;
- each image's pixels still beyond tolerance are grouped and fitted as one image's are
  (minirt.diagnose.rest, minirt.diagnose.fit), each group naming its scene.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

from minirt.diagnose import evidence, fit, rest
from minirt.diagnose.explain import indistinguishable
from minirt.diagnose.search import Search, valid_rules
from minirt.diagnose.target import Target
from minirt.diagnose.variants import VariantCache
from minirt.model import rules as rules_mod
from minirt.model.rules import Rules
from minirt.model.scene import Ball, Scene


@dataclass
class Image:
    """One image of the suite: its scene, the rules it is graded against, the image, and its search."""

    scene: Scene
    given: Rules
    target: Target
    search: Search = field(init=False, repr=False)
    weigher: evidence.Weigher = field(init=False, repr=False)  # its classes, kept while rules are weighed


@dataclass
class JointDiagnosis:
    rules: dict[str, str]  # named: decided by the images together
    undetermined: dict[str, list[str]]  # rule -> the values that fit every image equally
    explained: list[dict[str, Any]]  # per rule: value, pixels, against, neither (summed), and per scene
    rejected: list[evidence.Rejected]
    unexplained: list[dict[str, Any]]  # groups of what is left, each with its scene
    indistinguishable: list[dict[str, Any]]
    mismatch_pixels: int
    broken_pixels: int
    changes: dict[str, Any]  # the answer as overrides of every image's rules (undecided ones included)

    @property
    def undetermined_sentence(self) -> str | None:
        if not self.undetermined:
            return None
        parts = [f"{k}: {' or '.join(v)}" for k, v in sorted(self.undetermined.items())]
        return "the suite's images cannot decide " + "; ".join(parts) + ": each fits every image equally well"


def _apply(given: Rules, changes: dict[str, Any]) -> Rules | None:
    r = replace(given, **changes)
    return r if valid_rules(r) else None


def _score(images: list[Image], changes: dict[str, Any]) -> tuple[int, int] | None:
    """(pixels beyond tolerance, pixels a level off) summed over the images, ill-conditioned ones left out."""
    beyond = off = 0
    for im in images:
        r = _apply(im.given, changes)
        if r is None:
            return None
        mb, offm, _ = im.search.final_mask(r, [])
        beyond += int(mb.sum())
        off += int(offm.sum())
    return beyond, off


def _render_together(images: list[Image], candidates: list[dict[str, Any]]) -> None:
    """The renders ``_score`` of these candidates asks of each image (float64 and float32, whole), traced in
    batches before it asks for them one by one (``VariantCache.prefetch_whole``): the same bits."""
    for im in images:
        rules = [r for c in candidates if (r := _apply(im.given, c)) is not None]
        im.search.cache.prefetch_whole(im.scene, rules, f32=True)


def _proposals(images: list[Image], answers: list[Rules]) -> list[dict[str, Any]]:
    """The changes the images' own answers propose: each changed rule alone, the coupled offset pair
    together."""
    out: list[dict[str, Any]] = []
    for im, best in zip(images, answers, strict=True):
        names = im.given.differs(best)
        for name in names:
            unit = next((c for c in evidence.COUPLED if name in c), (name,))
            change = {n: getattr(best, n) for n in unit if n in names} if len(unit) > 1 else {}
            for c in ({name: getattr(best, name)}, change):
                if c and c not in out:
                    out.append(c)
    return out


def _descend(images: list[Image], proposals: list[dict[str, Any]]) -> dict[str, Any]:
    current: dict[str, Any] = {}
    score = _score(images, current)
    while True:
        found = None
        moves = [p for p in proposals if not all(current.get(k) == v for k, v in p.items())]
        _render_together(images, [{**current, **p} for p in moves])
        for p in moves:
            cand = {**current, **p}
            s = _score(images, cand)
            if s is None:
                continue
            key = (s, len(cand))
            if s < score and (found is None or key < found[0]):
                found = (key, cand)
        if found is None:
            return current
        score, current = found[0][0], found[1]


def _weigh(images: list[Image], changes: dict[str, Any]) -> list[tuple[evidence.Evidence, dict[str, int]]]:
    """Each changed rule (unit) of ``changes`` put back on every image: its evidence summed over them, and the
    pixels for it per scene."""
    out = []
    units: list[tuple[str, ...]] = []
    for name in changes:
        unit = next((c for c in evidence.COUPLED if name in c and set(c) <= set(changes)), (name,))
        if unit not in units:
            units.append(unit)
    for unit in units:
        total = evidence.Evidence(unit, 0, 0, 0, None)
        per: dict[str, int] = {}
        for im in images:
            best = _apply(im.given, changes)
            e = im.weigher.evidence(best, evidence.put_back(im.given, best, unit), unit)
            total.pixels, total.against, total.neither = (
                total.pixels + e.pixels, total.against + e.against, total.neither + e.neither
            )  # fmt: skip
            per[im.scene.name] = e.pixels
        out.append((total, per))
    return out


def _confirm(images: list[Image], changes: dict[str, Any]):
    rejected: list[evidence.Rejected] = []
    while True:
        weighed = _weigh(images, changes)
        worst = evidence.weakest([e for e, _ in weighed])
        if worst is None:
            return changes, weighed, rejected
        for n in worst.rules:
            value = rules_mod.format_rule_value(n, changes[n])
            rejected.append(evidence.Rejected(n, value, worst.pixels, worst.against, worst.neither))
        changes = {k: v for k, v in changes.items() if k not in worst.rules}


def _undecided(images: list[Image], changes: dict[str, Any]) -> dict[str, list[str]]:
    base = _score(images, changes)
    n = sum(im.target.model_shape[0] * im.target.model_shape[1] for im in images)
    out: dict[str, list[str]] = {}
    others = [{**changes, name: v} for name, value in changes.items() for v in rules_mod.values(name) if v != value]
    _render_together(images, others)
    for name, value in changes.items():
        for v in rules_mod.values(name):
            if v == value:
                continue
            s = _score(images, {**changes, name: v})
            if s is not None and evidence.fits_equally((base[0] - s[0], base[1] - s[1]), n):
                vals = out.setdefault(name, [rules_mod.format_rule_value(name, value)])
                vals.append(rules_mod.format_rule_value(name, v))
    return out


def diagnose_joint(
    items: list[tuple[Scene, Rules, Target]], cache: VariantCache | None = None, answers: list[Rules] | None = None
) -> JointDiagnosis:
    """The diagnosis of several images of one tracer, weighed on all of them at once (see the module's
    docstring). ``items``: (scene, the rules it is graded against, its image); ``answers``: each image's own
    diagnosis's rules where it was diagnosed already (a program's scenes are, one by one), else each image
    is searched here."""
    cache = cache or VariantCache(share=False)
    images = []
    for scene, given, target in items:
        im = Image(scene, given, target)
        im.search = Search(scene, target, cache, True)
        im.weigher = evidence.Weigher(im.search)
        images.append(im)
    if answers is None:
        answers = [im.search.run(im.given) for im in images]
    changes = _descend(images, _proposals(images, answers))
    changes, weighed, rejected = _confirm(images, changes)
    undecided = _undecided(images, changes)
    explained = [
        {
            "rule": n,
            "value": rules_mod.format_rule_value(n, changes[n]),
            "pixels": e.pixels,
            "against": e.against,
            "neither": e.neither,
            "per_scene": per,
            "decided": n not in undecided,
        }
        for e, per in weighed
        for n in e.rules
    ]
    explained.sort(key=lambda e: (-e["pixels"], e["rule"]))
    unexplained, mismatch, broken = [], 0, 0
    for im in images:
        best = _apply(im.given, changes)
        mb, _, _ = im.search.final_mask(best, [im.given, best])
        mg, _, _ = im.search.final_mask(im.given, [im.given, best])
        mismatch += int(mb.sum())
        broken += int((mb & ~mg).sum())
        if mb.any():
            groups = rest.groups(im.scene, best, mb, cache.first_hits(im.scene, best))
            fit.fit_groups(im.scene, best, im.target, groups)
            unexplained += [{"scene": im.scene.name, **g.as_dict()} for g in groups]
    return JointDiagnosis(
        rules={n: rules_mod.format_rule_value(n, v) for n, v in changes.items() if n not in undecided},
        undetermined=undecided,
        explained=explained,
        rejected=rejected,
        unexplained=unexplained,
        indistinguishable=_same_everywhere(images, changes, cache),
        mismatch_pixels=mismatch,
        broken_pixels=broken,
        changes=changes,
    )


def _same_everywhere(images: list[Image], changes: dict[str, Any], cache: VariantCache) -> list[dict[str, Any]]:
    """Single changes of the answer that draw every image of the suite the same: no scene tells them apart."""
    common: dict[tuple[str, str], dict[str, Any]] | None = None
    for im in images:
        best = _apply(im.given, changes)
        found = {(e["rule"], e["value"]): e for e in indistinguishable(im.scene, best, cache, im.target)}
        common = found if common is None else {k: v for k, v in common.items() if k in found}
        if not common:  # a scene told every change apart: the rest cannot bring one back
            break
    out = []
    for _key, e in sorted((common or {}).items()):
        item = dict(e, scene_that_tells=None)
        item["why"] = e.get("why") or _why_suite(e["rule"], changes, images)
        out.append(item)
    return out


# Why a single change draws every image of a suite the same, where the rules make it so for any scene
# (a rule moot under the answer: minirt.diagnose.search.moot_rules); else no scene of the suite shows it.
MOOT_UNDER = {
    ("shadow_range", "shadow_rays", False): "no shadow ray is traced (shadow_rays = false): where one would end "
    "changes nothing",
    ("ball_normal", "two_sided", True): "every normal is turned to face the ray (two_sided = true), whichever way "
    "it pointed",
    # the offset scenes (minirt.grading.suite) read an offset that carries a start past a wall the ray came
    # through from behind; facing the ray, the start moves back towards where the ray came from, and a surface
    # within the offset on that side, off the ray's path, is a contact -- a ball resting on a floor
    ("offset", "two_sided", True): "with every normal turned to face the ray (two_sided = true), an offset along "
    "the normal moves a secondary ray's start back towards where the ray came from: only a surface nearer than "
    "the offset on that side (a contact) shows it, and no scene of the suite has one",
}


def _why_suite(rule: str, changes: dict[str, Any], images: list[Image]) -> str:
    for (name, other, value), why in MOOT_UNDER.items():
        if name == rule and changes.get(other) is value:
            return why
    planes = [s for im in images for s in im.scene.shapes if not isinstance(s, Ball)]
    if rule == "raw_normals_plane" and all(p.written == 1 for p in planes):
        # a 2014 program receives every plane so (minirt.oracles.program.edition_scene)
        return "every plane of the suite comes with a normal of unit length: normalised or not, it is the same"
    return "no scene of the suite tells them apart"
