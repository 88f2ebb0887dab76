"""The reference tracer: the exercise's model (problem 13.1), vectorised with Dr.Jit's LLVM backend.

Structure follows the problem set, a module per step (pbrt's split, in miniature):
- minirt.reference.shapes: ``Ball`` and ``Plane`` each ``intersect`` a ray (the stable forms' numerics);
- minirt.reference.values: how the kernels read the scene -- constants unrolled into them, or the shape
  table's arrays and its BVH (minirt.reference.accel) -- behind one protocol, and ``Scene.Intersect``
  (here :meth:`Tracer.closest`), which keeps the closest hit;
- minirt.reference.interaction: the hit point, the shape's ``normal``, and where secondary rays start;
- minirt.reference.shading: ``TraceRay``'s local terms -- ambient, the shadow-tested diffuse and specular;
- minirt.reference.integrator: the recursion (here :meth:`Tracer.trace`): the reflection and the
  background added back to front, in one kernel or a wavefront of levels;
- minirt.reference.sampling: the camera's primary rays and supersampling's samples;
- minirt.reference.film: the output buffers, and an image assembled from its tiles.

``Tracer`` is the façade over them: one scene under one set of rules, rendered whole (``render``) or tile
by tile (``tiles``, ``render_rows``). Dr.Jit's FastMath is switched off while tracing: the NaN/inf guards
and the stable intersection forms rely on IEEE semantics.
"""

from __future__ import annotations

import time
from collections.abc import Collection, Sequence
from typing import Any

import drjit as dr
import numpy as np

from minirt.jit.engine import require_llvm
from minirt.model import camera
from minirt.model.effects import Effects, effects
from minirt.model.result import TERMS, RenderResult
from minirt.model.rules import Rules
from minirt.model.scene import Ball, Scene
from minirt.reference import film, integrator, sampling
from minirt.reference.accel import ShapeTable
from minirt.reference.settings import TraceSettings
from minirt.reference.shading import Level
from minirt.reference.values import Candidates, Tabled, Types, Unrolled, Values


class Tracer(TraceSettings):
    """Traces batches of rays through one scene under one set of rules: the settings the parts read
    (``TraceSettings``, filled in here) and the methods that trace and render with them.

    ``prune=False`` switches off every optimisation that skips work (effects and per-ray pruning):
    it exists so a test can show that pruning leaves every output bit-identical.
    """

    def __init__(
        self,
        scene: Scene,
        rules: Rules | Sequence[Rules],
        precision: str = "f64",
        prune: bool = True,
        runtime: bool | None = None,
        accel: str = "auto",
        looped: bool = False,
    ):
        """``runtime``: the rules a search varies most are values the kernel reads, not constants
        compiled into it -- specular_exponent, the camera's pixel_sample, pixel_shift, ray_origin, and
        near_root_only, two_sided, clamp, a numeric offset and offset_along (the rules that change which
        work is done stay compiled in: offset "error-bound", shadow_range, shadow_rays, background, and the
        effects; a batch of rule sets reads shadow_range, shadow_rays and background per ray too)
        -- and primary rays come from an array of pixel indices (``primary_rays(pixels)``). Renders
        that differ only in those, and renders of a few pixels, share one kernel: a search over
        candidates compiles each kernel once. The same bits either way (tested), at the cost of a few
        selects per ray. None (the default): read at run time for images below
        ``integrator.LOOP_FIRST_LEVEL_BELOW`` pixels, where a kernel's compile outweighs its runs -- a scene rendered
        under another rule (``--rule``, a profile, a test's sweep) then reuses the compiled kernels --
        and compiled in from there, where the selects would cost every ray and a compile is amortised.

        ``rules`` a list: the rule sets traced together in one kernel (runtime only), ray k·n + i the k-th
        rule set's ray i of ``primary_rays(pixels)`` -- each ray reads the per-ray rules
        (``values.PER_RAY``) of its own rule set, every other rule must be the same for all
        (``values.Candidates``), and each rule set's rays come out bit for bit as traced alone: a search's
        candidates in one launch instead of one each (minirt.diagnose.variants).

        ``accel``: how rays find their shapes. "unrolled" tests every shape in code generated for this
        scene (constants compiled in: fastest for a few shapes, one kernel per layout); "bvh" gathers
        from the shape table and walks a BVH over the balls (``minirt.reference.accel``: kernels independent
        of the layout, time ~log N); "loop" gathers from the table and tests every ball in a loop (the
        brute force, with kernels independent of the layout: what the tree is tested against); "auto"
        picks "bvh" from ``ACCEL_MIN_SHAPES`` shapes on. The same bits every way (tested).

        ``looped``: every trace runs its first level as the loop's first iteration, whatever its number of
        rays (``integrator.first_level_looped``): a caller that traces whole images and subsets of them
        (the rule diagnosis) compiles one kernel for both. The same bits (tested)."""
        require_llvm()
        batch = None if isinstance(rules, Rules) else list(rules)
        if batch is not None:
            # Several rule sets in one kernel, ray k * n + i the k-th's ray i (``primary_rays``): the rules
            # that are read at run time come per ray from the candidate's own values, any other rule must
            # be the same for all (``values.Candidates``; ``Divergent`` otherwise).
            if not runtime:
                raise ValueError("a batch of rule sets is traced with runtime=True")
            rules = Candidates(batch)
        self.scene, self.rules, self.precision, self.prune = scene, rules, precision, prune
        if runtime is None:
            runtime = scene.camera.width * scene.camera.height < integrator.LOOP_FIRST_LEVEL_BELOW
        self.runtime = runtime
        self.looped = looped
        self.T = Types.of(precision)
        if accel == "auto":
            accel = "bvh" if len(scene.shapes) >= ACCEL_MIN_SHAPES else "unrolled"
        if accel not in ACCELS:
            raise ValueError(f"unknown accel {accel!r} (auto, {', '.join(ACCELS)})")
        self.accel = accel
        # The one place that asks which representation the scene's values take: the tracer's code calls
        # the same methods on either (minirt.reference.values).
        if accel == "unrolled":
            self.values: Values = Unrolled(scene, rules, self.T, runtime)
        else:
            table = ShapeTable(scene, self.T, with_tree=accel == "bvh")
            self.values = Tabled(scene, rules, self.T, runtime, table)
        if precision == "f32":
            _check_float32_range(scene)
        if prune and batch is not None:
            # the union of the candidates' effects: pruning changes no bit (tested), so each candidate's
            # rays come out as they would traced alone
            self.effects = union_of_effects([effects(scene, r) for r in batch])
        elif prune:
            self.effects = effects(scene, rules)
        else:
            self.effects = Effects(True, True, True, True, scene.max_depth > 0, scene.max_depth, True)

    # ---- the exercise's steps (each in its module; see the module docstring) ----------------
    def closest(self, o, d) -> tuple[Any, Any]:
        """Appendix 1: the closest hit over all shapes, (id, t); ties keep the lower shape id."""
        return self.values.closest(o, d)

    def intersect(self, shape, o, d, gate: bool = False) -> Any:
        """t of the ray (o, d) at the shape, inf on a miss; ``gate``: see ``shapes.ball_t``, ``shapes.plane_t``."""
        return self.values.intersect(shape, o, d, gate)

    def intersect_ball(self, ball: Ball, o, d) -> Any:
        """t of the ray (o, d) at the ball, inf on a miss (``shapes.ball_t``)."""
        return self.values.intersect(ball, o, d)

    def occludes_ball(self, ball: Ball, o, d) -> Any:
        """intersect_ball(ball, o, d) < inf, from signs (``shapes.ball_occludes``)."""
        return self.values.occludes(ball, o, d)

    def trace(
        self,
        o,
        d,
        record: bool = False,
        tree: bool = False,
        out: dict[str, Any] | None = None,
        terms: Collection[str] | None = None,
        path: str = "auto",
    ) -> tuple[Any, list[Level]]:
        """TraceRay for a batch: the colour of each ray and its levels (``integrator.trace``: ``record``,
        ``tree``, ``out``, ``terms`` and ``path`` are described there)."""
        return integrator.trace(self, o, d, record, tree, out, terms, path)

    # ---- rays in, buffers out ------------------------------------------------------------------
    def primary_rays(self, pixels: np.ndarray | None = None) -> tuple[Any, Any]:
        """camera.primary_rays computed in Dr.Jit, the same bits (``sampling.primary_rays``); ``pixels``:
        row-major indices of the pixels wanted (default every pixel)."""
        if self.values.batch is not None:
            if pixels is None:
                pixels = np.arange(self.scene.camera.width * self.scene.camera.height)
            self.values.set_lanes(pixels.size)
            pixels = np.tile(pixels, len(self.values.batch.all))
        return sampling.primary_rays(self, pixels)

    def sample_rays(self, u, v, pixels: np.ndarray | None = None) -> tuple[Any, Any]:
        """camera.rays_through(scene, rules, u, v) in Dr.Jit (``sampling.sample_rays``): the rays through
        the sub-pixel offsets (u, v) of the pixels (default every pixel)."""
        return sampling.sample_rays(self, u, v, pixels)

    def load(self, a: np.ndarray) -> Any:
        """(N, 3) NumPy rows as a Dr.Jit 3-vector of the tracer's precision (``sampling.load``): rays of
        one's own to ``trace`` or ``closest`` (minirt.reference.probe, the rule diagnosis)."""
        return sampling.load(self, a)

    def to_numpy3(self, a, also=()) -> np.ndarray:
        """(N, 3) float64 from a Dr.Jit 3-vector of N rays, zeros canonical (``film.to_numpy3``): a level's
        points, normals or colours read back (the rule diagnosis)."""
        return film.to_numpy3(self.T, a, also)

    # The name minirt.diagnose.variants still calls (tests/package/test_house.py, PENDING).

    # ---- whole images -----------------------------------------------------------------------
    def render(
        self,
        progress=None,
        diagnostics: bool = False,
        tile_pixels: int | None = None,
        terms: Collection[str] | None = None,
    ) -> RenderResult:
        """The image and its buffers. ``diagnostics`` adds what the harness needs to classify pixels
        (aux ray_tree: every decision of each pixel's ray tree, hashed; aux shadow_margin): ~20 % more
        time, so a plain render skips them.

        An image larger than ``tile_pixels`` (default ``TILE_PIXELS``) is traced in tiles of whole rows
        (``tiles``) and assembled: Dr.Jit's working memory is then one tile's, whatever the image size;
        the same bits as one pass (tested). For images too big to hold at all, write the tiles as they
        come (``minirt.io.images.write_tiles``).

        ``terms``: the terms the result holds (default all of ``TERMS``). Each costs the kernels 24 or 32
        bytes a pixel of writes (a float64 3-vector, minirt.reference.film's two layouts); a caller that
        reads only some asks for those: the colour and the terms asked for are the same bits either way
        (tested). From ``integrator.LOOP_FIRST_LEVEL_BELOW`` pixels the vectors are ``Planes``, stacked into
        (h, w, 3) arrays only when read (minirt.model.result)."""
        sc = self.scene
        w, h = sc.camera.width, sc.camera.height
        rows = tile_rows(w, tile_pixels)
        if rows >= h:
            return self.render_rows(0, h, progress, diagnostics, terms)
        t0 = time.perf_counter()
        full: RenderResult | None = None
        for y0, tile in self.tiles(progress, diagnostics, tile_pixels, terms):
            if full is None:
                full = film.empty_like(tile, h)
            film.paste(full, tile, y0)
        assert full is not None
        full.meta["timings"] = {"total": time.perf_counter() - t0}
        return full

    def tiles(
        self,
        progress=None,
        diagnostics: bool = False,
        tile_pixels: int | None = None,
        terms: Collection[str] | None = None,
    ):
        """(first row, RenderResult of the rows from there) for each tile of whole rows, top to bottom."""
        sc = self.scene
        w, h = sc.camera.width, sc.camera.height
        rows = tile_rows(w, tile_pixels)
        count = -(-h // rows)
        for k in range(count):
            y0, y1 = k * rows, min(h, (k + 1) * rows)

            def sub(done: int, total: int, k=k) -> None:
                if progress:
                    progress(k * total + done, count * total)

            yield y0, self.render_rows(y0, y1, sub, diagnostics, terms)

    def render_rows(
        self, y0: int, y1: int, progress=None, diagnostics: bool = False, terms: Collection[str] | None = None
    ) -> RenderResult:
        """Rows y0 .. y1 - 1 of the image as a RenderResult of height y1 - y0 (the whole image: 0, height)."""
        sc = self.scene
        w = sc.camera.width
        h = y1 - y0
        pixels = None if (y0, y1) == (0, sc.camera.height) else np.arange(y0 * w, y1 * w, dtype=np.uint32)
        timings: dict[str, float] = {}
        t0 = time.perf_counter()
        o, d = self.primary_rays(pixels)
        bufs: dict[str, Any] = {}
        unknown = sorted(set(terms or ()) - set(TERMS))
        if unknown:
            raise ValueError(f"unknown term(s) {', '.join(unknown)}: the terms are {', '.join(TERMS)}")
        wanted = TERMS if terms is None else tuple(k for k in TERMS if k in terms)
        color, levels = self.trace(o, d, tree=diagnostics, out=bufs, terms=wanted)
        lvl0 = levels[0]
        dr.sync_thread()
        out = {k: film.read(b, h, w) for k, b in bufs.items() if k != "t"}
        out["shape_id"] = np.asarray(lvl0.shape_id).reshape(h, w)
        out["hit"] = out["shape_id"] >= 0
        out["t"] = np.asarray(bufs["t"]).reshape(h, w)  # inf on a miss already (shade_level)
        del o, d, color, bufs
        col = out.pop("color")
        terms = {k[5:]: out.pop(k) for k in list(out) if k.startswith("term.")}
        geom = out
        timings["primary"] = time.perf_counter() - t0
        if progress:
            progress(1, max(1, sc.samples))
        # Pixels whose neighbours' ray trees differ lie near a decision (a silhouette or shadow edge seen
        # in a reflection, too). The top 24 bits of the 32-bit hash: exact in a float32 EXR channel; two
        # different neighbouring trees look alike with probability 2^-24.
        aux: dict[str, np.ndarray] = {}
        if diagnostics:
            aux["ray_tree"] = (np.asarray(lvl0.record["tree"]) >> 8).astype(np.float64).reshape(h, w)
        if diagnostics and "shadow_margin" in lvl0.record:
            aux["shadow_margin"] = np.asarray(lvl0.record["shadow_margin"]).astype(np.float64).reshape(h, w)
        del lvl0, levels
        if sc.samples > 1:
            col, terms, more = sampling.render_samples(self, progress, y0, y1, falloff=diagnostics, terms=wanted)
            aux.update(more)
        timings["total"] = time.perf_counter() - t0
        for k in wanted:  # a term the effects skip is exactly zero
            if k not in terms:
                terms[k] = np.zeros((h, w, 3))
        meta = {
            "backend": "reference",
            "version": _versions(),
            "scene": sc.name,
            "scene_sha256": sc.digest,
            "settings": {"precision": self.precision, "samples": sc.samples, "width": w, "height": sc.camera.height,
                         "max_depth": sc.max_depth, "prune": self.prune, "sample_seed": camera.SAMPLE_SEED},
            "rules": self.rules.as_dict(),
            "effects": {"simulated": self.effects.simulated(), "skipped": self.effects.skipped(),
                        **self.effects.as_dict()},
            "timings": timings,
            "aux": DIAGNOSTICS if diagnostics else {},
        }  # fmt: skip
        return RenderResult(backend="reference", width=w, height=h, color=col, terms=terms, aux=aux, meta=meta, **geom)


# Pixels per tile: Dr.Jit's working set is ~330 B per pixel in float64 (the wavefront's levels, the rays,
# the read-out's interleaved buffers; measured: benchmarks/bench_scale.py, memory), so a tile of 2^20
# pixels costs ~350 MB above the finished image's NumPy buffers, and its kernels are long enough that
# the per-tile overhead is small (tiles of 1 Mpixel cost < 5 % more time than one pass).
TILE_PIXELS = 1 << 20


def tile_rows(width: int, tile_pixels: int | None = None) -> int:
    """Rows per tile: as many whole rows as fit in ``tile_pixels`` (at least one)."""
    return max(1, (tile_pixels or TILE_PIXELS) // width)


DIAGNOSTICS = {
    "ray_tree": "per pixel, a 24-bit hash of the shapes hit and the shadow (and, under clamp, light-side) decisions "
    "of its whole ray tree; neighbours with different values straddle an edge, possibly seen in a reflection",
    "shadow_margin": "per pixel, the distance from its shadow ray to the nearest ball silhouette in front of it "
    "(1e30: none): how far the hit point may move before the shadow decision can flip",
}

# From this many shapes on, "auto" traces through the shape table and the BVH (measured: benchmarks/bench_scale.py).
ACCEL_MIN_SHAPES = 16
ACCELS = ("unrolled", "bvh", "loop")
F32_LIMIT = 1e18  # squares stay below float32's max (3.4e38); reciprocals above its min normal


def union_of_effects(each: list[Effects]) -> Effects:
    """The effects a kernel simulates for several rule sets at once: every part any of them needs, the
    deepest reflection any reaches."""
    return Effects(
        *(any(getattr(e, n) for e in each) for n in ("ambient", "diffuse", "specular", "shadows", "reflection")),
        max(e.reflection_depth for e in each),
        any(e.background for e in each),
    )


def _check_float32_range(scene: Scene) -> None:
    """Refuse a scene float32 cannot hold: its squared lengths would overflow to inf and then NaN."""
    from minirt.errors import MinirtError

    values = [scene.camera.distance, *scene.light.position]
    for s in scene.shapes:
        values += [*s.center, s.radius] if isinstance(s, Ball) else [*s.point, s.distance]
    big = max(abs(v) for v in values)
    small = min([scene.camera.distance] + [s.radius for s in scene.shapes if isinstance(s, Ball)])
    if big > F32_LIMIT or small < 1 / F32_LIMIT:
        raise MinirtError(
            f"{scene.source or scene.name}: values from {small:g} to {big:g} are beyond float32's safe range "
            f"(1e-18 .. 1e18): use --precision f64"
        )


def _versions() -> dict[str, str]:
    from minirt.version import __version__

    return {"minirt": __version__, "drjit": dr.__version__}


def render(
    scene: Scene,
    rules: Rules,
    precision: str = "f64",
    prune: bool = True,
    progress=None,
    diagnostics: bool = False,
    terms: Collection[str] | None = None,
    runtime: bool | None = None,
) -> RenderResult:
    """Render a scene with the reference tracer (``diagnostics``: also aux ray_tree and shadow_margin;
    ``terms``: the terms to keep, default all; ``runtime``: see ``Tracer``)."""
    tr = Tracer(scene, rules, precision=precision, prune=prune, runtime=runtime)
    return tr.render(progress=progress, diagnostics=diagnostics, terms=terms)
