"""The candidates' renders: ``Variant`` (one rule set's colour and ill-conditioned pixels) and the
``VariantCache`` that keeps them.

Renders are cached per (scene, size, traced rules) in a ``VariantCache`` that a class run shares
across students, so each variant is traced once however many images are graded.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from minirt.diagnose.target import LEVEL_TOL
from minirt.model import bitmap
from minirt.model.rules import Rules
from minirt.model.scene import Ball, Scene

# A float32 tracer's ray directions, roots and hit points carry relative errors of order gamma(n) =
# n·2^-24 for the n ≈ 10-30 chained roundings of a ray's set-up and intersection; 2^6 u = 3.8e-6
# covers n up to 64. A decision whose relative margin is below it may go either way in such a tracer.
EPS_REL = 2.0**-24 * 64


# Images up to this many pixels render every candidate in full (and keep it for the next image) -- divided by
# balls / FULL_RENDER_BALLS beyond that many balls: a ray's cost grows with the balls it passes, and a
# candidate traced in full at 128² took 45 ms with 1,024 balls and 190 ms with 10,000 (against ~25 ms for a
# 512² image of a few balls), while the search asks about a few hundred pixels (a 10,000-ball check's rule
# diagnosis: 42 s in full renders).
FULL_RENDER_PIXELS = 512 * 512
FULL_RENDER_BALLS = 16


def full_render_pixels(scene: Scene) -> float:
    """The largest image whose candidates are rendered in full (``FULL_RENDER_PIXELS``, fewer with many balls)."""
    balls = sum(isinstance(s, Ball) for s in scene.shapes)
    return FULL_RENDER_PIXELS * min(1.0, FULL_RENDER_BALLS / max(balls, 1))


# From this many rays a band is computed in parts on threads (a single image's search only): below it a
# part's fixed cost (rays, the scene's shapes set up again, a thread) is not repaid -- the search's own
# asks are a few thousand rays, the final masks' hundreds of thousands.
BAND_SPLIT_RAYS = 1 << 16
# How far apart a float64 and a float32 colour channel must be before their levels can differ by more than
# LEVEL_TOL (``VariantCache._f32_twin``): LEVEL_TOL / 255, less 1 % for the encodings' roundings.
TWIN_GAP = 0.99 * LEVEL_TOL / 255
# Pixels of a band request from which the camera's filter kernel (minirt.reference.band_filter) is run, and
# then read for every request: ~0.03 CPU-s for an 800² image's rays, what NumPy's margins cost for ~40,000.
BAND_FILTER_RAYS = 1 << 14

# Candidates traced together (``VariantCache.prefetch``): one kernel launch for many rule sets, each ray its
# candidate's rules (minirt.reference.values.Candidates). A trace's fixed cost is Python building Dr.Jit's
# graph, ~8-11 ms for the bundled scenes whatever the rays: 19 candidates on 1,024 pixels of rules.toml took
# 150 ms one by one and 13 ms as one batch, bit for bit the same colours (tests/diagnose/test_batch.py). A
# batch holds at most this many rays (its colours ~48 MB), more candidates go to another batch.
BATCH_RAYS = 1 << 21
# A batch's kernel reads every rule a search varies per ray (minirt.reference.values: PER_RAY, SWITCHES);
# ``Divergent`` splits a batch on a rule the kernel turns out to compile in.


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

    def __init__(self, max_bytes: int = 2 << 30, share: bool = True):
        self.max_bytes = max_bytes
        # share: other images of the same scenes will be graded with this cache (a class), so a search renders
        # the scene's one-step variants in full and keeps them; a single image's search traces them only on
        # its subset of pixels (the same colours there, a fraction of the rays and copies)
        self.share = share
        self._items: OrderedDict[tuple, Variant] = OrderedDict()
        self._bytes = 0  # the kept variants' nbytes summed, kept up to date as they come, grow and go
        self._pinned: set[tuple] = set()
        self._bands: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}
        self._near: dict[tuple, np.ndarray | None] = {}  # ``_near_band``'s, per camera
        self._hits: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}
        self.alternatives: dict[tuple, tuple[list[dict[str, Any]], set]] = {}  # see explain.indistinguishable
        self._batched: dict[tuple, Variant] = {}  # ``prefetch``'s subsets, until the next prefetch
        self._batched32: dict[tuple, Variant] = {}  # ``prefetch32``'s, until the next prefetch32
        self.requested: set[tuple] = set()
        self.renders = 0  # rays traced, in units of whole images
        self.hits = 0

    @staticmethod
    def key(scene: Scene, rules: Rules) -> tuple:
        """What a render depends on: the scene (its digest and source), its size and the traced rules."""
        return (scene.digest, scene.source, scene.camera.width, scene.camera.height, rules.traced())

    def has(self, scene: Scene, rules: Rules) -> bool:
        """Whether the full render of ``rules`` is kept."""
        return self.key(scene, rules) in self._items

    def get(self, scene: Scene, rules: Rules, f32: bool = False, pin: bool = False) -> Variant:
        """The full render of ``rules`` (with its float32 twin if ``f32``); ``pin`` keeps it for good."""
        key = self.key(scene, rules)
        self.requested.add((key, "f64"))
        if pin:
            self._pinned.add(key)
        v = self._items.get(key)
        if v is None:
            v = self._trace(scene, rules.traced(), None)
            self._keep(key, v)
            self._trim()
        else:
            self.hits += 1
            self._items.move_to_end(key)
        if f32:
            self.requested.add((key, "f32"))
            if v.f32_flips is None:
                self._set_twin(key, v, self._f32_render(scene, v))
                self._trim()
        return v

    def _keep(self, key: tuple, v: Variant) -> None:
        """Keep a full render, its bytes counted (the caller trims)."""
        self._items[key] = v
        self._bytes += v.nbytes

    def _keep_whole(self, scene: Scene, batch: list[Variant]) -> None:
        """A batch's renders of every pixel kept as ``get`` keeps its own: (H, W) images, the same bits."""
        h, w = scene.camera.height, scene.camera.width
        for v in batch:
            self._keep(self.key(scene, v.rules), Variant(v.rules, v.color.reshape(h, w, 3), v.shadow_ill.reshape(h, w)))
        self._trim()

    def _set_twin(self, key: tuple, v: Variant, twin: tuple[np.ndarray | None, np.ndarray]) -> None:
        """A full render's float32 image and flips (``_f32_twin``), its bytes counted if it is still kept."""
        before = v.nbytes
        v.f32_stored, v.f32_flips = twin
        if self._items.get(key) is v:  # still kept (not trimmed when it came in)
            self._bytes += v.nbytes - before

    def subset(self, scene: Scene, rules: Rules, idx: np.ndarray, keep: bool = False, probe: bool = False) -> Variant:
        """The candidate's colour on the pixels ``idx``: from a full render when one is cached, or when
        ``keep`` (a candidate other images will ask for too) or the image is small (a render's fixed
        cost, tracing Dr.Jit's graph in Python, ~20-30 ms, outweighs its rays up to ~512²: render it all
        and keep it); else only those pixels' rays, not kept. ``probe``: one of the many values a
        one-dimensional search tries (the specular exponent, the offset), of which it keeps one: traced on
        ``idx`` alone unless cached or shared (a class's images ask for the same) -- a full 256² render cost
        ~4 ms against ~1.5 ms for a quarter of its pixels, and a check's search tried ~300 such values."""
        key = self.key(scene, rules)
        self.requested.add((key, "f64"))
        n = scene.camera.width * scene.camera.height
        if keep:
            self._pinned.add(key)
        whole = n <= full_render_pixels(scene) and (self.share or not probe)
        if key not in self._items and (keep or whole):
            self.get(scene, rules)
        v = self._items.get(key)
        if v is not None:
            self.hits += 1
            return Variant(v.rules, v.color.reshape(-1, 3)[idx], v.shadow_ill.reshape(-1)[idx], idx)
        if self._batched:
            v = self._batched.get((key, _digest(idx)))
            if v is not None:
                return v
        return self._trace(scene, rules.traced(), idx)

    def prefetch(self, scene: Scene, candidates: list[Rules], idx: np.ndarray, probe: bool = False) -> None:
        """Trace together the candidates that ``subset(scene, r, idx, probe=probe)`` would trace one by one
        (not cached): the next ``subset`` calls for them on these pixels read the batch's colours, kept until
        the next prefetch (a search step's, one_of's candidates). Where ``subset`` renders whole images (a
        small image), the batch is of whole images, kept in the cache as ``get`` keeps its renders: a small
        image's candidates cost little but their graph, ~20-30 ms each when traced one by one."""
        self._batched = {}
        n = scene.camera.width * scene.camera.height
        whole = n <= full_render_pixels(scene) and (self.share or not probe)
        todo, seen = [], set()
        for r in candidates:
            key = self.key(scene, r)
            if key in self._items or key in seen:
                continue
            seen.add(key)
            todo.append(r.traced())
        if len(todo) < 2:
            return
        if whole:
            self._keep_whole(scene, self._trace_batch(scene, todo, np.arange(n)))  # none kept yet (todo)
            return
        token = _digest(idx)
        for v in self._trace_batch(scene, todo, idx):
            self._batched[(self.key(scene, v.rules), token)] = v

    def prefetch_whole(self, scene: Scene, candidates: list[Rules], f32: bool = False) -> None:
        """The full renders ``get(scene, r, f32=f32)`` would make one by one, traced together (whole images, in
        batches of at most ``BATCH_RAYS`` rays, the cache trimmed after each) and kept as ``get`` keeps them,
        each with the bits of its render alone: a joint diagnosis scores every candidate on every image of a
        suite, ~400 renders of a 96² scene, where a render's graph (~10-20 ms) cost more than its rays. Only
        for images rendered whole anyway (``full_render_pixels``); ``requested`` is not touched: what a
        diagnosis looked at is what it ``get``s."""
        from minirt.errors import MinirtError

        h, w = scene.camera.height, scene.camera.width
        if w * h > full_render_pixels(scene):  # a large image's renders cost their rays: ``get`` makes them
            return
        every, per = np.arange(w * h), max(2, BATCH_RAYS // (w * h))  # a kernel's worth at a time, then trimmed
        todo = list({r.traced(): None for r in candidates if not self.has(scene, r)})
        for part in (todo[i : i + per] for i in range(0, len(todo) if len(todo) > 1 else 0, per)):
            self._keep_whole(scene, self._trace_batch(scene, part, every))
        kept = [self._items.get(self.key(scene, r)) for r in candidates] if f32 else []
        twins = list({v.rules: v for v in kept if v is not None and v.f32_flips is None}.values())
        for part in (twins[i : i + per] for i in range(0, len(twins) if len(twins) > 1 else 0, per)):
            try:
                got = self._trace_batch(scene, [v.rules for v in part], every, "f32")
            except MinirtError:  # beyond float32's range: ``get`` says so for each
                return
            for v, t in zip(part, got, strict=True):
                self._set_twin(self.key(scene, v.rules), v, self._f32_twin(v, t.color.reshape(h, w, 3)))
            self._trim()

    def prefetch32(self, scene: Scene, candidates: list[Rules], idx: np.ndarray) -> None:
        """Trace together, in float32, the candidates that ``subset32(scene, r, idx)`` would trace one by one:
        a search step's float32 twins (the candidates whose float64 image gains nothing). Kept until the next
        prefetch32; none when the scene is beyond float32's range (``subset32`` says so for each)."""
        from minirt.errors import MinirtError

        self._batched32 = {}
        todo = list({r.traced(): None for r in candidates})
        if len(todo) < 2:
            return
        try:
            got = self._trace_batch(scene, todo, idx, "f32")
        except MinirtError:
            return
        token = _digest(idx)
        for v in got:
            self._batched32[(self.key(scene, v.rules), token)] = v

    def _trace_batch(self, scene: Scene, todo: list[Rules], idx: np.ndarray, precision: str = "f64") -> list[Variant]:
        """``_trace`` of each candidate on ``idx``, in batches of at most ``BATCH_RAYS`` rays (split where
        their rules keep them apart: ``Divergent``)."""
        from minirt.reference.values import Divergent

        out: list[Variant] = []
        per = max(1, BATCH_RAYS // max(1, idx.size))
        stack = [todo[i : i + per] for i in range(0, len(todo), per)]
        while stack:
            group = stack.pop(0)
            if len(group) == 1:
                out.append(self._trace(scene, group[0], idx, precision))
                continue
            try:
                out += self._trace_many(scene, group, idx, precision)
            except Divergent as e:  # a rule the kernel compiles in: split on it
                parts: dict[Any, list[Rules]] = {}
                for r in group:
                    parts.setdefault(repr(e.fn(r)), []).append(r)
                stack += list(parts.values())
        return out

    def _trace_many(
        self, scene: Scene, group: list[Rules], idx: np.ndarray | None, precision: str = "f64"
    ) -> list[Variant]:
        """The candidates traced in one kernel on the pixels ``idx`` (None: every pixel): a batch's kernel
        (each ray its candidate's rules), one for any number of candidates -- a single render too."""
        import drjit as dr

        from minirt.reference.tracer import Tracer

        n = scene.camera.width * scene.camera.height
        self.renders += len(group) * (1 if idx is None else idx.size / n)
        # looped: a whole image traces in the kernel of its subsets (one LLVM compile fewer, a few per cent
        # of its run time; the same bits, tested)
        tr = Tracer(scene, group, precision=precision, runtime=True, looped=True)
        # One ray is traced twice: Dr.Jit folds arrays of width 1 into literals, and the kernel of one such
        # ray through two mirror planes (scenes/suite/offset_coarse.toml, one bounce) failed LLVM's verifier
        # ("Instruction does not dominate all uses"), which aborts the process.
        one = idx is not None and idx.size == 1 and len(group) == 1
        o, d = tr.primary_rays(np.repeat(idx, 2) if one else idx)  # the candidates' rays one after the other
        with dr.scoped_set_flag(dr.JitFlag.FastMath, False):
            color, levels = tr.trace(o, d, tree=True, path="fused")
        m = levels[0].record.get("shadow_margin")
        # The colour copied out of Dr.Jit's buffer, which then goes back to its allocation cache for the
        # next variant: a cache of views would hold every buffer, and each render would write into fresh
        # memory, page-faulting inside its kernels (in a check's process, 0.25 -> 4.7 ms for the
        # interleave of a 256^2 variant).
        c = tr.to_numpy3(color, also=() if m is None else (m,))
        sill = np.zeros(c.shape[0], dtype=bool) if m is None else np.asarray(m) < EPS_REL * _scale(scene)
        if one:
            c, sill = c[:1], sill[:1]
        if idx is None:
            h, w = scene.camera.height, scene.camera.width
            return [Variant(group[0], c.copy().reshape(h, w, 3), sill.copy().reshape(h, w))]
        k = idx.size
        part = [slice(i * k, (i + 1) * k) for i in range(len(group))]
        return [Variant(r, c[s].copy(), sill[s].copy(), idx) for r, s in zip(group, part, strict=True)]

    def band(self, scene: Scene, rules: Rules, idx: np.ndarray) -> np.ndarray:
        """(N,) bool: primary rays of pixels ``idx`` whose hit/miss, closest-shape or inside/outside
        decision is within EPS_REL of flipping (minirt.reference.band). Computed once per pixel and camera
        rules, only for the pixels asked about: the search asks only where two candidates differ."""
        from minirt.reference import band

        key = (scene.digest, scene.source, scene.camera.width, scene.camera.height, _ray_key(rules))
        n = scene.camera.width * scene.camera.height
        known, flag = self._bands.setdefault(key, (np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)))
        todo = idx[~known[idx]]
        if todo.size >= BAND_FILTER_RAYS or key in self._near:  # exact margins only where the kernel's may be low
            near = self._near_band(scene, rules, key)
            if near is not None:  # the rest's flags stay False, as they were made
                known[todo] = True
                todo = todo[near[todo]]
        if todo.size:
            from minirt.model import camera

            # only these pixels' rays (each the same bits as in the whole image's): the search asks for a
            # few thousand of an 800² image, and whole images' rays per camera rule set were an eighth of it
            def margin(part: np.ndarray) -> np.ndarray:
                o, d = camera.primary_rays(scene, rules, part)
                with np.errstate(invalid="ignore", divide="ignore", over="ignore"):  # per thread: set in each
                    return band.margins(scene, o, d, bound=EPS_REL)["margin"]  # exact below EPS_REL: the ball tree

            # A single image's final masks ask for most of the image's pixels under two cameras (~0.6 s of an
            # 800² grade): its parts go to threads (NumPy lets go of the GIL in its loops), each ray's margin
            # the same bits in any part. A class's worker processes fill the cores already: one part there.
            k = 1 if self.share or todo.size < BAND_SPLIT_RAYS else _threads()
            if k == 1:
                m = margin(todo)
            else:
                from concurrent.futures import ThreadPoolExecutor

                with ThreadPoolExecutor(k) as pool:
                    m = np.concatenate(list(pool.map(margin, np.array_split(todo, k))))
            flag[todo] = m < EPS_REL
            known[todo] = True
        return flag[idx]

    def _near_band(self, scene: Scene, rules: Rules, key: tuple) -> np.ndarray | None:
        """(H·W,) the pixels whose primary ray may lie in the band under these camera rules
        (minirt.reference.band_filter: a superset, from one kernel over the whole image), kept per camera;
        None where the filter does not answer for the scene (many shapes, far balls)."""
        if key not in self._near:
            from minirt.reference import band_filter
            from minirt.reference.tracer import Tracer

            near = None
            if band_filter.usable(scene, band_filter.reach(scene, rules), EPS_REL):
                # the rays in Dr.Jit, the same bits as camera.primary_rays (tested), read by the filter's kernel
                o, d = Tracer(scene, rules.traced(), runtime=True).primary_rays()
                near = band_filter.near_band(scene, o, d, EPS_REL)
            self._near[key] = near
        return self._near[key]

    def first_hits(self, scene: Scene, rules: Rules) -> tuple[np.ndarray, np.ndarray]:
        """(H·W,) shape id (-1: a miss) and t (inf: a miss) of every pixel's primary ray under the rules'
        camera rules and near_root_only, every hit counted (t_max left out): what a t_max cuts, and what
        the unexplained pixels are grouped by. One closest-hit kernel, kept per camera rules."""
        import drjit as dr

        from minirt.reference.tracer import Tracer

        plain = replace(rules.traced(), t_max=math.inf)
        cam = (scene.camera.width, scene.camera.height, _ray_key(rules), plain.near_root_only)
        key = (scene.digest, scene.source, *cam)
        if key not in self._hits:
            tr = Tracer(scene, plain, runtime=True)
            o, d = tr.primary_rays()
            with dr.scoped_set_flag(dr.JitFlag.FastMath, False):
                sid, t = tr.closest(o, d)
                dr.eval(sid, t)
            sid = np.asarray(sid).astype(np.int32)
            self._hits[key] = (sid, np.where(sid >= 0, np.asarray(t, dtype=np.float64), math.inf))
        return self._hits[key]

    def deep_t(self, scene: Scene, rules: Rules) -> np.ndarray:
        """(H·W,) the longest hit of each pixel's reflected rays (0: none hits): where a t_max cuts a pixel's
        reflection though its own hit is near. Every hit counted (t_max left out); one recorded trace, kept
        per traced rules."""
        import drjit as dr

        from minirt.reference.tracer import Tracer

        plain = replace(rules.traced(), t_max=math.inf)
        key = (*self.key(scene, plain), "deep")
        if key not in self._hits:
            n = scene.camera.width * scene.camera.height
            tr = Tracer(scene, plain, runtime=True)
            o, d = tr.primary_rays()
            with dr.scoped_set_flag(dr.JitFlag.FastMath, False):
                _, levels = tr.trace(o, d, record=True)
            deep, root = np.zeros(n), np.arange(n)
            for lvl in levels[1:]:
                root = root[np.asarray(lvl.parent).astype(np.int64)]
                t = np.broadcast_to(np.asarray(lvl.t, dtype=np.float64), root.shape)
                ok = np.isfinite(t)
                np.maximum.at(deep, root[ok], t[ok])
            self._hits[key] = deep
        return self._hits[key]

    def _f32_render(self, scene: Scene, v: Variant) -> tuple[np.ndarray | None, np.ndarray]:
        """The same rules traced in float32, and the pixels where that image differs by more than a level:
        decisions that rounding flips anywhere in the ray tree (reflections, planes' shadows, self-shadowing
        offsets). A float32 tracer may draw either image at those pixels."""
        from minirt.errors import MinirtError

        try:
            c32 = self._trace(scene, v.rules, None, "f32").color
        except MinirtError:  # beyond float32's range: no float32 tracer could draw it; nothing to add
            return None, np.zeros(v.color.shape[:2], dtype=bool)
        return self._f32_twin(v, c32)

    @staticmethod
    def _f32_twin(v: Variant, c32: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The float32 image as kept, and the pixels where it differs from ``v``'s by more than a level.

        Encoded only where the two colours are at least ~LEVEL_TOL / 255 apart (or not numbers): levels
        more than LEVEL_TOL apart, floor(255 a + 0.5) - floor(255 b + 0.5) > LEVEL_TOL, need 255 (a - b)
        > LEVEL_TOL up to three roundings (relative 2^-50), and the clamp only narrows a gap -- so the
        same flags as encoding every pixel (tested), for the few pixels a float32 trace moves that far."""
        flips = np.zeros(v.color.shape[:2], dtype=bool)
        with np.errstate(invalid="ignore"):
            far = bitmap.channel_any(~(np.abs(v.color - c32) <= TWIN_GAP))  # NaN and inf - inf: looked at
        at = np.flatnonzero(far)
        if at.size:
            a, b = bitmap.encode(v.color.reshape(-1, 3)[at]), bitmap.encode(c32.reshape(-1, 3)[at])
            flips.reshape(-1)[at] = bitmap.channel_any(np.abs(a.astype(np.int16) - b) > LEVEL_TOL)
        return c32.astype(np.float32), flips

    def subset32(self, scene: Scene, rules: Rules, idx: np.ndarray) -> Variant | None:
        """The candidate traced in float32 on the pixels ``idx`` (None beyond float32's range)."""
        from minirt.errors import MinirtError

        key = self.key(scene, rules)
        self.requested.add((key, "f32"))
        if self._batched32:
            v = self._batched32.get((key, _digest(idx)))
            if v is not None:
                return v
        try:
            return self._trace(scene, rules.traced(), idx, "f32")
        except MinirtError:
            return None

    def _trace(self, scene: Scene, rules: Rules, idx: np.ndarray | None, precision: str = "f64") -> Variant:
        """One candidate on the pixels ``idx`` (None: every pixel), in the batches' kernel."""
        return self._trace_many(scene, [rules], idx, precision)[0]

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


def _threads() -> int:
    """The processors this process may run on, at most 4 (parts beyond that gain little at these sizes)."""
    import os

    try:
        n = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        n = os.cpu_count() or 1
    return max(1, min(4, n))


def _digest(idx: np.ndarray) -> tuple:
    """Which pixels: a prefetched subset is found again by its pixel indices' bytes."""
    import hashlib

    return (idx.size, hashlib.blake2b(np.ascontiguousarray(idx).tobytes(), digest_size=16).digest())


def _ray_key(rules: Rules) -> tuple:
    return (rules.ray_origin, rules.pixel_sample, tuple(rules.pixel_shift))


def _scale(scene: Scene) -> float:
    """The scene's working size: where its balls, light and camera are (planes are unbounded)."""
    s = [1.0, scene.camera.distance, *map(abs, scene.light.position)]
    for b in scene.shapes:
        if isinstance(b, Ball):
            s.append(max(map(abs, b.center)) + b.radius)
    return max(s)
