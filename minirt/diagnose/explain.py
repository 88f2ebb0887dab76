"""What explains what: the diagnosis of an image, and the settings a scene cannot tell apart.

``diagnose`` runs the search (minirt.diagnose.search) from the scene's own rules and reports, for each
rule the answer changed, the pixels that change explains (``Explained``, ``Diagnosis``: counts leave
ill-conditioned pixels out). ``indistinguishable`` lists the single-rule changes of the answer that the
scene cannot tell apart from it, each with a bundled grading scene that does (``tells_apart``,
``GRADING_SET``) or why none does (``why_same``).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from minirt.diagnose import evidence, fit, rest
from minirt.diagnose.search import SAMPLE, Search, moot_rules, single_moves, valid_rules
from minirt.diagnose.target import FLOAT_TOL, Target, coded_levels
from minirt.diagnose.variants import VariantCache
from minirt.model import bitmap
from minirt.model import rules as rules_mod
from minirt.model.rules import Rules
from minirt.model.scene import Scene


@dataclass
class Explained:
    """A rule of the answer and its evidence (minirt.diagnose.evidence): the pixels that putting it back to
    the scene's value makes wrong, those it makes right (``against``), and those the rule changes that match
    neither value (``neither``)."""

    rule: str
    value: str
    pixels: int
    mask: np.ndarray = field(repr=False)
    against: int = 0
    neither: int = 0
    interval: tuple[float, float] | None = None  # a number's: the values that fit as well (offset, t_max)


@dataclass
class Diagnosis:
    """What the search found. Counts leave ill-conditioned pixels out."""

    given: Rules
    best: Rules
    pixels: int
    as_given_mask: np.ndarray  # pixels beyond tolerance under the scene's own rules
    best_mask: np.ndarray  # those still beyond tolerance under the best rules
    ill: np.ndarray  # ill-conditioned pixels among those that differ (left out)
    explained: list[Explained]
    indistinguishable: list[dict[str, Any]]
    given_color: np.ndarray
    best_color: np.ndarray
    steps: list[dict[str, Any]]
    renders: int  # candidate renders looked at (VariantCache.requested): traced now or taken from the cache
    # the pixels still beyond tolerance under ``best``, grouped by what the reference knows of them
    unexplained: list[rest.Group] = field(default_factory=list)
    # what the image does not bear out (minirt.diagnose.evidence): rules the search took and put back, the
    # rules it cannot decide, and the pixels the answer makes wrong that the scene's own rules drew right
    rejected: list[evidence.Rejected] = field(default_factory=list)
    one_of: evidence.OneOf | None = None
    broken_pixels: int = 0
    searched: Rules | None = None  # the search's own answer, before what the image does not bear out is put back

    @property
    def undetermined(self) -> dict[str, list[Any]]:
        """Rules the image cannot decide, each with the values that fit it equally."""
        return self.one_of.values if self.one_of else {}

    @property
    def changed(self) -> dict[str, str]:
        """The rules the diagnosis names: those the answer changes that the image decides."""
        return {n: v for n, v in self.reproducing.items() if n not in self.undetermined}

    @property
    def reproducing(self) -> dict[str, str]:
        """Every rule the answer changes, undecided ones at the value it took: the rules under which the
        reference draws the image as the diagnosis explains it."""
        return {n: rules_mod.format_rule_value(n, getattr(self.best, n)) for n in self.given.differs(self.best)}

    @property
    def as_given_pixels(self) -> int:
        return int(self.as_given_mask.sum())

    @property
    def mismatch_pixels(self) -> int:
        return int(self.best_mask.sum())


def diagnose(
    scene: Scene,
    given: Rules,
    target: Target,
    cache: VariantCache | None = None,
    alternatives: bool = True,
    outputs: bool = True,
    swaps: bool = True,
) -> Diagnosis:
    """Search rule space for the setting that best reproduces ``target`` (see the module's docstring).
    ``alternatives=False`` skips the list of settings the scene cannot tell apart from the answer
    (about half the time of a diagnosis; ``check`` does not show it). ``outputs=False`` keeps ``given``'s
    output rules: for an image whose encoding and layout are known (an oracle's ``color8()``).
    ``swaps=False`` skips only ``indistinguishable`` (the single changes this scene cannot tell apart): a
    program's images ask it of the suite's answer, not of each scene's own (minirt.diagnose.joint)."""
    cache = cache or VariantCache()
    cache.requested = set()
    search = Search(scene, target, cache, outputs)
    best = searched = search.run(given)
    rejected: list[evidence.Rejected] = []
    one_of = None
    broken_pixels = 0
    if alternatives:  # a grade: name only what the image bears out (minirt.diagnose.evidence)
        best, found, rejected = evidence.confirm(search, given, best)
    pair = [given, best]
    mg, _, ill_g = search.final_mask(given, pair)
    mb, off_b, ill_b = search.final_mask(best, pair)
    if alternatives:
        # the pixels the answer draws wrong that the scene's own rules drew right: counted, never the student's
        fixed, broken_pixels = int((mg & ~mb).sum()), int((mb & ~mg).sum())
        if best != given and broken_pixels > fixed:  # breaks more than it explains: no answer
            rejected += [
                evidence.Rejected(n, rules_mod.format_rule_value(n, getattr(best, n)), fixed, broken_pixels, 0)
                for n in given.differs(best)
            ]
            best, found, broken_pixels = given, [], 0
            pair = [given, best]
            mg, _, ill_g = search.final_mask(given, pair)
            mb, off_b, ill_b = search.final_mask(best, pair)
        one_of = evidence.one_of(search, given, best, [e.rules for e in found if e.undecided])
    shape = search.target.model_shape
    explained = []
    if alternatives:
        for e in found:
            for name in e.rules:
                value = rules_mod.format_rule_value(name, getattr(best, name))
                iv = search.interval(name, best) if name in ("offset", "t_max") else None
                explained.append(Explained(name, value, e.pixels, e.mask, e.against, e.neither, iv))
    else:
        for name in given.differs(best):
            _, off_back, _ = search.final_mask(evidence.put_back(given, best, (name,)), [])
            gained = off_back & ~off_b & ~ill_b
            explained.append(
                Explained(name, rules_mod.format_rule_value(name, getattr(best, name)), int(gained.sum()), gained)
            )
    explained.sort(key=lambda e: (-e.pixels, e.rule))
    groups = rest.groups(scene, best, mb, cache.first_hits(scene, best)) if mb.any() else []
    if alternatives and groups:
        fit.fit_groups(scene, best, target, groups)
    return Diagnosis(
        given=given,
        best=best,
        pixels=shape[0] * shape[1],
        as_given_mask=mg,
        best_mask=mb,
        ill=ill_g | ill_b,
        explained=explained,
        indistinguishable=indistinguishable(scene, best, cache, target) if alternatives and swaps else [],
        given_color=cache.get(scene, given).color,
        best_color=cache.get(scene, best).color,
        steps=search.steps,
        renders=len(cache.requested),
        unexplained=groups,
        rejected=rejected,
        one_of=one_of,
        broken_pixels=broken_pixels,
        searched=searched,
    )


def indistinguishable(scene: Scene, best: Rules, cache: VariantCache, target: Target) -> list[dict[str, Any]]:
    """Single-rule changes of ``best`` that this scene cannot tell apart from it: written the same way,
    their image equals best's on every pixel that is not ill-conditioned. Each with a bundled grading
    scene that does tell them apart (None when none does). A change that differs on a stride of pixels
    is told apart without a full render. It depends on the scene and the answer only, not on the image:
    a class's images with the same answer share one list (kept in the cache)."""
    key = (*VariantCache.key(scene, best), best, target.is_float)
    if key not in cache.alternatives:
        asked, cache.requested = cache.requested, set()
        found = _indistinguishable(scene, best, cache, target)
        cache.alternatives[key] = (found, cache.requested)
        cache.requested = asked
    found, renders = cache.alternatives[key]
    cache.requested |= renders  # what the list looked at counts whether it was made now or before
    return [dict(e) for e in found]


def _indistinguishable(scene: Scene, best: Rules, cache: VariantCache, target: Target) -> list[dict[str, Any]]:
    vb = cache.get(scene, best)
    h, w = vb.color.shape[:2]
    stride = np.arange(0, h * w, max(1, (h * w) // (4 * SAMPLE)))
    coded = coded_levels(vb.color.reshape(-1, 3), best, target.is_float)
    out = []
    moot = moot_rules(scene, best)
    moves = single_moves(best, rules_mod.TRACE_RULES)
    cache.prefetch(scene, [c for c in moves if best.differs(c)[0] not in moot], stride)  # one trace for all
    same = [
        c for c in moves
        if best.differs(c)[0] in moot or _distinct(scene, best, c, coded, stride, cache, target.is_float) == 0
    ]  # fmt: skip
    told = [c for c in same if not (best.differs(c)[0] in moot and best.differs(c)[0] in rules_mod.BUG_RULES)]
    _render_first_grading_pairs(best, told, cache)  # what tells_apart asks first, traced together
    for cand in same:
        (name,) = best.differs(cand)
        value = getattr(cand, name)
        out.append(
            {
                "rule": name,
                "value": rules_mod.format_rule_value(name, value),
                "as": rules_mod.format_rule_value(name, getattr(best, name)),
                "scene_that_tells": (
                    shows(name, getattr(best, name), value)
                    if name in moot and name in rules_mod.BUG_RULES
                    else tells_apart(name, getattr(best, name), value, cache)
                ),
            }
        )
        if out[-1]["scene_that_tells"] is None:
            out[-1]["why"] = why_same(name, getattr(best, name), value)
    return out


def _render_first_grading_pairs(best: Rules, cands: list[Rules], cache: VariantCache) -> None:
    """The renders ``tells_apart`` asks of the first grading scene for these pairs (best's value, the
    candidate's), traced together (``VariantCache.prefetch_whole``): the first scene tells most pairs apart."""
    rules: list[Rules] = []
    sc = None
    for c in cands:
        (name,) = best.differs(c)
        a, b = getattr(best, name), getattr(c, name)
        pair = None if _same_under_exercise(name, a, b) else _renders_could_tell(GRADING_SET[0], name, a, b)
        if pair is not None:
            sc = pair[0]
            rules += pair[1:]
    if sc is not None:
        cache.prefetch_whole(sc, rules)


def _distinct(
    scene: Scene, a: Rules, b: Rules, coded_a: np.ndarray, stride: np.ndarray, cache: VariantCache, is_float: bool
) -> int:
    """Pixels (not ill-conditioned in either) where b's image, written as a's output rules say, differs
    from a's (``coded_a``, flat): 0 means the two cannot be told apart. Only a count below the stride's
    says 0 is rendered in full."""
    tol = FLOAT_TOL if is_float else 0
    vs = cache.subset(scene, b, stride)
    d = bitmap.channel_max(np.abs(coded_levels(vs.color, a, is_float) - coded_a[stride])) > tol
    if d.any():
        where = stride[d]
        va = cache.get(scene, a)
        ill = (
            va.shadow_ill.reshape(-1)[where]
            | vs.shadow_ill[d]
            | cache.band(scene, a, where)
            | cache.band(scene, b, where)
        )
        if (~ill).any():
            return int((~ill).sum())
    vb = cache.get(scene, b)
    d = bitmap.channel_max(np.abs(coded_levels(vb.color.reshape(-1, 3), a, is_float) - coded_a)) > tol
    where = np.flatnonzero(d)
    va = cache.get(scene, a)
    ill = va.shadow_ill.reshape(-1)[where] | vb.shadow_ill.reshape(-1)[where]
    ill |= cache.band(scene, a, where) | cache.band(scene, b, where)
    return int((~ill).sum())


# The bundled scenes that tell every pair of rule values apart (tests/diagnose/test_diagnose.py proves it):
# rules.toml alone separates all but one pair; the others add margin.
GRADING_SET = ("rules", "three_balls", "exercise")


# Pairs of values that give the same image, beyond a handful of pixels one level apart, whenever the other
# rules are the exercise's: with the offset along the normal and "anything on the shadow ray blocks", a
# point facing away from the light shadows itself (its shadow ray re-enters its own surface), so clamping
# the diffuse term, or cutting the highlight at s·n <= 0, barely shows -- only just past a ball's lit edge,
# where a shadow ray can slip past its own ball (5 pixels, each one level, in three_balls at 256²). Under
# the 2014 edition's rules (offset along the ray) they differ widely.
SAME_UNDER_EXERCISE = {
    ("clamp", frozenset({True, "specular"})): "eth2014",
    # (r·(-s))^8 = (r·s)^8: an even power, unclamped, cannot show the sign of s; the 2014 edition cuts the
    # highlight at r·s > 0, where it shows
    ("specular_s", frozenset({"s", "-s"})): "eth2014",
}


def _same_under_exercise(name: str, a: Any, b: Any) -> bool:
    return (name, frozenset({a, b})) in SAME_UNDER_EXERCISE


def tells_apart(name: str, a: Any, b: Any, cache: VariantCache | None = None, min_pixels: int = 50) -> str | None:
    """The first bundled grading scene in which rule ``name`` = a and = b differ on >= min_pixels pixels
    (8-bit, as stored, ill-conditioned pixels left out), under the scene's own rules. A pair the exercise's
    rules make the same (``SAME_UNDER_EXERCISE``: every grading scene is under them) is told by none,
    without a render."""
    if _same_under_exercise(name, a, b):
        return None
    for stem in GRADING_SET:
        if distinct_pixels(stem, name, a, b, cache) >= min_pixels:
            return stem
    return None


def shows(name: str, a: Any, b: Any) -> str | None:
    """For a rule from real solutions' bugs that the graded scene provably cannot show (it has no ball, or
    its planes are written of unit length, ...): the first bundled grading scene where it is not so, found
    without a render. The answer is the rendered one (``tells_apart``) for every pair of every such rule:
    tests/diagnose/test_diagnose.py checks it."""
    if _same_under_exercise(name, a, b):
        return None
    for stem in GRADING_SET:
        if _renders_could_tell(stem, name, a, b) is not None:
            return stem
    return None


def _grading_pair(stem: str, name: str, a: Any, b: Any, profile: str | None = None):
    """(bundled scene ``stem`` at one ray a pixel, its rules -- or ``profile``'s -- with ``name`` = a, and
    with ``name`` = b), each a valid rule set; None when the scene is not installed."""
    from minirt.errors import SceneError
    from minirt.model.bundled import find_scene

    try:
        path = find_scene(stem)
        stat = path.stat()
    except (SceneError, OSError):  # a bundled scene missing from this install: ask the others
        return None
    read = _grading_scene(str(path), stat.st_mtime_ns, stat.st_size, profile)
    if read is None:
        return None
    sc, base = read
    return sc, _make_valid(replace(base, **{name: a})), _make_valid(replace(base, **{name: b}))


@functools.lru_cache(maxsize=32)
def _grading_scene(path: str, mtime_ns: int, size: int, profile: str | None) -> tuple[Scene, Rules] | None:
    """A grading scene read once (at one ray a pixel) with its rules, while its file stays as it was: a program's
    grade asks ``_grading_pair`` ~300 times, and each read parsed the TOML again (~3 ms)."""
    from minirt.errors import SceneError
    from minirt.model.scene import load_scene

    try:
        sc = load_scene(path).with_overrides(samples=1)
    except SceneError:
        return None
    return sc, rules_mod.resolve(sc, profile)


def _renders_could_tell(stem: str, name: str, a: Any, b: Any, profile: str | None = None):
    """``_grading_pair``'s (scene, rules with a, rules with b) where their renders could differ; None when the
    scene is not installed or rule ``name`` provably cannot change it under either (``moot_rules``: no ball,
    every normal of unit length ...)."""
    pair = _grading_pair(stem, name, a, b, profile)
    if pair is None or (name in moot_rules(pair[0], pair[1]) and name in moot_rules(pair[0], pair[2])):
        return None
    return pair


def why_same(name: str, a: Any, b: Any) -> str:
    """Why no bundled scene tells two values apart (for the indistinguishable list)."""
    if name == "specular_s":
        return "the same image under an even exponent, unclamped: (r·(-s))^e = (r·s)^e"
    if _same_under_exercise(name, a, b):
        return (
            "the same image whenever secondary rays are offset along the normal and anything on the shadow ray "
            "blocks: a point facing away from the light always shadows itself"
        )
    return "no bundled grading scene tells them apart"


def distinct_pixels(
    stem: str, name: str, a: Any, b: Any, cache: VariantCache | None = None, profile: str | None = None
) -> int:
    """Pixels of bundled scene ``stem`` (its own rules, or ``profile``'s; one ray per pixel) whose 8-bit
    image differs between rule ``name`` = a and = b (0 when the scene is not installed)."""
    cache = cache or VariantCache()
    pair = _renders_could_tell(stem, name, a, b, profile)
    if pair is None:
        return 0  # not installed, or provably the same picture
    sc, ra, rb = pair
    va, vb = cache.get(sc, ra), cache.get(sc, rb)
    ia, ib = bitmap.bitmap(va.color, ra), bitmap.bitmap(vb.color, rb)
    if ia.shape != ib.shape:
        return ia.shape[0] * ia.shape[1]
    differ = bitmap.channel_any(ia != ib)
    if ra.transpose != rb.transpose or ra.rows != rb.rows or ra.channels != rb.channels:
        return int(differ.sum())  # the layouts differ: compared as stored, nothing to leave out
    where = np.flatnonzero(bitmap.undo_layout(differ[..., None], **bitmap.layout_of(ra))[..., 0].reshape(-1))
    ill = va.shadow_ill.reshape(-1)[where] | vb.shadow_ill.reshape(-1)[where]
    ill |= cache.band(sc, ra, where) | cache.band(sc, rb, where)
    return int((~ill).sum())


def _make_valid(r: Rules) -> Rules:
    """offset_along = "ray" with the error-bound offset is no rule set: use the 2014 edition's 1e-3."""
    if not valid_rules(r) and r.offset == "error-bound":
        return replace(r, offset=1e-3)
    return r
