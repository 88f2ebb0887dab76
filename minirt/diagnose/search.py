"""The search: which rule settings make the reference's render reproduce an image.

Greedy descent in rule space from the scene's own rules (``Search``; minirt.diagnose.explain's
``diagnose`` runs it and reports what each changed rule explains):

- Output rules (encoding, gamma, layout) cost no render: the same colour is re-encoded; the best fit
  is chosen first and again after every step.
- Each step tries every single-rule change (every value of ``rules.values(name)``), every whole
  profile, and the best integer specular exponent (a ternary search on the summed level difference,
  odd and even exponents apart; the tracer reads the exponent at run time, so the search compiles
  once). Candidates are scored on a subset -- a stride of the pixels the current rules get wrong and
  of those they get right, counts scaled back up -- and the best three are rendered in full; the
  first that really removes mismatching pixels is taken. A change one step from the scene's own rules
  is rendered in full once and kept: every image of that scene asks for it.
- A pixel matches a candidate if it matches its float64 or its float32 image (a float32 tracer may
  draw either where rounding decides); a rule with no float64 effect is tried in float32 too.
- A descent stuck with pixels still wrong tries each traced change once more with the output rules that
  fit it best (``Search._paired``): a wrong gamma hides a trace rule's gain and the other way round.
- Greedy steps can take a rule that imitates the right one (a high exponent dims the wrong-side
  highlight that clamping removes) and stall: while pixels stay unexplained the descent restarts from
  the scene's rules with each rule the answer changed forbidden in the first step, and keeps what
  explains most.

Known limit: two rules that only show together, and only through a float32 tracer's rounding (an offset
along the ray *and* the far root from inside a ball), are not found; their pixels are reported
unexplained.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from minirt.diagnose.target import Target, coded_levels
from minirt.diagnose.variants import Variant, VariantCache
from minirt.model import bitmap
from minirt.model import rules as rules_mod
from minirt.model.effects import effects
from minirt.model.rules import Rules
from minirt.model.scene import Ball, Scene


@functools.lru_cache(maxsize=4096)
def valid_rules(r: Rules) -> bool:
    """Whether the tracer accepts this rule set (the one cross-rule constraint: offset_along = "ray" needs a
    number). Kept per rule set: a search asks about the same few hundred rule sets ~600 times (0.4 s of an
    800² grade's validation)."""
    return not rules_mod.validate_model_table("exercise", r.as_dict())


def moot_rules(scene: Scene, rules: Rules) -> set[str]:
    """Rules that provably change no pixel of this scene under ``rules`` (minirt.model.effects): the exponent
    and the clamp without lit terms, the background when it is black, offsets without secondary rays; the
    rules from real solutions' bugs where nothing they act on is there (no balls, no lit terms, every normal
    of unit length as written), the sign of s under an even, unclamped highlight, the normal's sign when
    every normal is turned to face the ray, and the shadow rays' range when none is traced."""
    fx = effects(scene, rules)
    out = set()
    if not fx.specular:
        out |= {"specular_exponent", "specular_s"}
    if rules.clamp is False and rules.specular_exponent % 2 == 0:
        out.add("specular_s")  # (r·(-s))^e = (r·s)^e: an even power, unclamped
    if rules.two_sided is True:
        out.add("ball_normal")  # every normal is turned to face the ray, whichever way it pointed
    if rules.shadow_rays is False:
        out.add("shadow_range")  # no shadow ray is traced: where one would end changes nothing
    if not (fx.diffuse or fx.specular):
        out |= {"clamp", "light", "shadow_rays"}
    if not any(scene.background):
        out.add("background")
    if not (fx.shadows or fx.reflection):
        out |= {"offset", "offset_along"}
    balls = [s for s in scene.shapes if isinstance(s, Ball)]
    planes = [s for s in scene.shapes if not isinstance(s, Ball)]
    if not balls:
        out.add("ball_normal")
    if all(b.radius == 1 for b in balls):
        out.add("raw_normals_ball")
    if all(p.written == 1 for p in planes):
        out.add("raw_normals_plane")
    return out


# Rules whose value the search finds from the image (``Search._found``) rather than from a list of values.
FOUND = ("t_max",)


def single_moves(current: Rules, names: tuple[str, ...], moot: set[str] = frozenset()) -> list[Rules]:
    """Every valid rule set one rule away from ``current``: each rule of ``names`` (but those ``moot`` and
    those whose value is read off the image, ``FOUND``) at each of its candidate values."""
    out = []
    for name in names:
        if name in moot or name in FOUND:
            continue
        for v in rules_mod.values(name):
            if v != getattr(current, name):
                cand = replace(current, **{name: v})
                if valid_rules(cand):
                    out.append(cand)
    return out


def _profile_moves(current: Rules) -> list[Rules]:
    """Whole profiles (their traced rules, the current output rules): a tracer written to another
    edition of the exercise differs in many rules at once, more than single steps find in order."""
    out = []
    for p in rules_mod.PROFILES.values():
        cand = replace(current, **{n: getattr(p, n) for n in rules_mod.TRACE_RULES})
        if cand != current and valid_rules(cand):
            out.append(cand)
    return out


# Candidates are first scored on a subset of pixels: every pixel the current rules get wrong, and a
# fixed stride of the ones they get right (SAMPLE of them, at least), whose breakages are scaled up.
# The best candidate is then rendered in full and accepted only if it really gains; a candidate that
# breaks a thin feature the stride missed is caught there.
SAMPLE = 4096
VERIFY = 3  # candidates verified in full per step before the search gives up
EXPONENT_SEARCH = 256  # the specular exponents a search considers (rules allow up to 1024)
# Rounds of a finer grid of OFFSET_STEPS offsets inside the bracket around the best ones: each round
# shrinks the bracket (in log scale) by about (OFFSET_STEPS + 1) / 2, four rounds of 9 from the grid's
# 10^(1/2) to a factor 1.0008 -- finer than the 2.4 % between 0.5 / 1024 and 5e-4.
OFFSET_ROUNDS = 4
OFFSET_STEPS = 9


def simplest(lo: float, hi: float) -> float:
    """The simplest number x with lo < x <= hi (0 <= lo < hi): fewest significant decimal digits (0.001,
    29.3) or fewest bits of an odd numerator over a power of two (0.5 / 1024 = 2^-11); among equally simple
    ones, the nearest to the middle of the interval (geometric, lo > 0). What a student wrote is simple in
    one of the two; any x in the interval reproduces the image as well as another."""
    if not lo < hi:
        return hi
    mid = math.sqrt(lo * hi) if lo > 0 else hi / 2
    for cost in range(1, 18):
        found = []
        top = math.floor(math.log10(hi))
        bottom = math.floor(math.log10(lo)) if lo > 0 else top - 1
        for e in range(top, bottom - 1, -1):  # decimal: k · 10^(e - cost + 1), k of ``cost`` digits
            kmin, kmax = 10 ** (cost - 1), 10**cost - 1
            scale = 10.0 ** (e - cost + 1)
            for k in {max(kmin, min(kmax, round(mid / scale) + j)) for j in (-1, 0, 1)}:
                x = float(f"{k}e{e - cost + 1}")
                if lo < x <= hi:
                    found.append(x)
        top2 = math.floor(math.log2(hi))
        bottom2 = math.floor(math.log2(lo)) if lo > 0 else top2 - 1
        for e in range(top2, bottom2 - 1, -1):  # binary: m · 2^(e - cost + 1), m odd of ``cost`` bits
            scale = math.ldexp(1.0, e - cost + 1)
            mmin, mmax = 1 << (cost - 1), (1 << cost) - 1
            for m in {max(mmin, min(mmax, round(mid / scale) + j)) for j in (-2, -1, 0, 1, 2)}:
                x = math.ldexp(m, e - cost + 1)
                if m % 2 == 1 and lo < x <= hi:
                    found.append(x)
        if found:
            return min(found, key=lambda x: (abs(math.log(x / mid)) if mid > 0 else abs(x - mid), x))
    return hi


@dataclass
class _Subset:
    idx: np.ndarray  # pixels: the wrong ones' stride, then the right ones'
    n_wrong: int
    w_weight: float
    r_weight: float
    before: np.ndarray | None = None  # the current rules' class of each


class Search:
    """The descent over rule space for one image (``run``), and the scores of rule sets on it (``either``,
    ``compare``, ``final_mask``) that the diagnosis's evidence reuses: every render goes through the cache."""

    def __init__(self, scene: Scene, target: Target, cache: VariantCache, outputs: bool = True):
        self.outputs = outputs  # False: the image's output rules are known (the start's); never searched
        self.scene, self.target, self.cache = scene, target, cache
        self.steps: list[dict[str, Any]] = []
        self._exponents: dict[Rules, int] = {}
        self._offsets: dict[Rules, float | None] = {}
        self._either: dict[Rules, np.ndarray | None] = {}  # ``either``'s differences, per rule set
        # What the diagnosis's "one of" looks at (minirt.diagnose.evidence): every rule set compared on every
        # pixel, and the interval of values a number read off the image could take, per (rule, the other rules
        # with that one at 0.0 for the offset, inf for t_max: ``interval``)
        self.compared: list[Rules] = []
        # every candidate's estimated gain over the step's rule set it was scored against, with the margin
        # three pixels of that step's stride stand for, by traced rules: current -> {candidate: (gain, margin)}
        self.estimates: dict[Rules, dict[Rules, tuple[float, float]]] = {}
        self.intervals: dict[tuple[str, Rules], tuple[float, float]] = {}
        target.model_shape = (scene.camera.height, scene.camera.width)

    def full(self, rules: Rules) -> tuple[np.ndarray | None, Variant]:
        v = self.cache.get(self.scene, rules)
        return self.target.difference(v.color, rules), v

    def ill_at(self, rules: Rules, v: Variant, at: np.ndarray) -> np.ndarray:
        """Ill-conditioned flags of a variant (its shadow flags and its rays' band) at pixels ``at``;
        for a subset variant, ``at`` indexes its subset."""
        if v.idx is None:
            return v.shadow_ill.reshape(-1)[at] | self.cache.band(self.scene, rules, at)
        return v.shadow_ill[at] | self.cache.band(self.scene, rules, v.idx[at])

    def either(self, rules: Rules) -> tuple[np.ndarray | None, Variant]:
        """Like ``full``, but a pixel matches if it matches the rules' float64 or float32 image: a float32
        tracer following these rules may draw either where rounding decides (its self-shadowing acne)."""
        v = self.cache.get(self.scene, rules, f32=True)
        if rules in self._either:  # the same renders, written and compared again at every step otherwise
            return self._either[rules], v
        d = self.target.difference(v.color, rules)
        if d is not None and v.f32_color is not None:
            d = np.minimum(d, self.target.difference(v.f32_color, rules))
        self._either[rules] = d
        return d, v

    def compare(self, a: Rules, b: Rules) -> tuple[int, int] | None:
        """Exact gain of b over a on every pixel: (beyond tolerance, one level off) that b fixes minus
        those it breaks, each matched by its float64 or float32 image. A pixel ill-conditioned in either
        never counts: it is looked at only where the two differ, as elsewhere it adds the same to both."""
        (da, va), (db, vb) = self.either(a), self.either(b)
        for r in (a, b):
            if r not in self.compared:
                self.compared.append(r)
        if da is None or db is None:
            return None if db is None else (1 << 40, 0)
        differ = np.flatnonzero((self.classes(da) != self.classes(db)).reshape(-1))
        keep = ~(self.ill_at(a, va, differ) | self.ill_at(b, vb, differ) | self.flips(a)[differ])
        sa = self.target.score(da.reshape(-1)[differ], keep)
        sb = self.target.score(db.reshape(-1)[differ], keep)
        return sa[0] - sb[0], sa[1] - sb[1]

    def flips(self, rules: Rules) -> np.ndarray:
        """(H·W,) pixels a float32 render of these rules draws otherwise: a float32 tracer's rounding, not
        a rule, decides them (self-shadowing acne under a fixed offset, reflected edges). The current
        rules' flips are left out while searching, so a student's float32 acne never reads as a rule."""
        return self.cache.get(self.scene, rules, f32=True).f32_flips.reshape(-1)

    def classes(self, d: np.ndarray) -> np.ndarray:
        """Per pixel: 0 exact, 1 one level off, 2 beyond tolerance: off + beyond (beyond tolerance is off
        too), two comparisons and an add where two nested np.where made three whole-image temporaries."""
        out = self.target.off(d).view(np.int8)
        out += self.target.beyond(d)
        return out

    def run(self, start: Rules) -> Rules:
        """Descend; where pixels stay unexplained, descend again from the start with each rule the
        answer changed forbidden in the first step, and keep what explains most. A greedy step can take
        a rule that imitates the right one (a high exponent dims the wrong-side highlight that clamping
        removes) and then stall; the restart lets the right one go first."""
        first = self.best_output(start)
        self.steps = []
        best = self._descend(start, first)
        path = self.steps
        tried: set[str] = set()
        while self._residual(best):
            names = [n for n in best.differs(start) if n in rules_mod.TRACE_RULES and n not in tried]
            if not names:
                break
            tried.update(names)
            improved = False
            for name in names:
                self.steps = []
                alt = self._descend(start, first, tabu=name)
                g = self.compare(best, alt) if alt != best else None
                if g is not None and g > (0, 0):
                    best, path, improved = alt, self.steps, True
            if not improved:
                break
        self.steps = path
        return best

    def _residual(self, rules: Rules) -> int:
        """Pixels beyond tolerance under ``rules`` (float64 or float32 image) that are not
        ill-conditioned (nor float32 flips)."""
        d, v = self.either(rules)
        if d is None:
            return self.target.model_shape[0] * self.target.model_shape[1]
        where = np.flatnonzero(self.target.beyond(d).reshape(-1))
        return int((~(self.ill_at(rules, v, where) | self.flips(rules)[where])).sum())

    def interval(self, name: str, rules: Rules) -> tuple[float, float] | None:
        """The interval of ``name``'s values (offset, t_max) that fit as well as ``rules``' own, as the search
        read it off the image with the other rules as in ``rules``; None when it did not, or when ``rules``'
        value lies outside it."""
        other = replace(rules, **{name: 0.0 if name == "offset" else math.inf}).traced()
        iv = self.intervals.get((name, other))
        x = getattr(rules, name)
        if iv is None or not isinstance(x, float) or not (iv[0] <= x <= iv[1]):
            return None
        return iv

    def moot(self, rules: Rules) -> set[str]:
        """``moot_rules`` of this search's scene."""
        return moot_rules(self.scene, rules)

    def subset_of(self, rules: Rules) -> _Subset | None:
        """The pixels a step from ``rules`` scores candidates on (a stride of the wrong ones and of the right
        ones, with their weights); None when the layout does not fit."""
        dc, _ = self.either(rules)
        if dc is None:
            return None
        cls = self.classes(dc).reshape(-1)
        wrong, right = np.flatnonzero(cls > 0), np.flatnonzero(cls == 0)
        wrong_s = wrong[:: max(1, wrong.size // (4 * SAMPLE))]
        right_s = right[:: max(1, right.size // SAMPLE)]
        sub = _Subset(
            idx=np.concatenate([wrong_s, right_s]),
            n_wrong=wrong_s.size,
            w_weight=wrong.size / max(1, wrong_s.size),
            r_weight=right.size / max(1, right_s.size),
        )
        sub.before = cls[sub.idx]
        return sub

    def best_offset_everywhere(self, rules: Rules) -> float | None:
        """The numeric offset that fits best with the other rules of ``rules`` (``_best_offset`` on the
        pixels a step from ``rules`` would score)."""
        sub = self.subset_of(rules)
        return None if sub is None else self._best_offset(rules, sub)

    def clearly_worse(self, a: Rules, b: Rules) -> bool:
        """Did a step of the descent already find b worse than a, beyond its stride's margin? True when some
        step scored both (a as the step's own rule set, or as a candidate beside b) and b's estimated gain
        falls short of a's by more than three pixels of that stride: no render needed to rule b out."""
        a, b = a.traced(), b.traced()  # scored on pixels beyond tolerance: the output rules move them by a level
        for current, est in self.estimates.items():
            if b not in est:
                continue
            eb, margin = est[b]
            ea = 0.0 if current == a else (est[a][0] if a in est else None)
            if ea is not None and eb < ea - margin:
                return True
        return False

    def quick_pixels(self) -> np.ndarray:
        """The stride of pixels ``quick_not_worse`` traces a candidate on (``VariantCache.prefetch`` them)."""
        h, w = self.target.model_shape
        return np.arange(0, h * w, max(1, (h * w) // SAMPLE))

    def quick_not_worse(self, a: Rules, b: Rules) -> bool:
        """Could b fit the image as well as a? On a stride of SAMPLE pixels (b traced there only), b leaves at
        most two more pixels beyond tolerance than a (room for a pixel ill-conditioned in b): a rule set
        clearly worse there is not looked at on every pixel. (A rule set that fits as well leaves the same
        pixels beyond tolerance on every stride; one that breaks even 0.1 % of the pixels shows on ~4.)"""
        at = self.quick_pixels()
        da, va = self.either(a)
        if da is None:
            return True
        if a.traced() == b.traced():  # output rules alone: a's own colours, written b's way (no render)
            color, ill = va.color.reshape(-1, 3)[at], va.shadow_ill.reshape(-1)[at]
        else:
            vb = self.cache.subset(self.scene, b, at, probe=True)
            color, ill = vb.color, vb.shadow_ill
        db = self.target.difference(color, b, at)
        if db is None:
            return False
        ba, bb = self.target.beyond(da.reshape(-1)[at]), self.target.beyond(db) & ~ill
        return int((bb & ~ba).sum()) - int((ba & ~bb).sum()) <= 2

    def _descend(self, start: Rules, current: Rules, tabu: str | None = None) -> Rules:
        """Greedy steps from ``current`` until no single change (or profile) removes mismatching pixels.

        Each step: (1) every candidate is scored on a subset of pixels (a stride of the wrong ones and
        of the right ones, counts scaled back up), traced on those pixels only -- unless it is one step
        from the scene's own rules (rendered in full once, shared by every image of the scene) or
        changes only output rules (no render). (2) The best VERIFY are rendered in full and the first
        that really gains is taken.

        A descent never returns to a rule set it has been at: ``compare`` leaves out pixels that are
        ill-conditioned in either rule set, so on a scene full of such pixels a change and its undoing
        can both look like gains (and the output refit after a step can undo that step); the rule space
        is finite, so the descent ends."""
        seen = {current}
        while True:
            dc, vc = self.either(current)
            if dc is None:
                return current
            cls = self.classes(dc).reshape(-1)
            if not (cls > 0).any():
                return current
            sub = self.subset_of(current)
            flips = self.flips(current)
            moot = moot_rules(self.scene, current)
            names = rules_mod.TRACE_RULES + (rules_mod.OUTPUT_RULES if self.outputs else ())
            singles = single_moves(current, names, moot)
            if "specular_exponent" not in moot:  # beside the listed values, the best integer
                e = self._best_exponent(current)
                if e != current.specular_exponent and e not in rules_mod.values("specular_exponent"):
                    singles.append(replace(current, specular_exponent=e))
            # t_max read off the image's own hits competes with the listed values at every step (a stump on the
            # t buffer, no render); the cut found in reflections and the offset only when the descent is stuck
            t_max = self._best_t_max(current, cls, reflected=False)
            if t_max is not None and t_max != current.t_max and valid_rules(replace(current, t_max=t_max)):
                singles.append(replace(current, t_max=t_max))
            singles += _profile_moves(current)
            singles = [c for c in singles if c not in seen]
            if tabu:
                singles = [c for c in singles if tabu not in current.differs(c)]
                tabu = None
            better = self._step(start, current, vc, sub, flips, singles, seen)
            if better is None and self._residual(current):  # not for pixels only a level off
                better = self._step(start, current, vc, sub, flips, self._paired(current, singles, seen), seen)
            if better is None and self._residual(current):  # values read off the image: t_max, the offset
                found = [c for c in self._found(current, cls, sub, moot) if c not in seen]
                better = self._step(start, current, vc, sub, flips, found, seen)
            if better is None:
                return current
            seen.add(better)
            current = better

    def _step(
        self, start: Rules, current: Rules, vc: Variant, sub: _Subset, flips, cands: list[Rules], seen: set[Rules]
    ):
        """The candidate that really gains most (with its best output rules, unless that refit lands on a
        rule set already ``seen``), or None (see ``_descend``)."""
        scored = []
        # the candidates traced on the subset, traced together (``VariantCache.prefetch``); not those one
        # step from the scene's rules that a shared cache renders in full (``_traced``)
        keep = self.cache.share
        estimates = [self._estimate(start, current, vc, c, sub.idx) for c in cands]  # (each asked once)
        self.cache.prefetch(self.scene, [
            c for c, est in zip(cands, estimates, strict=True)
            if est is None and c.traced() != current.traced() and not (keep and len(start.differs(c)) == 1)
        ], sub.idx)  # fmt: skip
        gains = []
        for k, c in enumerate(cands):
            est = estimates[k] if estimates[k] is not None else self._traced(start, current, vc, c, sub.idx)
            gains.append((est, self._gain_on(sub, current, vc, c, *est, flips)))
        # No effect in float64 here: a rule a float32 tracer shows only through rounding (an offset along the
        # ray, the far root from inside a ball), seen in its self-shadowing acne -- their float32 images
        # traced together (``VariantCache.prefetch32``), then each compared as before.
        now = current.traced()
        twin = [e is not None and e[0] == 0 and c.traced() != now for c, (_, e) in zip(cands, gains, strict=True)]
        self.cache.prefetch32(self.scene, [c for c, t in zip(cands, twin, strict=True) if t], sub.idx)
        for k, c in enumerate(cands):
            est, e = gains[k]
            if twin[k]:
                v32 = self.cache.subset32(self.scene, c, sub.idx)
                if v32 is not None:
                    e = self._gain_on(sub, current, vc, c, *est, flips, color2=v32.color)
            if e is not None:  # what the diagnosis's "one of" may reuse (``clearly_worse``)
                est = self.estimates.setdefault(current.traced(), {})
                est[c.traced()] = (e[0], 3 * max(sub.w_weight, sub.r_weight))
            if e is not None and e > (0, 0):
                scored.append([(-e[0], -e[1]), len(start.differs(c)), k, c])
        scored.sort(key=lambda s: s[:3])
        for _, _, _, c in scored[:VERIFY]:
            g = self.compare(current, c)
            if g is not None and g > (0, 0):
                self.steps.append({"rules": current.differs(c), "gain": g[0], "gain_one_level": g[1]})
                refit = self.best_output(c)
                return c if refit in seen else refit
        return None

    def _paired(self, current: Rules, singles: list[Rules], seen: set[Rules]) -> list[Rules]:
        """When no single change gains: each change of the traced rules with the output rules that fit it
        best. An output rule can hide a trace rule's effect and the other way round -- the background
        added to misses instead of hits, under a gamma curve, leaves every pixel wrong under either change
        alone (``matte``: every pixel) -- so the pair is tried as one step. Only a descent stuck with
        pixels beyond tolerance pays for it (a full render and an output fit per candidate); one stuck
        with pixels a level off -- most answers' last step -- does not (it doubled an 800² grade)."""
        out: list[Rules] = []
        for c in singles if self.outputs else ():
            if c.traced() == current.traced():
                continue
            refit = self.best_output(c)
            if refit != c and refit not in seen and refit not in out:
                out.append(refit)
        return out

    def _found(self, current: Rules, cls: np.ndarray, sub: _Subset, moot: set[str]) -> list[Rules]:
        """Candidates whose value is read off the image, for a descent stuck with pixels beyond tolerance:
        the t_max that cuts the wrong pixels' hits or their reflections' off (``_best_t_max``) and the
        numeric offset that fits best (``_best_offset``)."""
        out = []
        t_max = self._best_t_max(current, cls)  # (the cut of the pixels' own hits is a move of every step)
        if t_max is not None and t_max != current.t_max:
            out.append(replace(current, t_max=t_max))
        if "offset" not in moot:
            x = self._best_offset(current, sub)
            if x is not None and x != current.offset:
                out.append(replace(current, offset=x))
        return [c for c in out if valid_rules(c)]

    def _best_t_max(self, rules: Rules, cls: np.ndarray, reflected: bool = True) -> float | None:
        """The t_max whose cut best matches the wrong pixels: the pixels sorted by their farthest hit (their
        own, or with ``reflected`` a reflected ray's: ``VariantCache.deep_t``), farthest first, the cut that
        takes the most pixels beyond tolerance that the image shows as a miss would be drawn, and the fewest
        exact ones that it does not (a decision stump on the reference's t buffers); then the simplest number
        between the farthest hit it keeps and the nearest it drops (``simplest``). None when no cut fixes
        more pixels than it breaks."""
        sid, t = self.cache.first_hits(self.scene, rules)
        first = np.where(sid >= 0, t, 0.0)
        deep = self.cache.deep_t(self.scene, rules) if reflected else np.zeros_like(first)
        key = np.maximum(first, deep)  # a cut below it changes the pixel: its own hit or a reflection's
        hit = np.flatnonzero(key > 0)
        if hit.size == 0:
            return None
        # what a cut pixel shows: the colour of a miss (the background under "on-miss", else black)
        h, w = self.target.model_shape
        miss = np.zeros((h, w, 3))
        if rules.background == "on-miss":
            miss[:] = self.scene.background
        dm = self.target.difference(miss, rules)
        if dm is None:
            return None
        as_miss = ~self.target.beyond(dm).reshape(-1)
        if not reflected and not (as_miss & (cls.reshape(-1) == 2) & (first > 0)).any():
            return None  # no wrong hit drawn as a miss: no cut of the own hits can gain
        order = hit[np.argsort(-key[hit], kind="stable")]
        # a cut at the pixel's own hit fixes a wrong pixel that the image shows as a miss, and breaks a right
        # one that it does not; one in a reflection changes the pixel: it fixes it if wrong, else breaks it
        own = first[order] >= deep[order]
        c, m = cls.reshape(-1)[order], as_miss[order]
        fixes, breaks = (c == 2) & (m | ~own), (c == 0) & (~m | ~own)
        score = np.cumsum(fixes.astype(np.int64) - breaks)
        tt = key[order]
        cut = np.flatnonzero(np.append(tt[1:] != tt[:-1], True))  # cut only between different t
        k = cut[np.argmax(score[cut])]
        if score[k] <= 0:
            return None
        lo = float(tt[k + 1]) if k + 1 < tt.size else 0.0
        x = simplest(lo, float(tt[k]))
        self.intervals[("t_max", replace(rules, t_max=math.inf).traced())] = (lo, float(tt[k]))
        return x

    def _best_offset(self, rules: Rules, sub: _Subset) -> float | None:
        """The numeric offset that fits the image best with the other rules as they are, found rather than
        picked from a list: the pixels beyond tolerance on the search's subset counted on a grid of offsets
        (four a decade, 1e-8 .. 0.1, and 0), then the bracket around the best run narrowed by finer grids
        (``OFFSET_ROUNDS``, on the pixels that change inside it), then the simplest number
        inside (``simplest``): a student's 0.5 / 1024 comes out as 0.00048828125, not as the nearest grid
        value. The tracer reads the offset at run time: one kernel for all."""
        if rules.offset == "error-bound" and rules.offset_along == "ray":
            return None
        key = replace(rules, offset=0.0).traced()
        if key in self._offsets:
            return self._offsets[key]
        idx = sub.idx
        weight = np.where(np.arange(idx.size) < sub.n_wrong, sub.w_weight, sub.r_weight)

        def beyond(x: float, at: np.ndarray) -> np.ndarray:
            r = replace(rules, offset=x)
            v = self.cache.subset(self.scene, r, at, probe=True)
            d = self.target.difference(v.color, r, at)
            return self.target.beyond(d) & ~v.shadow_ill

        def traced_together(xs: list[float], at: np.ndarray) -> None:  # one kernel for them, the same bits
            self.cache.prefetch(self.scene, [replace(rules, offset=x) for x in xs], at, probe=True)

        grid = [0.0] + [10.0 ** (k / 4) for k in range(-32, -3)]  # 1e-8 .. 0.1: a student's offsets
        traced_together(grid, idx)
        counts = [float((beyond(x, idx) * weight).sum()) for x in grid]
        best = min(counts)
        runs = [i for i, c in enumerate(counts) if c == best]
        a, b = runs[0], runs[-1]
        if a == 0:
            self._offsets[key] = 0.0
            self.intervals[("offset", key)] = (0.0, grid[b])
            return 0.0

        # Narrow the bracket around the best run in rounds, each a finer grid on the pixels of the whole
        # image whose match differs between the bracket's ends and its best offset.
        lo, hi = max(grid[a - 1], grid[1] / 2), grid[min(b + 1, len(grid) - 1)]
        mid = grid[(a + b) // 2]
        everywhere = np.arange(self.target.model_shape[0] * self.target.model_shape[1])
        traced_together([lo, mid, hi], everywhere)
        ends = [beyond(x, everywhere) for x in (lo, mid, hi)]
        at = np.flatnonzero((ends[0] != ends[1]) | (ends[1] != ends[2]))
        if at.size:
            for _ in range(OFFSET_ROUNDS):
                xs = [lo * (hi / lo) ** (k / (OFFSET_STEPS + 1)) for k in range(OFFSET_STEPS + 2)]
                traced_together(xs[1:-1], at)
                c = [int(beyond(x, at).sum()) for x in xs[1:-1]]
                run = [k + 1 for k, v in enumerate(c) if v == min(c)]
                lo, hi = xs[run[0] - 1], xs[run[-1] + 1]
        x = simplest(lo, hi)
        self._offsets[key] = x
        self.intervals[("offset", key)] = (lo, hi)
        return x

    def _one_step(self, start: Rules, name: str, value: Any) -> Variant | None:
        """The full render of the scene's own rules with one rule changed (shared across images); for a
        cache that is not shared (``VariantCache.share``) only one already there: the others are traced on
        the search's subset of pixels (``_traced``), all a single image's decision needs."""
        r = start if value == getattr(start, name) else replace(start, **{name: value})
        if not valid_rules(r) or not (self.cache.share or r == start or self.cache.has(self.scene, r)):
            return None
        return self.cache.get(self.scene, r, pin=True)

    def _estimate(
        self, start: Rules, current: Rules, vc: Variant, c: Rules, idx: np.ndarray
    ) -> tuple[np.ndarray, Variant, np.ndarray] | None:
        """(colour at idx, the variant whose ill-conditioned flags stand for the candidate's, positions
        in it) when it needs no tracing: an output-rule change (the same colour) or a change that makes
        the candidate a one-step render from the scene's own rules (shared by every image of the
        scene). None otherwise: composing one-step differences was tried and misleads where rules
        interact (clamping and the exponent act on the same highlight)."""
        changed = [n for n in current.differs(c) if n in rules_mod.TRACE_RULES]
        if not changed:
            return vc.color.reshape(-1, 3)[idx], vc, idx
        if len(changed) == 1:
            (name,) = changed
            old = self._one_step(start, name, getattr(current, name))
            if old is not None and current.traced() == old.rules:
                new = self._one_step(start, name, getattr(c, name))
                if new is not None:
                    return new.color.reshape(-1, 3)[idx], new, idx
        return None

    def _traced(self, start: Rules, current: Rules, vc: Variant, c: Rules, idx: np.ndarray):
        if c.traced() == current.traced():
            return vc.color.reshape(-1, 3)[idx], vc, idx
        # one step from the scene's own rules: every image of this scene asks for it, keep it
        v = self.cache.subset(self.scene, c, idx, keep=self.cache.share and len(start.differs(c)) == 1)
        return v.color, v, np.arange(idx.size)

    def _gain_on(
        self, sub: _Subset, current: Rules, vc: Variant, c: Rules, color, v: Variant, at: np.ndarray, flips, color2=None
    ) -> tuple[float, float] | None:
        """The candidate's estimated gain over the current rules on the subset: (pixels beyond tolerance,
        pixels one level off) it fixes minus those it breaks, the stride's counts scaled back up. With
        ``color2`` (its float32 image) a pixel matching either counts as matching."""
        d = self.target.difference(color, c, sub.idx)
        if d is None:
            return None
        if color2 is not None:
            d = np.minimum(d, self.target.difference(color2, c, sub.idx))
        before, after = sub.before, self.classes(d)
        # ill-conditioned pixels count for neither; they matter only where the two differ
        keep = np.ones(sub.idx.size, dtype=bool)
        ch = np.flatnonzero(before != after)
        where = sub.idx[ch]
        keep[ch] = ~(self.ill_at(current, vc, where) | self.ill_at(c, v, at[ch]) | flips[where])
        w_, r_ = slice(0, sub.n_wrong), slice(sub.n_wrong, None)

        def count(sl, b, a):
            return int(((before[sl] == b) & (after[sl] == a) & keep[sl]).sum())

        fixed2 = (count(w_, 2, 0) + count(w_, 2, 1)) * sub.w_weight
        fixed1 = count(w_, 1, 0) * sub.w_weight
        worse = count(w_, 1, 2) * sub.w_weight  # one level off made worse: one more beyond, one fewer off
        part = count(w_, 2, 1) * sub.w_weight  # beyond made one level off: one more off
        broke2 = count(r_, 0, 2) * sub.r_weight
        broke1 = count(r_, 0, 1) * sub.r_weight
        return fixed2 - worse - broke2, fixed1 - broke1 + worse - part

    def best_output(self, rules: Rules) -> Rules:
        """The output rules (no render needed) that fit the image best for these traced rules: every
        encoding and gamma is encoded once and compared with the image in every layout, on a stride of
        about 4 SAMPLE pixels (single output-rule moves are verified in full later by the descent)."""
        if not self.outputs:
            return rules
        v = self.cache.get(self.scene, rules)
        n = v.color.shape[0] * v.color.shape[1]
        at = np.arange(0, n, max(1, n // (4 * SAMPLE)))
        color, sill = v.color.reshape(-1, 3)[at], v.shadow_ill.reshape(-1)[at]
        encs = rules_mod.values("encoding") if not self.target.is_float else (rules.encoding,)
        best, best_key = None, None
        keep, given = ~sill, rules_mod.output_rules_of(rules)
        sampled: dict[tuple, np.ndarray | None] = {}  # each layout's image on the stride, taken once
        for enc in encs:
            for gam in rules_mod.values("gamma"):
                coded = coded_levels(color, replace(rules, encoding=enc, gamma=gam), self.target.is_float)
                for tr in (False, True):
                    for rows in rules_mod.values("rows"):
                        for ch in rules_mod.values("channels"):
                            if (tr, rows, ch) not in sampled:
                                img = self.target.in_layout(replace(rules, transpose=tr, rows=rows, channels=ch))
                                fits = img.shape[:2] == self.target.model_shape
                                sampled[tr, rows, ch] = img.reshape(-1, 3)[at] if fits else None
                            img_at = sampled[tr, rows, ch]
                            if img_at is None:
                                continue
                            d = bitmap.channel_max(np.abs(coded - img_at))
                            # the candidate differs from ``rules`` in its output rules only: the count of
                            # them that changed is len(rules.differs(candidate)), without making it
                            out = (enc, gam, rows, ch, tr)  # rules_mod.OUTPUT_RULES' order
                            moved = sum(a != b for a, b in zip(out, given, strict=True))
                            key = (*self.target.score(d, keep), moved)
                            if best_key is None or key < best_key:
                                best, best_key = out, key
        if best is None:
            return rules
        return replace(rules, **dict(zip(rules_mod.OUTPUT_RULES, best, strict=True)))

    def _best_exponent(self, rules: Rules) -> int:
        """The integer exponent that fits the image best with the other rules as they are: the listed
        values are too coarse (an exponent of 6 loses to 8 there, 4 and 8 being equally wrong) and the
        count of mismatching pixels is flat away from the right value (a highlight is wrong or right),
        so a ternary search follows the summed level difference on a stride of pixels, which falls
        towards it -- odd and even exponents apart (unclamped, an odd power of a negative r·s is
        negative: a different curve). The tracer reads the exponent at run time: one kernel for all."""
        key = replace(rules, specular_exponent=1).traced()
        if key in self._exponents:
            return self._exponents[key]
        n = self.target.model_shape[0] * self.target.model_shape[1]
        at = np.arange(0, n, max(1, n // (4 * SAMPLE)))
        memo: dict[int, float] = {}

        def l1(x: int) -> float:
            if x not in memo:
                r = replace(rules, specular_exponent=x)
                v = self.cache.subset(self.scene, r, at, probe=True)
                d = self.target.difference(v.color, r, at)
                memo[x] = math.inf if d is None else float(d[~v.shadow_ill].sum())
            return memo[x]

        found = []
        spans = []
        for parity in (0, 1):
            xs = [x for x in range(1, EXPONENT_SEARCH + 1) if x % 2 == parity]
            spans.append([xs, 0, len(xs) - 1])
        while True:  # the two ternary searches side by side: each round's four exponents traced together
            asks = []
            for xs, lo, hi in spans:
                if hi - lo > 2:
                    asks += [xs[lo + (hi - lo) // 3], xs[hi - (hi - lo) // 3]]
                else:
                    asks += xs[lo : hi + 1]
            asks = [x for x in asks if x not in memo]
            self.cache.prefetch(self.scene, [replace(rules, specular_exponent=x) for x in asks], at, probe=True)
            if not any(hi - lo > 2 for _, lo, hi in spans):
                break
            for span in spans:
                xs, lo, hi = span
                if hi - lo > 2:
                    m1, m2 = lo + (hi - lo) // 3, hi - (hi - lo) // 3
                    span[1:] = [lo, m2] if l1(xs[m1]) <= l1(xs[m2]) else [m1, hi]
        for xs, lo, hi in spans:
            found.append(min(xs[lo : hi + 1], key=lambda x: (l1(x), x)))
        best = min(found, key=lambda x: (l1(x), x))
        self._exponents[key] = best
        return best

    def final_mask(self, rules: Rules, f32_of: list[Rules]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(beyond-tolerance mask, off-by-any mask, ill mask) of ``rules`` on every pixel, leaving out
        pixels ill-conditioned in it (band, shadows, float32 flips) or in the renders ``f32_of``."""
        shape = self.target.model_shape
        d, v = self.either(rules)
        if d is None:
            full = np.ones(shape, dtype=bool)
            return full, full, np.zeros(shape, dtype=bool)
        off = self.target.off(d)
        ill = np.zeros(shape, dtype=bool)
        where = np.flatnonzero(off.reshape(-1))
        ill.reshape(-1)[where] = self.ill_at(rules, v, where)
        for r in f32_of:
            ill |= self.cache.get(self.scene, r, f32=True).f32_flips & off
        return self.target.beyond(d) & ~ill, off & ~ill, ill
