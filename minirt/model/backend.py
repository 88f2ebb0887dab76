"""What every backend is: the reference tracer and each oracle behind one interface.

A backend takes a parsed Scene and the model Rules and returns a RenderResult (minirt.model.result),
the one result type, with timings and the exact commands or parameters it used in ``meta``. It never
raises for a renderer's failure: it returns a result with status "error" (the renderer broke) or
"skip" (not installed, or the scene cannot be reproduced), and a one-line reason.

Everything minirt knows about a backend is said here, by the backend itself: its display name, its
precision, the model its colour follows, whether it runs beside the others, the memory it holds per
pixel, the command-line options it takes, the rules it can follow, its geometry tolerance with the
derivation, its sweep knob and its export. Nothing outside a backend's own module asks which backend it
is. The reference tracer (minirt.reference.backend) implements this interface as every oracle
(minirt.oracles) does; minirt.harness.backends finds each by name.

Rules: a backend declares, per model rule, the values it can reproduce (``supported``). The harness
renders the reference under ``adapt(rules)`` -- the requested rules with every unsupported value
replaced by one the backend can do -- and compares like with like; the rules changed are the ones the
attribution step reports.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from minirt.model import rules as rules_mod
from minirt.model.result import RenderResult
from minirt.model.rules import Rules
from minirt.model.scene import Scene

U32 = 2.0**-24  # float32 unit round-off
U64 = 2.0**-53


@dataclass
class GeometryTolerance:
    """Per-pixel tolerances for one backend's geometry buffers against the float64 reference."""

    band: np.ndarray  # bool (H, W): decisions within the backend's precision of flipping
    t_abs: np.ndarray  # float (H, W): allowed |t_backend - t_ref|
    normal_deg: np.ndarray  # float (H, W): allowed angle between normals
    why: dict[str, str] = field(default_factory=dict)
    summary: dict[str, float | str] = field(default_factory=dict)  # figures; "<key>_reason" beside a non-finite one
    # bool (H, W) or None: where two shapes' nearest hits are a depth tie at the backend's per-shape precision
    # (an id mismatch there is not a defect); None: the harness's scene-wide rule, id_tie < 4 band_eps
    ties: np.ndarray | None = None
    # bool (H, W) or None: the pixels the backend rendered (None: every pixel). The others are in ``band`` (not
    # judged) and out of the fractions that make a check inconclusive: a sampled render is judged where it is.
    traced: np.ndarray | None = None


@dataclass(frozen=True)
class Margins:
    """What the harness measured of the checked rays, for a backend to turn into its tolerance.

    ``margins``: minirt.reference.band.margins of the reference's primary rays, flat per ray (margin,
    origin, silhouette, grazing, tie, near, id_tie, hit_nd, hit_cos, origin_norm); ``margin``, ``origin`` and
    ``silhouette`` exact below ``bound`` and inf elsewhere (the rest exact): compare them with a threshold
    through ``below``, which widens the bound when the threshold is larger (``widen(eps)``: the margins
    exact below eps). ``start(t_min=, plane_err=, ball_err=)``: minirt.reference.band.start_band on the same
    rays, the rays whose "does this candidate count" decision lies within the backend's position error of
    its minimum distance (None: no such band). ``scaled(scale=, origin_scale=, inside_scale=, tie_scale=)``:
    the margins with per-shape scales, exact below 1 (what ``per_shape_band`` compares), for a backend that
    records them (None: the scene-wide threshold)."""

    margins: dict[str, np.ndarray]
    start: Callable[..., np.ndarray] | None = None
    scaled: Callable[..., dict[str, np.ndarray]] | None = None
    bound: float = math.inf
    widen: Callable[[float], dict[str, np.ndarray]] | None = None

    def below(self, key: str, eps: float, h: int, w: int) -> np.ndarray:
        """(H, W) bool: ``margins[key] < eps``, exact whatever eps (``margin``, ``origin``, ``silhouette``
        are known exactly only below ``bound``: a larger eps asks ``widen`` for them)."""
        m = self.margins if eps <= self.bound or self.widen is None else self.widen(eps)
        return m[key].reshape(h, w) < eps

    def image(self, h: int, w: int) -> dict[str, np.ndarray]:
        return {k: v.reshape(h, w) for k, v in self.margins.items()}

    def start_band(self, h: int, w: int, **kw) -> np.ndarray:
        return np.zeros((h, w), dtype=bool) if self.start is None else self.start(**kw).reshape(h, w)

    def per_shape_band(self, p: dict, h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
        """(band, ties), both bool (H, W), from the per-shape scales a backend records (``band_scale`` and
        the optional ``band_origin_scale``, ``band_inside_scale``, ``band_tie_scale``): a ray is in the band
        where a margin divided by its shape's scale is below 1; an id mismatch is a depth tie where the
        id-tie margin divided by the pair's scale is below 4 -- the scene-wide rule id_tie < 4 band_eps with
        each pair's own scale for band_eps (one scene-wide value excused every id mismatch beside a far
        ball: defect campaign f32_2027_22, ids-swapped passed POV-Ray on judged pixels)."""
        m = self.scaled(
            scale=p["band_scale"],
            origin_scale=p.get("band_origin_scale"),
            inside_scale=p.get("band_inside_scale"),
            tie_scale=p.get("band_tie_scale"),
        )
        return m["margin"].reshape(h, w) < 1.0, m["id_tie"].reshape(h, w) < 4.0


def farthest_hit(p: dict) -> float:
    """The farthest t along the harness's rays at which a backend that records ``max_distance`` (POV-Ray's
    MAX_DISTANCE from its own ray's origin, ``max_distance_lift`` before the harness's) still reports a
    hit, less 1e-6 of it for the rounding of t; inf for a backend without one."""
    return p.get("max_distance", math.inf) * (1 - 1e-6) - p.get("max_distance_lift", 0.0)


def tolerance_inputs(
    result: RenderResult, ref: RenderResult, measured: Margins
) -> tuple[int, int, dict[str, Any], dict[str, np.ndarray], np.ndarray]:
    """What every ``geometry_tolerance`` starts from: the image's height and width, the precision the backend
    recorded (``result.meta["precision"]``, {} if none), the measured margins as (H, W) images, and the
    reference's t (0 where it misses)."""
    h, w = ref.height, ref.width
    return h, w, result.meta.get("precision") or {}, measured.image(h, w), np.where(ref.hit, ref.t, 0.0)


def generic_tolerance(result: RenderResult, ref: RenderResult, measured: Margins) -> GeometryTolerance:
    """The tolerance of a backend that records only generic keys in ``meta["precision"]`` (``band_eps``,
    ``t_rel``, ``t_abs``, ``normal_deg``), or a result no registered backend made (a test's)."""
    h, w, p, _, t_ref = tolerance_inputs(result, ref, measured)
    eps = p.get("band_eps", 1e-6)
    band = measured.below("margin", eps, h, w)
    t_abs = p.get("t_rel", 1e-6) * t_ref + p.get("t_abs", 0.0)
    nd = np.full((h, w), p.get("normal_deg", 1e-3))
    why = {"band": f"margin < {eps:.3g}", "t": "t_rel*t + t_abs from the backend", "normal": "normal_deg"}
    return GeometryTolerance(band=band, t_abs=t_abs, normal_deg=nd, why=why, summary={"band_eps": eps})


@dataclass(frozen=True)
class Setting:
    """One turn of a backend's accuracy knob in the sweep (minirt.sweep): one row of its table."""

    value: Any  # the knob's setting, as the sweep's rows record it
    cost: float  # on the series' cost axis (bits, samples per pixel, triangles per ball, ...)
    options: dict[str, Any]  # the backend's render options for it
    label: str  # as a reader names it, in the sweep's answer: "the reference at 16 spp"
    progress: str  # what the progress line says while it renders: "reference 16 spp"
    samples: int | None = None  # the scene's samples per pixel for it (None: the sweep's scene, one sample)


@dataclass(frozen=True)
class Truth:
    """What a series' error is measured against: a converged render, made once per sweep -- by the first
    row that needs it -- and shared by every series of the same backend that names the same ``key``."""

    key: str  # its name in the sweep's document ("reference/1024spp")
    backend: str  # rendered by this backend (its name) ...
    options: dict[str, Any]  # ... with these options
    samples: int | None = None  # the scene's samples per pixel for it (None: the sweep's scene, one sample)
    rules: Rules | None = None  # under these rules (None: the series' own)
    describe: dict[str, Any] = field(default_factory=dict)  # recorded in the sweep's document beside them


# A per-run time of one render: (the time of the render itself, its per-run start-up, the timer's resolution;
# 0: fine-grained). See Series.seconds.
Seconds = Callable[[RenderResult], tuple[float, float, float]]


@dataclass(frozen=True)
class Series:
    """One knob of a backend, swept: its settings, the rules it renders under and what its error is.

    ``error``: "color" (RMSE and friends against the truth's colour), "color_exposure" (the same after
    matching exposure: a physically based renderer's units), "geometry+color" (the reference's own
    precision: geometry and colour against the truth) or "geometry+check" (a geometry-only backend: its
    buffers against the truth's and the harness's own verdict). ``metric``, ``cost`` and ``theory`` are
    what the sweep's document says of the series (its error measure, its cost axis, what theory expects);
    ``knobs`` the values it was built from, under the names the document's ``knobs`` gives them."""

    backend: str  # rendered by this backend (its name)
    knob: str
    settings: tuple[Setting, ...]
    rules: Rules
    truth: Truth
    error: str
    metric: str  # the error the series is read by ("rmse", "t_rel_mean"): its plot, fit and Pareto front
    cost: str  # what the cost axis counts
    theory: str  # how theory expects the error to fall with the cost
    knobs: dict[str, Any] = field(default_factory=dict)
    candidate: bool = True  # may answer "what does an error below the criterion cost" (the sweep's answer)
    fit: bool = True  # fit a slope to it (not to two points, one of them the truth itself)
    level_factor: float | None = None  # the cost's factor per knob step: the fit gives its factor per level
    # (time of the render, per-run start-up, timer resolution) of one result; None: the render's wall clock
    # (minirt.harness.backends.render), no start-up, fine-grained
    seconds: Seconds | None = None

    @property
    def key(self) -> str:
        return f"{self.backend}/{self.knob}"


class Backend:
    """The interface of every backend (see the module's docstring). Class attributes are facts about the
    backend, read without rendering (and without importing its renderer)."""

    name: ClassVar[str] = ""
    display_name: ClassVar[str] = ""  # as pages name it ("POV-Ray")
    shades: ClassVar[bool] = False  # does it produce a colour image?
    # How its colour relates to the exercise's model: "exercise" (the same model, compared level by level),
    # "physical" (a physically based renderer's, compared statistically), None (no colour)
    shading_model: ClassVar[str | None] = None
    float32: ClassVar[bool] = False  # traces in float32 (a render warns about the scene's float32 hazards)
    concurrent: ClassVar[bool] = False  # runs beside the others in a check (its work is in its own process)
    reports_progress: ClassVar[bool] = False  # takes options["progress"], a callable(done, total)
    # Memory, bytes per pixel (minirt.jobs.memory, fitted to measured peaks): a check keeps its render and
    # figures (check_kept); a render keeps its result (render_kept) while one render runs (render_running).
    check_kept: ClassVar[int] = 1400
    render_kept: ClassVar[int] = 220
    render_running: ClassVar[int] = 430
    packages: ClassVar[tuple[str, ...]] = ()  # the Python distributions it renders with (`minirt doctor`)
    export_as: ClassVar[str | None] = None  # `minirt export --to NAME`; None: no export
    export_what: ClassVar[str] = ""  # what that export writes, for --help
    # rule name -> values this backend reproduces, preferred first. A rule not listed: any value -- except
    # the rules from real solutions' bugs (rules.BUG_RULES), which a backend follows only at their
    # defaults unless it lists them or ``follows_bugs`` says it follows every one (the reference does).
    supported: ClassVar[dict[str, tuple[Any, ...]]] = {}
    follows_bugs: ClassVar[bool] = False

    def available(self) -> tuple[bool, str]:
        """(usable, reason or version line)."""
        raise NotImplementedError

    def version(self) -> str:
        raise NotImplementedError

    def adapt(self, rules: Rules) -> Rules:
        """The closest rules this backend can follow."""
        changes = {}
        for name, values in self.supported.items():
            if getattr(rules, name) not in values:
                changes[name] = values[0]
        if not self.follows_bugs:
            for name in rules_mod.BUG_RULES:
                if name not in self.supported and getattr(rules, name) != rules_mod.default(name):
                    changes[name] = rules_mod.default(name)
        return replace(rules, **changes)

    def cannot_follow(self, rules: Rules) -> list[str]:
        return rules.differs(self.adapt(rules))

    def options(self, precision: str = "f64", samples: int | None = None, timeout: float | None = None) -> dict:
        """The render options for the command line's (and the API's) --precision, --samples and --timeout:
        each backend takes those it has a meaning for."""
        return {"precision": precision}

    def is_float32(self, options: dict[str, Any]) -> bool:
        """Does a render with these options trace in float32?"""
        return self.float32

    # Does a check ask ``check_options`` before rendering (it then renders after the reference)?
    chooses_pixels: ClassVar[bool] = False

    def check_options(self, scene: Scene, reference: RenderResult) -> dict[str, Any]:
        """Options for the render a check compares with ``reference`` (the reference's own render of the
        scene under the rules this backend follows, one ray a pixel, with its diagnostics): a backend too
        slow to render every pixel of a large image names the pixels worth its time (``chooses_pixels``)."""
        return {}

    def runs_apart(self, options: dict[str, Any]) -> bool:
        """Whether its render with these options works in processes of its own, so that a check starts it
        beside the others' work (minirt.harness.compare.start_ahead): ``concurrent``, by default."""
        return self.concurrent

    def render(self, scene: Scene, rules: Rules, options: dict[str, Any] | None = None) -> RenderResult:
        """Render under `rules` (already adapted by the caller); options are backend-specific, and a
        backend that ``reports_progress`` is given ``options["progress"]``, called as ``progress(done, total)``."""
        raise NotImplementedError

    def streams(self, scene: Scene, rules: Rules) -> bool:
        """Would this render be written tile by tile as it is traced (``tiles``), in bounded memory?"""
        return False

    def tiles(
        self, scene: Scene, rules: Rules, options: dict[str, Any] | None = None, progress=None
    ) -> Iterator[tuple[int, RenderResult]]:
        """The image as (first row, tile) pairs, top to bottom (where ``streams`` says so)."""
        raise NotImplementedError

    def export(self, scene: Scene, rules: Rules, out_dir: Path, options: dict[str, Any] | None = None) -> list[Path]:
        """Write the scene as a user would open it in this renderer; return the files written."""
        raise NotImplementedError

    def geometry_tolerance(self, result: RenderResult, ref: RenderResult, measured: Margins) -> GeometryTolerance:
        """Translate this backend's recorded precision (``result.meta["precision"]``) into per-pixel
        tolerances, each with its derivation (``why``)."""
        return generic_tolerance(result, ref, measured)

    # The sweep's knobs (minirt.sweep): their defaults, by name (none: nothing to sweep).
    sweep_knobs: ClassVar[dict[str, Any]] = {}

    def sweep(self, scene: Scene, rules: Rules, knobs: dict[str, Any]) -> list[Series]:
        """What accuracy costs in time: this backend's knobs, each a series of settings (minirt.sweep).
        ``knobs``: the settings the caller asked for, by knob name (absent: ``sweep_knobs``'s defaults; see
        ``turned``). Building the series renders nothing: the sweep renders them."""
        return []

    def turned(self, knobs: dict[str, Any]) -> dict[str, Any]:
        """``sweep_knobs`` with the caller's settings in place of the defaults; a knob this backend does not
        have is a ValueError (a misspelt knob would sweep the defaults unnoticed)."""
        unknown = sorted(set(knobs) - set(self.sweep_knobs))
        if unknown:
            known = ", ".join(self.sweep_knobs) or "none"
            raise ValueError(f"{self.name}: no sweep knob {', '.join(unknown)} (its knobs: {known})")
        return {**self.sweep_knobs, **knobs}
