"""What the image shows of each rule the search changed: evidence by leave-one-out, and "one of" where
it cannot decide.

The search (minirt.diagnose.search) returns the rule set that fits best; greedy steps can take a rule that
gains a few pixels by accident, or that imitates a bug the table lacks. Before the diagnosis names a rule,
``confirm`` puts it back to the scene's value in the final rule set and counts:

- ``pixels``: made wrong by putting it back (the evidence for it) -- but for a pixel where a tracer
  following the scene's value could draw it as the image does (ill-conditioned under it: ``Search.ill_at``,
  or drawn so by its float32 render);
- ``against``: made right by putting it back (pixels the rule breaks) -- but where a tracer following the
  rule could draw it as the image does;
- ``neither``: pixels whose picture the rule changes (the two renders differ beyond tolerance) and that
  match neither: the rule acts there, but the image shows something else.

"Wrong" is beyond tolerance, except for a rule whose two values never differ by more than one level (the
encoding, a gamma that barely moves): its only evidence is which one the image matches *exactly*.

A rule is named only if pixels >= 1, pixels > against and pixels >= neither: it explains more than it breaks,
and where it changes the picture the image mostly agrees with it. The weakest rule that fails is put back
and every rule is weighed again (a rule's evidence depends on the others), until all hold. What is put
back is listed (``Rejected``), with its counts, and the pixels it had claimed stay unexplained.

``one_of`` then asks whether other rule sets fit the image exactly as well -- the same pixels beyond
tolerance and (8-bit) nearly the same exact matches: the rule sets the search compared on every pixel,
every single-rule change of the answer, one named rule put back with another changed, the other
``offset_along`` with its own best offset, and for the numbers read off the image (offset, t_max, the
exponent) the interval of values that fit equally. Rules on which such sets disagree, where one of them
changes a rule the answer names, are not named: they go to ``undetermined`` with the values that fit. So
does a rule whose every deciding pixel is ill-conditioned under one of its values while putting it back
leaves pixels beyond tolerance (``confirm``). A change of a rule the answer leaves at the scene's value is
no claim about the image: ``indistinguishable`` says which of those the scene cannot show.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np

from minirt.diagnose.search import Search, single_moves, valid_rules
from minirt.diagnose.target import coded_levels
from minirt.model import bitmap
from minirt.model import rules as rules_mod
from minirt.model.rules import Rules

# Rules only valid together: reverting one alone would leave offset_along = "ray" with "error-bound".
COUPLED = (("offset", "offset_along"),)

# Two rule sets fit "equally" when they leave the same pixels beyond tolerance and their exact 8-bit matches
# differ by no more than a float32 tracer's rounding moves: a value within ~2^-22 (relative, a few dozen
# roundings of 2^-24) of a rounding step lands on either side -- 255 · 2^-22 · 3 channels ≈ 2e-4 of the
# pixels, so 1e-3 of them (plus one) is five times what rounding alone does.
EQUAL_LEVELS = 1e-3

# How far a search for the exponents that fit as well as the answer's goes, each way.
EXPONENT_REACH = 16

# A number read off the image (offset, t_max) whose interval of equally fitting values is this narrow
# (relative) is decided: the diagnosis names the simplest number inside (search.simplest: what a student
# writes, 0.5 / 1024 or 29.3) and gives the interval beside it. Wider, the image cannot decide it. 1 %: a
# 200² image pins 0.5 / 1024 to 0.1 %, a t_max cut between two pixels' hits 29.28 and 29.31 to 0.1 %;
# between 1e-6 and 1e-4 (two decades) no one number is the answer.
NARROW = 0.01


@dataclass
class Evidence:
    """One rule (or coupled pair) of the answer weighed by putting it back to the scene's value."""

    rules: tuple[str, ...]
    pixels: int  # made wrong by putting it back
    against: int  # made right by putting it back: pixels the rule breaks
    neither: int  # changed by the rule, matching neither value
    mask: np.ndarray | None = field(repr=False)  # (H, W): the ``pixels`` (None: summed over several images)
    undecided: bool = False  # nil evidence both ways, on ill-conditioned pixels only (``confirm``)

    @property
    def holds(self) -> bool:
        return self.pixels >= 1 and self.pixels > self.against and self.pixels >= self.neither

    @property
    def weight(self) -> int:
        return self.pixels - self.against - self.neither


@dataclass
class Rejected:
    """A rule the search took that the image does not bear out, with its counts (``Evidence``)."""

    rule: str
    value: str
    pixels: int
    against: int
    neither: int

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def groups_of(given: Rules, best: Rules) -> list[tuple[str, ...]]:
    """The changed rules, as the units leave-one-out puts back: a coupled pair together when putting one back
    alone would be no valid rule set."""
    names = given.differs(best)
    out: list[tuple[str, ...]] = []
    for name in names:
        back = replace(best, **{name: getattr(given, name)})
        if valid_rules(back):
            out.append((name,))
            continue
        pair = next(c for c in COUPLED if name in c)
        unit = tuple(n for n in pair if n in names) or (name,)
        if unit not in out:
            out.append(unit)
    return out


def put_back(given: Rules, best: Rules, unit: tuple[str, ...]) -> Rules:
    """``best`` with the rules of ``unit`` at the scene's values (the coupled rule too, where needed)."""
    back = replace(best, **{n: getattr(given, n) for n in unit})
    if not valid_rules(back):
        pair = next(c for c in COUPLED if set(unit) & set(c))
        back = replace(best, **{n: getattr(given, n) for n in pair})
    return back


def _worse_without(search: Search, given: Rules, best: Rules, unit: tuple[str, ...]) -> bool:
    """Does putting ``unit`` back leave more pixels beyond tolerance, counted as the diagnosis reports them
    (``Search.final_mask``)?"""
    back = put_back(given, best, unit)
    pair = [given, best, back]
    return int(search.final_mask(back, pair)[0].sum()) > int(search.final_mask(best, pair)[0].sum())


class Weigher:
    """Per-pixel classes (0 exact, 1 a level off, 2 beyond tolerance) of rule sets on one image, kept."""

    def __init__(self, search: Search):
        self.search = search
        self._cls: dict[Rules, np.ndarray | None] = {}

    def cls(self, rules: Rules) -> np.ndarray | None:
        if rules not in self._cls:
            d, _ = self.search.either(rules)
            self._cls[rules] = None if d is None else self.search.classes(d).reshape(-1)
        return self._cls[rules]

    def ill(self, a: Rules, b: Rules, at: np.ndarray) -> np.ndarray:
        """Ill-conditioned in either rule set, or drawn otherwise by a float32 render of either, at ``at``."""
        return self.ill_one(a, at) | self.ill_one(b, at)

    def ill_one(self, r: Rules, at: np.ndarray) -> np.ndarray:
        """Where a tracer following ``r`` could draw a pixel otherwise than its renders do: ill-conditioned
        under ``r`` (band, shadow), or drawn otherwise by its float32 render, at ``at``."""
        s = self.search
        return s.ill_at(r, s.either(r)[1], at) | s.flips(r)[at]

    def one_level(self, a: Rules, b: Rules) -> bool:
        """Do a and b's images never differ by more than one level (or FLOAT_TOL) on any pixel? Then only
        exact matches can tell them apart."""
        s = self.search
        isf = s.target.is_float
        if isf or set(a.differs(b)) & {"rows", "channels", "transpose"}:
            return False
        ca, cb = s.cache.get(s.scene, a).color, s.cache.get(s.scene, b).color
        da = coded_levels(ca.reshape(-1, 3), a, isf)
        db = coded_levels(cb.reshape(-1, 3), b, isf)
        return bool(bitmap.channel_max(np.abs(da - db)).max(initial=0) <= 1)

    def evidence(self, best: Rules, back: Rules, unit: tuple[str, ...]) -> Evidence:
        """``best`` weighed against ``back`` (``best`` with ``unit`` put back): see the module's docstring."""
        cb, ck = self.cls(best), self.cls(back)
        n = self.search.target.model_shape[0] * self.search.target.model_shape[1]
        h, w = self.search.target.model_shape
        if cb is None or ck is None:  # a layout that does not fit: the one that fits is all the evidence
            mask = np.ones(n, bool) if ck is None else np.zeros(n, bool)
            return Evidence(unit, n if ck is None else 0, n if cb is None else 0, 0, mask.reshape(h, w))
        differ = np.flatnonzero(cb != ck)
        # A pixel the image shows as ``best`` draws it and ``back`` does not is evidence for ``best`` unless a
        # tracer following ``back`` could have drawn it so (ill-conditioned under ``back``); the other way
        # round, evidence against ``best`` unless one following ``best`` could have.
        ill_best, ill_back = self.ill_one(best, differ), self.ill_one(back, differ)
        a, k = cb[differ], ck[differ]
        if self.one_level(best, back):
            made_right, made_wrong = (k >= 1) & (a == 0), (a >= 1) & (k == 0)
        else:
            made_right, made_wrong = (k == 2) & (a < 2), (a == 2) & (k < 2)
        mask = np.zeros(n, bool)
        mask[differ[made_right & ~ill_back]] = True
        neither = self._neither(best, back)
        return Evidence(unit, int(mask.sum()), int((made_wrong & ~ill_best).sum()), neither, mask.reshape(h, w))

    def _neither(self, best: Rules, back: Rules) -> int:
        """Pixels beyond tolerance under both whose two renders differ beyond tolerance (written under best's
        output rules; for output rules alone the pictures are the same colours: 0)."""
        s = self.search
        if not set(best.differs(back)) & set(rules_mod.TRACE_RULES):
            return 0
        cb, ck = self.cls(best), self.cls(back)
        both = np.flatnonzero((cb == 2) & (ck == 2))
        if both.size == 0:
            return 0
        isf = s.target.is_float
        xb = coded_levels(s.cache.get(s.scene, best).color.reshape(-1, 3)[both], best, isf)
        xk = coded_levels(s.cache.get(s.scene, back).color.reshape(-1, 3)[both], best, isf)
        apart = s.target.beyond(bitmap.channel_max(np.abs(xb - xk)))
        at = both[apart]
        return int((~self.ill(best, back, at)).sum()) if at.size else 0


def weakest(found: list[Evidence]) -> Evidence | None:
    """The rule (unit) to put back first: of those the image does not bear out (and that are not undecided),
    the one with the least weight; None when every one holds."""
    weak = [e for e in found if not e.holds and not e.undecided]
    return min(weak, key=lambda e: (e.weight, e.pixels, e.rules)) if weak else None


def confirm(search: Search, given: Rules, best: Rules) -> tuple[Rules, list[Evidence], list[Rejected]]:
    """Put back, one at a time and weakest first, every changed rule the image does not bear out (see the
    module's docstring); return the rule set that is left, the evidence of each rule it changes, and what
    was put back. A rule whose evidence is nil both ways only because every pixel it decides is
    ill-conditioned in one of the two, while putting it back leaves pixels beyond tolerance, stays: the
    image cannot decide it (``Evidence.undecided``; ``one_of`` lists both values)."""
    weigh = Weigher(search)
    rejected: list[Rejected] = []
    while True:
        found = [weigh.evidence(best, put_back(given, best, u), u) for u in groups_of(given, best)]
        for e in found:
            e.undecided = (
                not e.holds and e.pixels == e.against == e.neither == 0 and _worse_without(search, given, best, e.rules)
            )
        worst = weakest(found)
        if worst is None:
            return best, found, rejected
        for name in worst.rules:
            value = rules_mod.format_rule_value(name, getattr(best, name))
            rejected.append(Rejected(name, value, worst.pixels, worst.against, worst.neither))
        best = put_back(given, best, worst.rules)


# ---------------------------------------------------------------------------------------------------------
@dataclass
class OneOf:
    """Rules the image cannot decide: each with the values that fit equally (a number's as an interval)."""

    values: dict[str, list[Any]]  # rule -> values as --rule takes them (or {"from": lo, "to": hi})
    alternatives: list[dict[str, str]]  # the equally fitting rule sets, restricted to those rules
    sentence: str


def same_tracer(a: Rules, b: Rules) -> bool:
    """Are a and b one tracer written two ways? Pixel centres are pixel corners shifted by half a pixel, the
    same rays bit for bit ((x + 0) + 0.5 = x + 0.5): no image can, or needs to, tell them apart."""

    def shift(r: Rules) -> tuple[float, float]:
        half = 0.5 if r.pixel_sample == "center" else 0.0
        return (r.pixel_shift[0] + half, r.pixel_shift[1] + half)

    return shift(a) == shift(b) and replace(a, pixel_sample="corner", pixel_shift=(0.0, 0.0)) == replace(
        b, pixel_sample="corner", pixel_shift=(0.0, 0.0)
    )


def fits_equally(gain: tuple[int, int], pixels: int) -> bool:
    """Does a rule set whose gain over another is ``gain`` (pixels beyond tolerance, pixels a level off) on an
    image of ``pixels`` pixels fit it equally well (``EQUAL_LEVELS``)?"""
    return gain[0] == 0 and abs(gain[1]) <= EQUAL_LEVELS * pixels + 1


def equal(search: Search, a: Rules, b: Rules) -> bool:
    """Do a and b fit the image equally well (``fits_equally``; ill-conditioned pixels left out)?"""
    g = search.compare(a, b)
    return g is not None and fits_equally(g, search.target.model_shape[0] * search.target.model_shape[1])


def _candidates(search: Search, given: Rules, best: Rules) -> list[Rules]:
    """Rule sets that might fit as well as ``best``: compared during the search, one rule away, one named
    rule put back and another changed (a pixel shift of half a pixel draws pixel centres), and the other
    offset_along with its own best offset."""
    out = [r for r in search.compared if r != best]
    names = rules_mod.TRACE_RULES + (rules_mod.OUTPUT_RULES if search.outputs else ())
    out += single_moves(best, names)
    for unit in groups_of(given, best):
        # a named rule put back and another of its kind changed (a traced rule stands in for a traced one; an
        # output rule's one level or layout for an output rule's)
        kind = rules_mod.TRACE_RULES if set(unit) <= set(rules_mod.TRACE_RULES) else rules_mod.OUTPUT_RULES
        back = put_back(given, best, unit)
        out += [m for m in single_moves(back, kind, search.moot(back)) if not set(back.differs(m)) <= set(unit)]
    asked = {"offset", "offset_along"} & set(given.differs(best))  # the offset's alternatives, when it is named
    if asked and isinstance(best.offset, float) and "offset" not in search.moot(best):
        for along in rules_mod.values("offset_along"):
            other = replace(best, offset_along=along)
            x = search.best_offset_everywhere(other)
            if x is not None and valid_rules(replace(other, offset=x)):
                out.append(replace(other, offset=x))
    seen, unique = set(), []
    for r in out:
        if r not in seen and valid_rules(r):
            seen.add(r)
            unique.append(r)
    return unique


def one_of(search: Search, given: Rules, best: Rules, undecided: list[tuple[str, ...]] = ()) -> OneOf | None:
    """The rules on which rule sets that fit as well as ``best`` disagree, among those that change a rule
    ``best`` names (None when there are none); ``undecided``: units ``confirm`` could not decide, each
    with its scene value as the alternative."""
    named = set(given.differs(best))
    equals: list[Rules] = [put_back(given, best, u) for u in undecided]
    asked = [
        r for r in _candidates(search, given, best)
        # a rule the answer does not name: ``indistinguishable`` says what the scene cannot show
        if set(best.differs(r)) & named and r not in equals and not same_tracer(best, r)
        and not search.clearly_worse(best, r)
    ]  # fmt: skip
    traced = [r for r in asked if r.traced() != best.traced()]
    search.cache.prefetch(search.scene, traced, search.quick_pixels(), probe=True)  # one trace for all
    for r in asked:
        if r in equals:
            continue
        if not search.quick_not_worse(best, r):
            continue
        if equal(search, best, r):
            equals.append(r)
    values: dict[str, list[Any]] = {}
    for name, (lo, hi) in _intervals(search, given, best).items():
        values[name] = [{"from": lo, "to": hi}]
    for r in equals:
        for name in best.differs(r):
            for v in (best, r):
                shown = _value(search, name, v)
                values.setdefault(name, [])
                if shown not in values[name]:
                    values[name].append(shown)
    if not values:
        return None
    names = sorted(values)
    alts = []
    for r in [best, *equals]:
        alt = {n: _shown(_value(search, n, r)) for n in names}
        if alt not in alts:
            alts.append(alt)
    return OneOf(values, alts, _sentence(values, alts))


def narrow(iv: tuple[float, float]) -> bool:
    """Is an interval of equally fitting numbers narrow enough to name the simplest one (``NARROW``)?"""
    lo, hi = iv
    return hi <= lo * (1 + NARROW) or (lo == hi)


def _value(search: Search, name: str, r: Rules) -> Any:
    """Rule ``name`` of ``r`` as --rule takes it, or for a number read off the image the interval of values
    that fit as well (``Search.interval``)."""
    iv = search.interval(name, r) if name in ("offset", "t_max") else None
    if iv is not None and not narrow(iv):
        return {"from": iv[0], "to": iv[1]}
    return rules_mod.format_rule_value(name, getattr(r, name))


def _intervals(search: Search, given: Rules, best: Rules) -> dict[str, tuple[float, float]]:
    """The numbers ``best`` names (changes from ``given``) read off the image whose neighbours fit as well:
    the offset's and t_max's brackets from the search, the exponents on either side that fit equally."""
    out: dict[str, tuple[float, float]] = {}
    named = set(given.differs(best))
    for name in ("offset", "t_max"):
        iv = search.interval(name, best)
        if iv is not None and not narrow(iv) and name in named:
            out[name] = iv
    e = best.specular_exponent
    if "specular_exponent" in named and "specular_exponent" not in search.moot(best):
        lo = hi = e
        for step in (-1, 1):
            x = e + step
            while abs(x - e) <= EXPONENT_REACH and 1 <= x <= rules_mod.SPECULAR_EXPONENT_MAX:
                other = replace(best, specular_exponent=x)
                if not (search.quick_not_worse(best, other) and equal(search, best, other)):
                    break
                lo, hi = min(lo, x), max(hi, x)
                x += step
        if lo < hi:
            out["specular_exponent"] = (lo, hi)
    return out


def _shown(v: Any) -> str:
    if isinstance(v, dict):
        return f"between {v['from']:g} and {v['to']:g}"
    return str(v)


def _sentence(values: dict[str, list[Any]], alts: list[dict[str, str]]) -> str:
    if len(alts) > 1 and len(values) > 1:
        options = " or ".join(", ".join(f"{k}={v}" for k, v in a.items()) for a in alts)
        head = f"the image cannot decide {', '.join(sorted(values))}: {options} fit it equally well"
    else:
        parts = [f"your {k} is {' or '.join(_shown(v) for v in vs)}" for k, vs in sorted(values.items())]
        head = "; ".join(parts) + ": the image fits each equally well"
    return head + "; grade your program (minirt grade --program) to tell them apart."
