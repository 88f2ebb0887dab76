"""The exact oracle: the exercise's model in certified ball arithmetic (python-flint's ``arb``), the judge
where every float renderer is inconclusive.

Every decision of the model -- which shape a ray hits, lit or not, which side of a surface, the clamp's
gates -- is made on intervals that contain the exact value of the expression on the scene's binary64
numbers, at a precision raised per pixel (128, 256, 512, 1,024 bits) until each is certified; colours
to 2^-40. A decision uncertain at 1,024 bits is an exact tie (a ray tangent to a ball, a shadow ray
through an occluder's silhouette exactly), flagged per pixel (``aux["exact_tie"]``, with the decision in
``meta["ties"]``), never guessed, and not judged. minirt.oracles.exact.model states the model rule by
rule; minirt.oracles.exact.render the precisions and the pixels.

Conventions bridged (none: this is the model the reference tracer computes in float64):

- Rays: the exercise's own, set up exactly from the scene's numbers (rational image-plane points, the
  rules pixel_sample, pixel_shift and ray_origin), not the reference's rounded ones; so the reference's
  rounding of its rays is part of its error, which its tolerance here covers.
- Offsets: a number, along the normal or the new ray, or "error-bound" (pbrt-v4's bound, as an exact
  offset from the exact hit point); an offset of 0 starts a ray exactly on its surface, where a root
  t = 0 does not count.
- Every rule of the exercise's readings is followed; the rules from real solutions' bugs
  (``rules.BUG_RULES``: ``t_max``, ``raw_normals_ball`` ...) only at their defaults, as for every oracle (a
  check under another value says SKIP);
  the output rules are the bitmap's, as for every backend.
- Pixels: the whole image up to ``WHOLE_IMAGE_PIXELS`` (512^2: ~10 s at 40 us a ray; campaign sizes are
  64^2 at most); a larger image a stratified sample of ``SAMPLE_PIXELS`` (one pixel of each block,
  deterministic), plus the pixels ``options["pixels"]`` names (row-major indices: those another oracle
  left inconclusive), or every pixel with ``options["pixels"] = "all"``. A pixel not traced is in
  ``aux["rendered"]`` false and not judged. A check (``check_options``) traces the whole image up to
  ``CHECK_WHOLE_PIXELS`` (64^2) and above it the reference's edges -- silhouettes, shadow edges and
  terminators, and the edges seen in reflections: where float renderers' bands leave their checks
  inconclusive -- with the stratified sample; its verdict is on the pixels traced (the count is in the
  check's figures, ``traced_pixels``).
- Robust bounds (``aux`` "robust", "robust_geometry", "t_lo" ... "color_hi"): the model again with every
  ray, hit point and plane widened (minirt.oracles.exact.model), what minirt.harness.judge rules with.
- Tolerance (``geometry_tolerance``): zero on decisions, except where the *reference's* float64 error
  bound lets its own decision flip -- the band is the reference's, per shape (``band_scales``) -- and the
  reference's error bound on t and normals: the reference's stability is what this oracle judges.
- Several samples per pixel (``options["samples"]``, the check of a scene with samples > 1): the
  reference's own stratified sub-pixel positions (minirt.model.camera.sample_offsets, binary64 numbers
  taken exactly), the colour their mean; no robust bounds (those are of one ray: every pixel is "not
  robust"), so the judge rules on one-sample renders only.
"""

from __future__ import annotations

import functools
import math
import time
from typing import Any, ClassVar

import numpy as np

from minirt.model import camera
from minirt.model.backend import U64, GeometryTolerance, Margins, tolerance_inputs
from minirt.model.result import RenderResult, edge_classes
from minirt.model.rules import Rules
from minirt.model.scene import Ball, Scene
from minirt.oracles.base import Oracle

NAME = "exact"
# The per-pixel buffers a render adds (minirt.oracles.exact.render.buffers; the judge reads the robust ones)
AUX = ("rendered", "exact_tie", "certified_bits", "color_rad", "t_rel_rad", "robust", "robust_geometry",
       "t_lo", "t_hi", "color_lo", "color_hi", "normal_lo", "normal_hi")  # fmt: skip
WHOLE_IMAGE_PIXELS = 512 * 512
SAMPLE_PIXELS = 4096
# A check traces every pixel up to the campaign's largest size (64^2); above it, the pixels where float
# renderers are left inconclusive -- every edge of the reference's image -- and a stratified sample
# (``check_options``): a 256^2 bundled scene in ~1 s rather than ~10 s.
CHECK_WHOLE_PIXELS = 64 * 64
SAMPLE_SEED = 38
OPTIONS = ("pixels", "samples", "workers")
# Options every backend is given that mean nothing here (the model is exact whatever the precision).
SHARED_OPTIONS = ("precision", "prune", "diagnostics", "terms", "runtime", "timeout", "progress")
# The reference's float64 error, in units of u = 2^-53, on the quantities its decisions compare (derived
# beside ``band_scales`` and ``geometry_tolerance``); twice the count of roundings, for headroom.
REF_ULPS = 32.0


def _import_flint():
    import flint

    return flint


def version_line() -> str:
    try:
        flint = _import_flint()
    except ImportError:
        return ""
    return f"python-flint {flint.__version__} (arb ball arithmetic)"


def origin_reach(scene: Scene, rules: Rules) -> float:
    """The largest |o| of a primary ray's origin: the camera, or an image-plane point (|x|, |y| <= 1/2 plus a
    pixel shift of up to 4 pixels)."""
    w, h = scene.camera.width, scene.camera.height
    sx, sy = rules.pixel_shift
    half = math.hypot(0.5 + (abs(sx) + 1) / w, 0.5 + (abs(sy) + 1) / h)
    return scene.camera.distance if rules.ray_origin == "camera" else half


def band_scales(scene: Scene, rules: Rules) -> list[float]:
    """Per shape, the relative precision of the reference's float64 decisions about it (the scale of
    minirt.reference.band.margins: a ray is in the band where its margin over this is below 1).

    Ball (centre C, radius r), rays from origins within R of 0: the reference rounds the ray's origin and
    direction (a few u |o|, 3 u), f = o - C (u (R + |C|)), b = f·d and g = f - b d (about 4 u |f|), |g|^2
    and r^2 - |g|^2 (a fused multiply-add): its distance h of the ray from the centre errs by about
    10 u (R + |C| + r); relative to r, the silhouette's and the origin's margin. Plane: n·d's sign flips
    where |n·d| is within a few u (the grazing margin), and the point-normal t errs by about
    4 u (|a| + R + t)/|n·d|, which the depth ties' cos-weighted relative gap sees as a relative error of
    4 u (|a| + R)/t + 4 u; scaled here with t >= 1 assumed as R, so 4 u (|a| + 2 R + 1). REF_ULPS doubles
    the counts."""
    reach = origin_reach(scene, rules)
    out = []
    for s in scene.shapes:
        if isinstance(s, Ball):
            out.append(REF_ULPS * U64 * (reach + math.hypot(*s.center) + s.radius) / s.radius)
        else:
            out.append(REF_ULPS * U64 * (abs(s.distance) + 2 * reach + 1.0))
    return out


def shape_sizes(scene: Scene) -> list[float]:
    """Per shape, the size of its numbers: |C| + r for a ball, |a| for a plane."""
    return [math.hypot(*s.center) + s.radius if isinstance(s, Ball) else abs(s.distance) for s in scene.shapes]


def start_error(scene: Scene, rules: Rules) -> float:
    """The reference's position error where a candidate hit lies at t ~ 0 (a ray starting on a surface):
    a few u of the ray's origin and the surface's size there."""
    reach = origin_reach(scene, rules)
    size = max(shape_sizes(scene), default=0.0)
    return REF_ULPS * U64 * (reach + size)


def choose_pixels(scene: Scene, requested: Any) -> np.ndarray:
    """Row-major indices of the pixels to trace (module docstring): all, or a stratified sample and those
    requested."""
    w, h = scene.camera.width, scene.camera.height
    n = w * h
    if isinstance(requested, str):
        if requested != "all":
            raise ValueError(f'pixels must be "all" or a list of row-major indices, got {requested!r}')
        return np.arange(n)
    extra = np.zeros(0, dtype=np.int64)
    if requested is not None:
        extra = np.asarray(requested, dtype=np.int64).reshape(-1)
        if extra.size and (extra.min() < 0 or extra.max() >= n):
            raise ValueError(f"pixels: indices must be within 0 .. {n - 1}")
        if n > WHOLE_IMAGE_PIXELS:
            return np.unique(np.concatenate([stratified(w, h), extra]))
        return np.unique(extra)
    if n <= WHOLE_IMAGE_PIXELS:
        return np.arange(n)
    return stratified(w, h)


def stratified(w: int, h: int, count: int = SAMPLE_PIXELS) -> np.ndarray:
    """One pixel of each block of a grid of about ``count`` blocks over the image, drawn by a seeded PCG64:
    the same pixels for the same size (made once per size: ~25 ms of a check's thread for each scene)."""
    return _stratified(w, h, count).copy()


@functools.lru_cache(maxsize=16)
def _stratified(w: int, h: int, count: int) -> np.ndarray:
    side = max(1.0, math.sqrt(w * h / count))
    bx, by = max(1, round(w / side)), max(1, round(h / side))
    xs = np.linspace(0, w, bx + 1).astype(np.int64)
    ys = np.linspace(0, h, by + 1).astype(np.int64)
    rng = np.random.Generator(np.random.PCG64(SAMPLE_SEED))
    out = []
    for j in range(by):
        for i in range(bx):
            x0, x1, y0, y1 = xs[i], max(xs[i + 1], xs[i] + 1), ys[j], max(ys[j + 1], ys[j] + 1)
            out.append(int(rng.integers(y0, y1)) * w + int(rng.integers(x0, x1)))
    return np.unique(np.asarray(out, dtype=np.int64))


class ExactOracle(Oracle):
    name: ClassVar[str] = NAME
    display_name: ClassVar[str] = "exact"
    shades: ClassVar[bool] = True
    shading_model: ClassVar[str | None] = "exercise"
    # Certified: its decisions are the exact model's (the campaign's judge of last resort asks for it by this).
    certified: ClassVar[bool] = True
    packages: ClassVar[tuple[str, ...]] = ("python-flint",)
    # Bytes per pixel, measured with tracemalloc on three_balls 64x64: a result keeps 430 (its buffers and the
    # robust bounds, aux), a render peaks at 2,020 (a Python object per pixel until the buffers are filled);
    # a check keeps the result and the harness's figures (the reference's default 1,400 besides).
    render_kept: ClassVar[int] = 450
    render_running: ClassVar[int] = 2100
    check_kept: ClassVar[int] = 1900
    # Every hit counts and normals are of unit length: the exercise's model; the rules from real solutions'
    # bugs (minirt.model.rules) are graded by the reference, not judged here.
    supported: ClassVar[dict[str, tuple[Any, ...]]] = {"t_max": (math.inf,)}

    def available(self) -> tuple[bool, str]:
        try:
            _import_flint()
        except ImportError:
            return False, "python-flint is not installed (pip install python-flint)"
        return True, version_line()

    def version(self) -> str:
        return version_line()

    def options(self, precision: str = "f64", samples: int | None = None, timeout: float | None = None) -> dict:
        return {} if samples is None or samples <= 1 else {"samples": samples}

    chooses_pixels: ClassVar[bool] = True

    def check_options(self, scene: Scene, reference: RenderResult) -> dict[str, Any]:
        """Every pixel up to CHECK_WHOLE_PIXELS, in this process; above, the reference's edges and the
        stratified sample, on a worker process per core (where this process may start them: not in a Dask
        worker), which the check runs beside the other oracles' work (``runs_apart``)."""
        from minirt.jobs.batch import cores
        from minirt.oracles.exact.render import can_spread

        w, h = scene.camera.width, scene.camera.height
        if w * h <= CHECK_WHOLE_PIXELS:
            return {}
        edges = np.logical_or.reduce(list(edge_classes(reference).values()))
        options: dict[str, Any] = {"pixels": np.union1d(stratified(w, h), np.flatnonzero(edges))}
        if can_spread() and cores() > 1:
            options["workers"] = cores()
        return options

    def runs_apart(self, options: dict[str, Any]) -> bool:
        return options.get("workers", 1) > 1

    def geometry_tolerance(self, result: RenderResult, ref: RenderResult, measured: Margins) -> GeometryTolerance:
        """The reference's float64 error bound as per-pixel tolerances (``band_scales``, ``start_error``); the
        exact oracle's own ties and the pixels it did not trace are not judged (added to the band)."""
        h, w, p, m, t_ref = tolerance_inputs(result, ref, measured)
        start = p.get("start_err", 0.0)
        starts = measured.start_band(h, w, t_min=0.0, plane_err=start, ball_err=start)
        if measured.scaled is not None and p.get("band_scale"):
            band, ties = measured.per_shape_band(p, h, w)
        else:
            band, ties = m["margin"] < p.get("band_eps", 1e-12), None
        aux = result.aux
        rendered = aux.get("rendered", np.ones((h, w), dtype=bool))
        # not judged: this oracle's exact ties, the pixels it did not trace, and those whose decisions are not
        # robust (minirt.oracles.exact.model: a decision within the slack of flipping, the reference's own
        # rounding may take it either way -- a shadow edge through a pixel that the reference's edge classes,
        # made from its own decisions, cannot see)
        own = aux.get("exact_tie", np.zeros((h, w), dtype=bool)) | ~rendered
        if "robust" in aux:
            own = own | (rendered & ~aux["robust"])
        band = band | starts | own
        # t: the reference's root or quotient errs by REF_ULPS u (R + |C| + r + t) over the cosine of the hit
        # (a ball's discriminant error over its square root, sqrt(disc) = r cos; a plane's numerator over |n·d|)
        reach = p.get("reach", 1.0)
        size = np.zeros((h, w))
        for k, s in enumerate(p.get("sizes", [])):
            size[ref.shape_id == k] = s
        with np.errstate(divide="ignore"):
            t_abs = REF_ULPS * U64 * (reach + size + t_ref) / np.maximum(m["hit_cos"], 1e-300)
        if "t_lo" in aux:  # and never below the robust interval's reach from the certified t
            with np.errstate(invalid="ignore"):
                reach_t = np.maximum(aux["t_hi"] - result.t, result.t - aux["t_lo"])
            t_abs = np.where(np.isfinite(reach_t), np.maximum(t_abs, reach_t), t_abs)
        radius = np.ones((h, w))
        for k, r in enumerate(p.get("radii", [])):
            radius[ref.shape_id == k] = r if r else np.inf
        # normal: a ball's (p - C)/r turns by the hit point's error over r; a plane's is the scene's, rounded
        with np.errstate(invalid="ignore"):
            nd = np.degrees(np.minimum(np.pi, REF_ULPS * U64 + (t_abs + REF_ULPS * U64 * (reach + size)) / radius))
        if "normal_lo" in aux:
            spread = np.degrees(2 * np.linalg.norm(aux["normal_hi"] - aux["normal_lo"], axis=-1))
            nd = np.maximum(nd, spread)
        why = {
            "band": "the reference's own float64 error bound: a margin below each shape's scale "
            f"{REF_ULPS:g} u (R + |C| + r)/r (ball), {REF_ULPS:g} u (|a| + 2R + 1) (plane), or a candidate hit "
            f"with t cos within {start:.3g} of 0; plus this oracle's exact ties, pixels not traced and pixels whose "
            "decisions are not robust (within 2^-40 of flipping)",
            "t": f"|dt| <= {REF_ULPS:g} u (R + size + t)/cos at the hit (the reference's roots and quotients), or the "
            "robust interval's reach",
            "normal": f"{REF_ULPS:g} u + the hit point's error over the radius (balls), or the robust interval's",
        }
        summary = {
            "band_eps": float(max(p.get("band_scale") or [0.0])),
            "exact_ties": int(result.aux.get("exact_tie", np.zeros(1, dtype=bool)).sum()),
            "not_traced": int((~rendered).sum()),
            "not_robust": int((rendered & ~aux.get("robust", rendered)).sum()),
            "start_band_pixels": int(starts.sum()),
        }
        traced = None if rendered.all() else rendered
        return GeometryTolerance(band=band, t_abs=t_abs, normal_deg=nd, why=why, summary=summary, ties=ties,
                                 traced=traced)  # fmt: skip

    def render(self, scene: Scene, rules: Rules, options: dict[str, Any] | None = None, progress=None) -> RenderResult:
        w, h = scene.camera.width, scene.camera.height
        given = dict(options or {})
        progress = given.pop("progress", progress)
        for k in SHARED_OPTIONS:
            given.pop(k, None)
        unknown = sorted(set(given) - set(OPTIONS))
        if unknown:
            return RenderResult.failed(NAME, w, h, "error", f"unknown option(s) {', '.join(unknown)} "
                                       f"(known: {', '.join(OPTIONS)})")  # fmt: skip
        ok, why = self.available()
        if not ok:
            return RenderResult.failed(NAME, w, h, "skip", why)
        bad = self.cannot_follow(rules)
        if bad:
            return RenderResult.failed(NAME, w, h, "skip", f"cannot follow rule(s) {', '.join(bad)}")
        samples = given.get("samples", 1)
        workers = given.get("workers", 1)
        for key, val in (("samples", samples), ("workers", workers)):
            if isinstance(val, bool) or not isinstance(val, int) or val < 1:
                return RenderResult.failed(NAME, w, h, "error", f"{key} must be an integer >= 1, got {val!r}")
        try:
            pixels = choose_pixels(scene, given.get("pixels"))
        except (ValueError, TypeError) as e:
            return RenderResult.failed(NAME, w, h, "error", str(e))
        try:
            return self._render(scene, rules, pixels, samples, workers, progress)
        except Exception as e:  # a failure is a result, never an exception
            msg = str(e).splitlines()[0] if str(e) else ""
            return RenderResult.failed(NAME, w, h, "error", f"{type(e).__name__}: {msg}")

    def _render(self, scene: Scene, rules: Rules, pixels: np.ndarray, samples: int, workers: int, progress):
        from minirt.oracles.exact.render import buffers, trace_colours, trace_columns

        w, h = scene.camera.width, scene.camera.height
        t0 = time.perf_counter()
        if samples == 1:
            uv0 = 0.0 if rules.pixel_sample == "corner" else 0.5
            uvs = [np.full((len(pixels), 2), uv0)]
        else:
            uvs = []
            for s in range(samples):
                u, v = camera.sample_offsets(samples, s, w * h)
                uvs.append(np.stack([u[pixels], v[pixels]], axis=1))
        # Robust bounds are of one ray a pixel (what the judge rules on); the mean of several has none of its
        # own -- one sample's bounds are not the mean's -- so a render of several samples leaves them out
        # (every pixel not robust), and with them more than half its time. Of the samples after the first
        # only the colour is read: traced together, as colours alone.
        bounds = samples == 1
        first = trace_columns(scene, rules, pixels, uvs[0], workers, progress, bounds)
        buf = buffers(w, h, first)
        ties = [{"pixel": int(first.index[k]), "decision": tie} for k, tie in first.ties.items()]
        bits = first.bits.astype(np.int64)
        if samples > 1:
            n = pixels.size
            rest = trace_colours(scene, rules, np.tile(pixels, samples - 1), np.concatenate(uvs[1:]), workers,
                                 progress)  # fmt: skip
            total = 0 + buf["color"]  # the samples' images summed in order, then divided: the mean
            for color in rest.color.reshape(samples - 1, n, 3):
                img = np.zeros((h * w, 3))
                img[pixels] = color
                total = total + img.reshape(h, w, 3)
            buf["color"] = total / samples
            tied = np.zeros(h * w, dtype=bool)
            tied[[pixels[k % n] for k in rest.ties]] = True
            buf["exact_tie"] |= tied.reshape(h, w)
            most = np.zeros(h * w, dtype=np.int32)
            most[pixels] = rest.bits.reshape(samples - 1, n).max(axis=0)
            buf["certified_bits"] = np.maximum(buf["certified_bits"], most.reshape(h, w))
            ties += [{"pixel": int(pixels[k % n]), "decision": tie} for k, tie in rest.ties.items()]
            bits = np.concatenate([bits, rest.bits])
        seconds = time.perf_counter() - t0
        aux = {k: buf[k] for k in AUX}
        # The model's colour is negative where the rules leave s·n or (r·s)^e unclamped (profile exercise);
        # the harness's pre-flight takes a negative colour for a broken renderer, and every check reads the
        # 8-bit image, clamp(c, 0, 1): the colour is given from 0 up, the model's own in aux "color_exact".
        aux["color_exact"] = buf["color"]
        color = np.maximum(buf["color"], 0.0)
        meta = {
            "backend": NAME,
            "version": version_line(),
            "scene": scene.name,
            "scene_sha256": scene.digest,
            "rules": rules.as_dict(),
            "options": {"samples": samples, "workers": workers},
            "settings": {"width": w, "height": h, "pixels_traced": int(pixels.size), "samples_cast": samples},
            "precision": self.precision(scene, rules),
            "certified": {
                "pixels": int(pixels.size),
                "ties": len(ties),
                "bits": {str(b): int((bits == b).sum()) for b in sorted(set(bits.tolist()))},
                "color_abs": 2.0**-40,
            },
            "ties": ties[:100],
            "effects": {"simulated": ["geometry", "shading"], "skipped": []},
            # Timings only here: a render's sidecar leaves "timings" out, so the same command writes the same bytes
            "timings": {"total": seconds, "per_ray": seconds / max(1, pixels.size * samples)},
            "commands": ["minirt.oracles.exact.render.trace_pixels (python-flint arb)"],
        }
        return RenderResult(backend=NAME, width=w, height=h, hit=buf["hit"], shape_id=buf["shape_id"], t=buf["t"],
                            position=buf["position"], normal=buf["normal"], color=color,
                            terms=buf.get("terms", {}), aux=aux, meta=meta)  # fmt: skip

    def probe(self, scene: Scene, rules: Rules, x: int, y: int) -> dict[str, Any]:
        """Pixel (x, y)'s certified ray tree (minirt.oracles.exact.render.PixelTracer.describe): what `minirt
        probe --certified` shows beside the reference's."""
        from minirt.oracles.exact.render import PixelTracer

        uv = 0.0 if rules.pixel_sample == "corner" else 0.5
        out = PixelTracer(scene, rules).describe(y * scene.camera.width + x, uv, uv)
        return {"backend": NAME, "version": version_line(), **out}

    @staticmethod
    def precision(scene: Scene, rules: Rules) -> dict[str, Any]:
        """What ``geometry_tolerance`` reads: the reference's error bound's inputs."""
        return {
            "band_scale": band_scales(scene, rules),
            "start_err": start_error(scene, rules),
            "reach": origin_reach(scene, rules),
            "sizes": shape_sizes(scene),
            "radii": [s.radius if isinstance(s, Ball) else 0.0 for s in scene.shapes],
            "why": "the reference's float64 error bound (minirt.oracles.exact.band_scales)",
        }
