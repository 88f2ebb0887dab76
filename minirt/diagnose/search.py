"""Diagnosis: which rule settings explain an image?

Given a scene and an image that some tracer made of it (a student's, or an oracle's colour buffer),
search the space of model rules (minirt.model.rules) for the setting whose render reproduces the image, and
say how many pixels each differing rule explains. ``grade`` uses it for outside images; ``check``
uses it for an oracle's remaining difference. It sits beside the harness: it consumes renders of the
reference tracer and rule sets, and never changes the tracer.

How an image is compared with a render (``Target.mismatch``)
-------------------------------------------------------------
- An 8-bit image: the render's colour is written as the candidate's output rules say (gamma,
  encoding, layout; minirt.model.bitmap) and a pixel matches when every channel is within one level: a
  student's float32 arithmetic or another rounding order moves a value across a quantisation step,
  never by two levels (relative error ~1e-6 of a value <= 255 is ~3e-4 of a level).
- A float image (EXR, float TIFF, 16-bit): both are clamped to [0, 1], put through the gamma rule,
  and a pixel matches when every channel is within ``FLOAT_TOL``.
- Ill-conditioned pixels never count: a primary ray whose hit, closest shape or start inside a ball
  is within ``EPS_REL`` (a float32 tracer's rounding) of flipping (minirt.reference.band), a shadow ray that
  close to a ball's silhouette, a pixel whose float32 render differs from its float64 one
  (``_Search.ill_at``, ``flips``). Comparing two candidates, a pixel ill-conditioned in either is left
  out of both scores, so such a pixel never decides between them.

The search (``diagnose``)
-------------------------
Greedy descent in rule space from the scene's own rules (``_Search``):

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
  fit it best (``_Search._paired``): a wrong gamma hides a trace rule's gain and the other way round.
- Greedy steps can take a rule that imitates the right one (a high exponent dims the wrong-side
  highlight that clamping removes) and stall: while pixels stay unexplained the descent restarts from
  the scene's rules with each rule the answer changed forbidden in the first step, and keeps what
  explains most.

Renders are cached per (scene, size, traced rules) in a ``VariantCache`` that a class run shares
across students, so each variant is traced once however many images are graded. Known limit: two
rules that only show together, and only through a float32 tracer's rounding (an offset along the ray
*and* the far root from inside a ball), are not found; their pixels are reported unexplained.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from minirt.model import bitmap
from minirt.model import rules as rules_mod
from minirt.model.effects import effects
from minirt.model.rules import Rules
from minirt.model.scene import Ball, Scene

# A float32 tracer's ray directions, roots and hit points carry relative errors of order gamma(n) =
# n·2^-24 for the n ≈ 10-30 chained roundings of a ray's set-up and intersection; 2^6 u = 3.8e-6
# covers n up to 64. A decision whose relative margin is below it may go either way in such a tracer.
EPS_REL = 2.0**-24 * 64
# Float images: half an 8-bit level (1/510 = 2.0e-3) is where the 8-bit image of the same values
# could first differ by a level; 2^-10 = 9.8e-4 sits below it and ~150x above a float32 tracer's
# colour error (~100 roundings of 2^-24 on values <= 1, 6e-6).
FLOAT_TOL = 2.0**-10
# Images up to this many pixels render every candidate in full (and keep it for the next image).
FULL_RENDER_PIXELS = 512 * 512
# Levels an 8-bit channel may differ by: one (a value on the other side of a rounding step).
LEVEL_TOL = 1


@dataclass
class Variant:
    """One candidate's render, on every pixel or on a subset (``idx``, row-major pixel indices)."""

    rules: Rules  # traced rules only (output rules at their defaults)
    color: np.ndarray  # (H, W, 3) float64, or (N, 3) on a subset
    shadow_ill: np.ndarray  # (H, W) or (N,) bool: shadow rays within rounding of a ball's silhouette
    idx: np.ndarray | None = None  # None: every pixel
    f32_flips: np.ndarray | None = None  # (H, W) bool, on demand (full renders only)
    f32_stored: np.ndarray | None = None  # (H, W, 3) float32: the same rules traced in float32

    @property
    def f32_color(self) -> np.ndarray | None:
        """The float32 render as float64 (exact: every float32 is a float64), so that it is encoded with
        the same float64 arithmetic as ``color``; kept as float32, half the bytes."""
        return None if self.f32_stored is None else self.f32_stored.astype(np.float64)

    @property
    def nbytes(self) -> int:
        extra = sum(a.nbytes for a in (self.f32_flips, self.f32_stored) if a is not None)
        return self.color.nbytes + self.shadow_ill.nbytes + extra


class VariantCache:
    """Renders of one or more scenes under many rule sets, shared by every image graded in one process;
    subset renders are the search's own and not kept. Tracing, not compiling, is what the cache saves:
    Dr.Jit keeps compiled kernels.

    Full renders (float64 colour, shadow flags, and the float32 twin when asked for: ``Variant.nbytes``
    counts them all) are kept up to ``max_bytes``, least recently used first out -- except the *pinned*
    ones: the scene's own rules with at most one rule changed, which every image of the scene asks for.
    They are few (a scene's rules have ~35 single changes) and never evicted, so a long class run does not
    trace them again; only the renders of one image's own search path age out.

    ``requested`` collects the candidate renders (rules, precision) asked for since it was last cleared,
    traced now or taken from the cache: the diagnosis reports that count, which does not depend on what
    earlier images left in the cache (a class graded by one process or by several writes the same
    pages)."""

    def __init__(self, max_bytes: int = 2 << 30):
        self.max_bytes = max_bytes
        self._items: OrderedDict[tuple, Variant] = OrderedDict()
        self._bytes = 0  # the kept variants' nbytes summed, kept up to date as they come, grow and go
        self._pinned: set[tuple] = set()
        self._bands: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}
        self.alternatives: dict[tuple, tuple[list[dict[str, Any]], set]] = {}  # see ``indistinguishable``
        self.requested: set[tuple] = set()
        self.renders = 0  # rays traced, in units of whole images
        self.hits = 0

    @staticmethod
    def _key(scene: Scene, rules: Rules) -> tuple:
        return (scene.digest, scene.source, scene.camera.width, scene.camera.height, rules.traced())

    def get(self, scene: Scene, rules: Rules, f32: bool = False, pin: bool = False) -> Variant:
        """The full render of ``rules`` (with its float32 twin if ``f32``); ``pin`` keeps it for good."""
        key = self._key(scene, rules)
        self.requested.add((key, "f64"))
        if pin:
            self._pinned.add(key)
        v = self._items.get(key)
        if v is None:
            v = self._trace(scene, rules.traced(), None)
            self._items[key] = v
            self._bytes += v.nbytes
            self._trim()
        else:
            self.hits += 1
            self._items.move_to_end(key)
        if f32:
            self.requested.add((key, "f32"))
            if v.f32_flips is None:
                before = v.nbytes
                v.f32_stored, v.f32_flips = self._f32_render(scene, v)
                if self._items.get(key) is v:  # still kept (not trimmed when it came in)
                    self._bytes += v.nbytes - before
                self._trim()
        return v

    def subset(self, scene: Scene, rules: Rules, idx: np.ndarray, keep: bool = False) -> Variant:
        """The candidate's colour on the pixels ``idx``: from a full render when one is cached, or when
        ``keep`` (a candidate other images will ask for too) or the image is small (a render's fixed
        cost, tracing Dr.Jit's graph in Python, ~20-30 ms, outweighs its rays up to ~512²: render it all
        and keep it); else only those pixels' rays, not kept."""
        key = self._key(scene, rules)
        self.requested.add((key, "f64"))
        n = scene.camera.width * scene.camera.height
        if keep:
            self._pinned.add(key)
        if key not in self._items and (keep or n <= FULL_RENDER_PIXELS):
            self.get(scene, rules)
        v = self._items.get(key)
        if v is not None:
            self.hits += 1
            return Variant(v.rules, v.color.reshape(-1, 3)[idx], v.shadow_ill.reshape(-1)[idx], idx)
        return self._trace(scene, rules.traced(), idx)

    def band(self, scene: Scene, rules: Rules, idx: np.ndarray) -> np.ndarray:
        """(N,) bool: primary rays of pixels ``idx`` whose hit/miss, closest-shape or inside/outside
        decision is within EPS_REL of flipping (minirt.reference.band). Computed once per pixel and camera
        rules, only for the pixels asked about: the search asks only where two candidates differ."""
        from minirt.reference import band

        key = (scene.digest, scene.source, scene.camera.width, scene.camera.height, _ray_key(rules))
        n = scene.camera.width * scene.camera.height
        known, flag = self._bands.setdefault(key, (np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)))
        todo = idx[~known[idx]]
        if todo.size:
            from minirt.model import camera

            # only these pixels' rays (each the same bits as in the whole image's): the search asks for a
            # few thousand of an 800² image, and whole images' rays per camera rule set were an eighth of it
            o, d = camera.primary_rays(scene, rules, todo)
            with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
                m = band.margins(scene, o, d)
            flag[todo] = m["margin"] < EPS_REL
            known[todo] = True
        return flag[idx]

    def _f32_render(self, scene: Scene, v: Variant) -> tuple[np.ndarray | None, np.ndarray]:
        """The same rules traced in float32, and the pixels where that image differs by more than a level:
        decisions that rounding flips anywhere in the ray tree (reflections, planes' shadows, self-shadowing
        offsets). A float32 tracer may draw either image at those pixels."""
        from minirt.errors import MinirtError

        try:
            c32 = self._trace(scene, v.rules, None, "f32").color
        except MinirtError:  # beyond float32's range: no float32 tracer could draw it; nothing to add
            return None, np.zeros(v.color.shape[:2], dtype=bool)
        a, b = bitmap.encode(v.color), bitmap.encode(c32)
        return c32.astype(np.float32), (np.abs(a.astype(np.int16) - b) > LEVEL_TOL).any(-1)

    def subset32(self, scene: Scene, rules: Rules, idx: np.ndarray) -> Variant | None:
        """The candidate traced in float32 on the pixels ``idx`` (None beyond float32's range)."""
        from minirt.errors import MinirtError

        self.requested.add((self._key(scene, rules), "f32"))
        try:
            return self._trace(scene, rules.traced(), idx, "f32")
        except MinirtError:
            return None

    def _trace(self, scene: Scene, rules: Rules, idx: np.ndarray | None, precision: str = "f64") -> Variant:
        import drjit as dr

        from minirt.reference.tracer import Tracer

        n = scene.camera.width * scene.camera.height
        self.renders += 1 if idx is None else idx.size / n
        tr = Tracer(scene, rules, precision=precision, runtime=True)
        o, d = tr.primary_rays(idx)  # full images and subsets alike: one kernel for both
        with dr.scoped_set_flag(dr.JitFlag.FastMath, False):
            color, levels = tr.trace(o, d, tree=True)
        m = levels[0].record.get("shadow_margin")
        # One trace kernel for both; the colour copied out of Dr.Jit's buffer, which then goes back to its
        # allocation cache for the next variant: a cache of views would hold every buffer, and each
        # render would write into fresh memory, page-faulting inside its kernels (in a check's process,
        # 0.25 -> 4.7 ms for the interleave of a 256^2 variant).
        c = tr._to_numpy3(color, also=() if m is None else (m,)).copy()
        sill = np.zeros(c.shape[0], dtype=bool) if m is None else np.asarray(m) < EPS_REL * _scale(scene)
        if idx is None:
            h, w = scene.camera.height, scene.camera.width
            return Variant(rules, c.reshape(h, w, 3), sill.reshape(h, w))
        return Variant(rules, c, sill, idx)

    def _trim(self) -> None:
        if self._bytes <= self.max_bytes:
            return
        for key in [k for k in self._items if k not in self._pinned]:  # oldest first
            if self._bytes <= self.max_bytes or len(self._items) <= 1:
                break
            self._bytes -= self._items.pop(key).nbytes

    @property
    def nbytes(self) -> int:
        """The kept renders' bytes: a running sum (summing over the cache at every insertion made a long
        session's check runs quadratic in its size)."""
        return self._bytes


def _ray_key(rules: Rules) -> tuple:
    return (rules.ray_origin, rules.pixel_sample, tuple(rules.pixel_shift))


def _scale(scene: Scene) -> float:
    """The scene's working size: where its balls, light and camera are (planes are unbounded)."""
    s = [1.0, scene.camera.distance, *map(abs, scene.light.position)]
    for b in scene.shapes:
        if isinstance(b, Ball):
            s.append(max(map(abs, b.center)) + b.radius)
    return max(s)


# ---------------------------------------------------------------------------------------------
@dataclass
class Target:
    """The image to explain, as stored (any layout), 8-bit levels or floats, three channels."""

    pixels: np.ndarray  # (rows, columns, 3) uint8 or float32
    is_float: bool
    name: str = ""
    _layouts: dict = field(default_factory=dict, repr=False)

    @property
    def shape(self) -> tuple[int, int]:
        return self.pixels.shape[0], self.pixels.shape[1]

    def in_layout(self, rules: Rules) -> np.ndarray:
        """The image brought back to the scene's layout under the candidate's layout rules (int16
        levels, or float32 clamped to [0, 1]); computed once per layout."""
        key = (rules.rows, rules.channels, rules.transpose)
        if key not in self._layouts:
            img = bitmap.undo_layout(self.pixels, **bitmap.layout_of(rules))
            self._layouts[key] = np.clip(img, 0.0, 1.0) if self.is_float else img.astype(np.int16)
        return self._layouts[key]

    def difference(self, color: np.ndarray, rules: Rules, idx: np.ndarray | None = None) -> np.ndarray | None:
        """Per pixel, the largest channel difference (levels, or float units) between the image and the
        colour written under ``rules``' output rules; None when the layout does not fit the size.
        ``color`` is (H, W, 3), or (N, 3) for the pixels ``idx``."""
        img = self.in_layout(rules)
        h, w = (color.shape[0], color.shape[1]) if idx is None else (None, None)
        if idx is None and img.shape[:2] != (h, w):
            return None
        if idx is not None:
            if img.shape[:2] != self._model_shape:
                return None
            img = img.reshape(-1, 3)[idx]
        if self.is_float:
            return np.abs(img - bitmap.transfer(color, rules.gamma)).max(-1)
        enc = bitmap.encode(color, rules.encoding, rules.gamma)
        return np.abs(enc.astype(np.int16) - img).max(-1)

    _model_shape: tuple[int, int] = (0, 0)

    def score(self, d: np.ndarray, keep: np.ndarray | None = None) -> tuple[int, int]:
        """(pixels beyond tolerance, pixels exactly one level off), among ``keep``. The second breaks
        ties: encodings differ by at most one level, so only exact matches tell them apart, and a
        float32 tracer lands a level off only where a value sits on a rounding step (rare)."""
        if keep is not None:
            d = d[keep]
        if self.is_float:
            return int((d > FLOAT_TOL).sum()), 0
        return int((d > LEVEL_TOL).sum()), int((d == 1).sum())

    def off(self, d: np.ndarray) -> np.ndarray:
        """Pixels that are not an exact match: any level off (8-bit), beyond FLOAT_TOL (float)."""
        return d > FLOAT_TOL if self.is_float else d >= 1

    def beyond(self, d: np.ndarray) -> np.ndarray:
        """Pixels beyond tolerance: more than one level (8-bit), more than FLOAT_TOL (float)."""
        return d > (FLOAT_TOL if self.is_float else LEVEL_TOL)


# ---------------------------------------------------------------------------------------------
@dataclass
class Explained:
    rule: str
    value: str
    pixels: int
    mask: np.ndarray = field(repr=False)


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

    @property
    def changed(self) -> dict[str, str]:
        return {n: rules_mod.format_rule_value(n, getattr(self.best, n)) for n in self.given.differs(self.best)}

    @property
    def as_given_pixels(self) -> int:
        return int(self.as_given_mask.sum())

    @property
    def mismatch_pixels(self) -> int:
        return int(self.best_mask.sum())


def _valid(r: Rules) -> bool:
    """A rule set the tracer accepts (the one cross-rule constraint: offset_along = "ray" needs a number)."""
    return not rules_mod.validate_model_table("exercise", r.as_dict())


def _moot(scene: Scene, rules: Rules) -> set[str]:
    """Rules that provably change no pixel of this scene (minirt.model.effects): the exponent and the
    clamp without lit terms, the background when it is black, offsets without secondary rays."""
    fx = effects(scene, rules)
    out = set()
    if not fx.specular:
        out.add("specular_exponent")
    if not (fx.diffuse or fx.specular):
        out.add("clamp")
    if not any(scene.background):
        out.add("background")
    if not (fx.shadows or fx.reflection):
        out |= {"offset", "offset_along"}
    return out


def _moves(current: Rules, names: tuple[str, ...], moot: set[str] = frozenset()) -> list[Rules]:
    out = []
    for name in names:
        if name in moot:
            continue
        for v in rules_mod.values(name):
            if v != getattr(current, name):
                cand = replace(current, **{name: v})
                if _valid(cand):
                    out.append(cand)
    return out


def _profile_moves(current: Rules) -> list[Rules]:
    """Whole profiles (their traced rules, the current output rules): a tracer written to another
    edition of the exercise differs in many rules at once, more than single steps find in order."""
    out = []
    for p in rules_mod.PROFILES.values():
        cand = replace(current, **{n: getattr(p, n) for n in rules_mod.TRACE_RULES})
        if cand != current and _valid(cand):
            out.append(cand)
    return out


# Candidates are first scored on a subset of pixels: every pixel the current rules get wrong, and a
# fixed stride of the ones they get right (SAMPLE of them, at least), whose breakages are scaled up.
# The best candidate is then rendered in full and accepted only if it really gains; a candidate that
# breaks a thin feature the stride missed is caught there.
SAMPLE = 4096
VERIFY = 3  # candidates verified in full per step before the search gives up
EXPONENT_SEARCH = 256  # the specular exponents a search considers (rules allow up to 1024)


@dataclass
class _Subset:
    idx: np.ndarray  # pixels: the wrong ones' stride, then the right ones'
    n_wrong: int
    w_weight: float
    r_weight: float
    before: np.ndarray | None = None  # the current rules' class of each


class _Search:
    def __init__(self, scene: Scene, target: Target, cache: VariantCache, outputs: bool = True):
        self.outputs = outputs  # False: the image's output rules are known (the start's); never searched
        self.scene, self.target, self.cache = scene, target, cache
        self.steps: list[dict[str, Any]] = []
        self._exponents: dict[Rules, int] = {}
        target._model_shape = (scene.camera.height, scene.camera.width)

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
        d, v = self.full(rules)
        self.cache.get(self.scene, rules, f32=True)
        if d is not None and v.f32_color is not None:
            d = np.minimum(d, self.target.difference(v.f32_color, rules))
        return d, v

    def compare(self, a: Rules, b: Rules) -> tuple[int, int] | None:
        """Exact gain of b over a on every pixel: (beyond tolerance, one level off) that b fixes minus
        those it breaks, each matched by its float64 or float32 image. A pixel ill-conditioned in either
        never counts: it is looked at only where the two differ, as elsewhere it adds the same to both."""
        (da, va), (db, vb) = self.either(a), self.either(b)
        if da is None or db is None:
            return None if db is None else (1 << 40, 0)
        differ = np.flatnonzero((self._cls(da) != self._cls(db)).reshape(-1))
        keep = ~(self.ill_at(a, va, differ) | self.ill_at(b, vb, differ) | self.flips(a)[differ])
        sa = self.target.score(da.reshape(-1)[differ], keep)
        sb = self.target.score(db.reshape(-1)[differ], keep)
        return sa[0] - sb[0], sa[1] - sb[1]

    def flips(self, rules: Rules) -> np.ndarray:
        """(H·W,) pixels a float32 render of these rules draws otherwise: a float32 tracer's rounding, not
        a rule, decides them (self-shadowing acne under a fixed offset, reflected edges). The current
        rules' flips are left out while searching, so a student's float32 acne never reads as a rule."""
        return self.cache.get(self.scene, rules, f32=True).f32_flips.reshape(-1)

    def _cls(self, d: np.ndarray) -> np.ndarray:
        """Per pixel: 0 exact, 1 one level off, 2 beyond tolerance."""
        return np.where(self.target.beyond(d), 2, np.where(self.target.off(d), 1, 0)).astype(np.int8)

    def run(self, start: Rules) -> Rules:
        """Descend; where pixels stay unexplained, descend again from the start with each rule the
        answer changed forbidden in the first step, and keep what explains most. A greedy step can take
        a rule that imitates the right one (a high exponent dims the wrong-side highlight that clamping
        removes) and then stall; the restart lets the right one go first."""
        first = self._best_output(start)
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
            return self.target._model_shape[0] * self.target._model_shape[1]
        where = np.flatnonzero(self.target.beyond(d).reshape(-1))
        return int((~(self.ill_at(rules, v, where) | self.flips(rules)[where])).sum())

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
            cls = self._cls(dc).reshape(-1)
            wrong = np.flatnonzero(cls > 0)
            if wrong.size == 0:
                return current
            right = np.flatnonzero(cls == 0)
            wrong_s = wrong[:: max(1, wrong.size // (4 * SAMPLE))]
            right_s = right[:: max(1, right.size // SAMPLE)]
            sub = _Subset(
                idx=np.concatenate([wrong_s, right_s]),
                n_wrong=wrong_s.size,
                w_weight=wrong.size / wrong_s.size,
                r_weight=right.size / max(1, right_s.size),
            )
            sub.before = cls[sub.idx]
            flips = self.flips(current)
            moot = _moot(self.scene, current)
            names = rules_mod.TRACE_RULES + (rules_mod.OUTPUT_RULES if self.outputs else ())
            singles = _moves(current, names, moot)
            if "specular_exponent" not in moot:  # beside the listed values, the best integer
                e = self._best_exponent(current)
                if e != current.specular_exponent and e not in rules_mod.values("specular_exponent"):
                    singles.append(replace(current, specular_exponent=e))
            singles += _profile_moves(current)
            singles = [c for c in singles if c not in seen]
            if tabu:
                singles = [c for c in singles if tabu not in current.differs(c)]
                tabu = None
            better = self._step(start, current, vc, sub, flips, singles, seen)
            if better is None and self._residual(current):  # not for pixels only a level off
                better = self._step(start, current, vc, sub, flips, self._paired(current, singles, seen), seen)
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
        for k, c in enumerate(cands):
            est = self._estimate(start, current, vc, c, sub.idx)
            traced = est is None
            if traced:
                est = self._traced(start, current, vc, c, sub.idx)
            e = self._gain_on(sub, current, vc, c, *est, flips)
            if e is not None and e[0] == 0 and c.traced() != current.traced():
                # No effect in float64 here: a rule a float32 tracer shows only through rounding (an offset
                # along the ray, the far root from inside a ball), seen in its self-shadowing acne.
                v32 = self.cache.subset32(self.scene, c, sub.idx)
                if v32 is not None:
                    e = self._gain_on(sub, current, vc, c, *est, flips, color2=v32.color)
            if e is not None and e > (0, 0):
                scored.append([(-e[0], -e[1]), len(start.differs(c)), k, c, traced])
        scored.sort(key=lambda s: s[:3])
        for _, _, _, c, _ in scored[:VERIFY]:
            g = self.compare(current, c)
            if g is not None and g > (0, 0):
                self.steps.append({"rules": current.differs(c), "gain": g[0], "gain_one_level": g[1]})
                refit = self._best_output(c)
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
            refit = self._best_output(c)
            if refit != c and refit not in seen and refit not in out:
                out.append(refit)
        return out

    def _one_step(self, start: Rules, name: str, value: Any) -> Variant | None:
        """The full render of the scene's own rules with one rule changed (shared across images)."""
        r = start if value == getattr(start, name) else replace(start, **{name: value})
        return self.cache.get(self.scene, r, pin=True) if _valid(r) else None

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
        v = self.cache.subset(self.scene, c, idx, keep=len(start.differs(c)) == 1)
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
        before, after = sub.before, self._cls(d)
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

    def _best_output(self, rules: Rules) -> Rules:
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
        best, best_key = rules, None
        for enc in encs:
            for gam in rules_mod.values("gamma"):
                coded = _coded(color, replace(rules, encoding=enc, gamma=gam), self.target.is_float)
                for tr in (False, True):
                    for rows in rules_mod.values("rows"):
                        for ch in rules_mod.values("channels"):
                            cand = replace(rules, encoding=enc, gamma=gam, transpose=tr, rows=rows, channels=ch)
                            img = self.target.in_layout(cand)
                            if img.shape[:2] != self.target._model_shape:
                                continue
                            d = np.abs(coded - img.reshape(-1, 3)[at]).max(-1)
                            key = (*self.target.score(d, ~sill), len(rules.differs(cand)))
                            if best_key is None or key < best_key:
                                best, best_key = cand, key
        return best

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
        n = self.target._model_shape[0] * self.target._model_shape[1]
        at = np.arange(0, n, max(1, n // (4 * SAMPLE)))
        memo: dict[int, float] = {}

        def l1(x: int) -> float:
            if x not in memo:
                r = replace(rules, specular_exponent=x)
                v = self.cache.subset(self.scene, r, at)
                d = self.target.difference(v.color, r, at)
                memo[x] = math.inf if d is None else float(d[~v.shadow_ill].sum())
            return memo[x]

        found = []
        for parity in (0, 1):
            xs = [x for x in range(1, EXPONENT_SEARCH + 1) if x % 2 == parity]
            lo, hi = 0, len(xs) - 1
            while hi - lo > 2:
                m1, m2 = lo + (hi - lo) // 3, hi - (hi - lo) // 3
                if l1(xs[m1]) <= l1(xs[m2]):
                    hi = m2
                else:
                    lo = m1
            found.append(min(xs[lo : hi + 1], key=lambda x: (l1(x), x)))
        best = min(found, key=lambda x: (l1(x), x))
        self._exponents[key] = best
        return best

    def final_mask(self, rules: Rules, f32_of: list[Rules]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(beyond-tolerance mask, off-by-any mask, ill mask) of ``rules`` on every pixel, leaving out
        pixels ill-conditioned in it (band, shadows, float32 flips) or in the renders ``f32_of``."""
        shape = self.target._model_shape
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


def diagnose(
    scene: Scene,
    given: Rules,
    target: Target,
    cache: VariantCache | None = None,
    alternatives: bool = True,
    outputs: bool = True,
) -> Diagnosis:
    """Search rule space for the setting that best reproduces ``target`` (see the module's docstring).
    ``alternatives=False`` skips the list of settings the scene cannot tell apart from the answer
    (about half the time of a diagnosis; ``check`` does not show it). ``outputs=False`` keeps ``given``'s
    output rules: for an image whose encoding and layout are known (an oracle's ``color8()``)."""
    cache = cache or VariantCache()
    cache.requested = set()
    search = _Search(scene, target, cache, outputs)
    best = search.run(given)
    pair = [given, best]
    mg, _, ill_g = search.final_mask(given, pair)
    mb, off_b, ill_b = search.final_mask(best, pair)
    shape = search.target._model_shape
    explained = []
    for name in given.differs(best):
        back = replace(best, **{name: getattr(given, name)})
        if not _valid(back):
            back = replace(best, **{n: getattr(given, n) for n in _coupled(name)})
        _, off_back, _ = search.final_mask(back, [])
        gained = off_back & ~off_b & ~ill_b
        explained.append(
            Explained(name, rules_mod.format_rule_value(name, getattr(best, name)), int(gained.sum()), gained)
        )
    explained.sort(key=lambda e: (-e.pixels, e.rule))
    return Diagnosis(
        given=given,
        best=best,
        pixels=shape[0] * shape[1],
        as_given_mask=mg,
        best_mask=mb,
        ill=ill_g | ill_b,
        explained=explained,
        indistinguishable=indistinguishable(scene, best, cache, target) if alternatives else [],
        given_color=cache.get(scene, given).color,
        best_color=cache.get(scene, best).color,
        steps=search.steps,
        renders=len(cache.requested),
    )


def _coupled(name: str) -> tuple[str, ...]:
    """Rules that are only valid together (reverting one alone would be an invalid rule set)."""
    if name in ("offset", "offset_along"):
        return ("offset", "offset_along")
    return (name,)


def indistinguishable(scene: Scene, best: Rules, cache: VariantCache, target: Target) -> list[dict[str, Any]]:
    """Single-rule changes of ``best`` that this scene cannot tell apart from it: written the same way,
    their image equals best's on every pixel that is not ill-conditioned. Each with a bundled grading
    scene that does tell them apart (None when none does). A change that differs on a stride of pixels
    is told apart without a full render. It depends on the scene and the answer only, not on the image:
    a class's images with the same answer share one list (kept in the cache)."""
    key = (*VariantCache._key(scene, best), best, target.is_float)
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
    coded = _coded(vb.color.reshape(-1, 3), best, target.is_float)
    out = []
    moot = _moot(scene, best)
    for cand in _moves(best, rules_mod.TRACE_RULES):
        (name,) = best.differs(cand)
        if name in moot or _distinct(scene, best, cand, coded, stride, cache, target.is_float) == 0:
            value = getattr(cand, name)
            out.append(
                {
                    "rule": name,
                    "value": rules_mod.format_rule_value(name, value),
                    "as": rules_mod.format_rule_value(name, getattr(best, name)),
                    "scene_that_tells": tells_apart(name, getattr(best, name), value, cache),
                }
            )
            if out[-1]["scene_that_tells"] is None:
                out[-1]["why"] = why_same(name, getattr(best, name), value)
            if out[-1]["scene_that_tells"] is None:
                out[-1]["why"] = why_same(name, getattr(best, name), value)
    return out


def _coded(color: np.ndarray, rules: Rules, is_float: bool) -> np.ndarray:
    if is_float:
        return bitmap.transfer(color, rules.gamma)
    return bitmap.encode(color, rules.encoding, rules.gamma).astype(np.int16)


def _distinct(
    scene: Scene, a: Rules, b: Rules, coded_a: np.ndarray, stride: np.ndarray, cache: VariantCache, is_float: bool
) -> int:
    """Pixels (not ill-conditioned in either) where b's image, written as a's output rules say, differs
    from a's (``coded_a``, flat): 0 means the two cannot be told apart. Only a count below the stride's
    says 0 is rendered in full."""
    tol = FLOAT_TOL if is_float else 0
    vs = cache.subset(scene, b, stride)
    d = np.abs(_coded(vs.color, a, is_float) - coded_a[stride]).max(-1) > tol
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
    d = np.abs(_coded(vb.color.reshape(-1, 3), a, is_float) - coded_a).max(-1) > tol
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
SAME_UNDER_EXERCISE = {("clamp", frozenset({True, "specular"})): "eth2014"}


def tells_apart(name: str, a: Any, b: Any, cache: VariantCache | None = None, min_pixels: int = 50) -> str | None:
    """The first bundled grading scene in which rule ``name`` = a and = b differ on >= min_pixels pixels
    (8-bit, as stored, ill-conditioned pixels left out), under the scene's own rules."""
    for stem in GRADING_SET:
        if distinct_pixels(stem, name, a, b, cache) >= min_pixels:
            return stem
    return None


def why_same(name: str, a: Any, b: Any) -> str:
    """Why no bundled scene tells two values apart (for the indistinguishable list)."""
    if (name, frozenset({a, b})) in SAME_UNDER_EXERCISE:
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
    from minirt.errors import SceneError
    from minirt.model.bundled import bundled_scene

    cache = cache or VariantCache()
    try:
        sc = bundled_scene(stem).with_overrides(samples=1)
    except SceneError:  # a bundled scene missing from this install: ask the others
        return 0
    base = rules_mod.resolve(sc, profile)
    ra, rb = _make_valid(replace(base, **{name: a})), _make_valid(replace(base, **{name: b}))
    va, vb = cache.get(sc, ra), cache.get(sc, rb)
    ia, ib = bitmap.bitmap(va.color, ra), bitmap.bitmap(vb.color, rb)
    if ia.shape != ib.shape:
        return ia.shape[0] * ia.shape[1]
    differ = (ia != ib).any(-1)
    if ra.transpose != rb.transpose or ra.rows != rb.rows or ra.channels != rb.channels:
        return int(differ.sum())  # the layouts differ: compared as stored, nothing to leave out
    where = np.flatnonzero(bitmap.undo_layout(differ[..., None], **bitmap.layout_of(ra))[..., 0].reshape(-1))
    ill = va.shadow_ill.reshape(-1)[where] | vb.shadow_ill.reshape(-1)[where]
    ill |= cache.band(sc, ra, where) | cache.band(sc, rb, where)
    return int((~ill).sum())


def _make_valid(r: Rules) -> Rules:
    """offset_along = "ray" with the error-bound offset is no rule set: use the 2014 edition's 1e-3."""
    if not _valid(r) and r.offset == "error-bound":
        return replace(r, offset=1e-3)
    return r
