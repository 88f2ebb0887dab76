"""What the sweep measures: every backend's series, the errors each is measured by, and the criteria.

Each backend says what it sweeps (minirt.model.backend, ``Backend.sweep``): its knobs, each a ``Series``
of settings with the rules it renders under, the converged answer (``Truth``) its error is measured
against, the kind of that error, its cost axis and what theory expects. ``catalogue`` collects them for
every registered backend, under the knobs the caller asked for; the sweep reads nothing else about a
backend.

Errors: colours are clipped to [0, 1] first (what the 8-bit image shows). RMSE is over pixels and
channels; FLIP is the mean LDR ꟻLIP (``flip_evaluator``, 67 pixels per degree) with the clipped
linear values taken as display values, as the exercise writes them without a gamma curve. Geometry:
``mask_mismatch`` is the fraction of pixels whose hit/miss differs, ``id_mismatch`` whose shape id
differs, ``t_rel_mean``/``t_rel_max`` the relative t error over pixels that hit the same shape.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from minirt.harness import backends as bk
from minirt.model.result import RenderResult
from minirt.model.rules import Rules
from minirt.model.scene import Scene
from minirt.model.series import Series, Setting

# The settings swept: per backend, by knob name ({"mitsuba": {"spp": (1, 4)}}); a backend or a knob not
# named sweeps that backend's defaults (its ``sweep_knobs``).
Knobs = Mapping[str, Mapping[str, Any]]

COLOR_LEVEL = 1 / 255  # one 8-bit level: a colour RMSE below it is an image error below one level
# A backend that does not shade has no 8-bit level. The harness's own geometry check grants it the bound
# it declares (Embree: the faceting bound of its level, oracles/embree.py precision_summary), so it passes
# at every level and cannot say which level is enough; the criterion is that check passing *and* the mean
# relative t error below the relative t tolerance the check holds an exact float32 intersector to (64 u32,
# Mitsuba's T_REL).
GEOMETRY_T_REL = 64 * 2.0**-24


# ---------------------------------------------------------------------------------------------
# Every backend's series


@dataclass(frozen=True)
class Catalogue:
    """Every registered backend's series under the sweep's knobs, by key ("backend/knob"), in the
    registry's order: sweep.json's ``series`` and ``knobs`` list them all, whichever backends ran."""

    series: dict[str, Series]

    def of(self, backend: str) -> list[Series]:
        return [s for s in self.series.values() if s.backend == backend]

    def swept(self, backend: str) -> bool:
        """Does ``backend`` declare its series here (False: unknown, or its module would not load)?"""
        return any(s.backend == backend for s in self.series.values())

    def setting(self, backend: str, knob: str | None, value: Any) -> Setting | None:
        s = self.series.get(f"{backend}/{knob}")
        return next((x for x in s.settings if x.value == value), None) if s else None

    def label(self, backend: str, knob: str | None, value: Any) -> str:
        """A setting as a reader names it: "the reference at 16 spp", "POV-Ray +A0.0 +R3"."""
        s = self.setting(backend, knob, value)
        return s.label if s else f"{backend} {knob}={value}"

    def candidate(self, key: str) -> bool:
        s = self.series.get(key)
        return s is not None and s.candidate

    def document(self) -> dict[str, dict[str, str]]:
        """sweep.json's ``series``: what each series is measured by, its cost axis, what theory expects."""
        return {k: {"metric": s.metric, "cost": s.cost, "theory": s.theory} for k, s in self.series.items()}

    def recorded(self, backend: str | None = None) -> dict[str, Any]:
        """The knob values the series were built from (``backend``'s, or all), as sweep.json's ``knobs``
        names them; a name two series record alike (a converged answer they share) keeps the first's."""
        out: dict[str, Any] = {}
        for s in self.series.values():
            if backend is None or s.backend == backend:
                for k, v in s.knobs.items():
                    out.setdefault(k, list(v) if isinstance(v, tuple) else v)
        return out


def catalogue(scene: Scene, rules: Rules, knobs: Knobs) -> Catalogue:
    """Every registered backend's series (``Backend.sweep``) with the knobs asked for; building them
    renders nothing. Knobs for a backend no one registered, or a knob a backend does not have, are a
    ValueError."""
    unknown = sorted(set(knobs) - set(bk.all_names()))
    if unknown:
        raise ValueError(f"knobs for unknown backend {', '.join(unknown)} (known: {', '.join(bk.all_names())})")
    out: dict[str, Series] = {}
    for name in bk.all_names():
        try:
            b = bk.get(name)
        except Exception:  # a broken install must not take the sweep down: its row says why (run_series)
            continue
        for s in b.sweep(scene, rules, dict(knobs.get(name, {}))):
            out[s.key] = s
    return Catalogue(out)


def rows_by_series(rows: list[dict[str, Any]]) -> dict[str, list[dict[str, Any]]]:
    """The measured rows of each series ("backend/knob"), in row order."""
    out: dict[str, list[dict[str, Any]]] = {}
    for r in rows:
        if r["status"] == "ok" and r["knob"]:
            out.setdefault(f"{r['backend']}/{r['knob']}", []).append(r)
    return out


def usable(r: dict[str, Any], metric: str) -> bool:
    """Can the row be plotted and fitted on log axes? Points with error 0 (below measurement) cannot."""
    e, s = r["error"].get(metric), r.get("seconds_median")
    return e is not None and math.isfinite(e) and e > 0 and s is not None and s > 0


# ---------------------------------------------------------------------------------------------
# Errors


def color_errors(test: np.ndarray, ref: np.ndarray, exposure: float = 1.0) -> dict[str, float]:
    """RMSE, largest absolute difference and mean ꟻLIP of two linear colour images, each multiplied by
    `exposure` and clipped to [0, 1]."""
    a = np.clip(np.nan_to_num(np.asarray(test, dtype=np.float64) * exposure, nan=0.0), 0.0, 1.0)
    b = np.clip(np.nan_to_num(np.asarray(ref, dtype=np.float64) * exposure, nan=0.0), 0.0, 1.0)
    out = {"rmse": float(np.sqrt(np.mean((a - b) ** 2))), "max_abs": float(np.max(np.abs(a - b)))}
    out["flip"] = flip(a, b)
    return out


def exposure(color: np.ndarray) -> float:
    """1 / the 99.9th percentile of the brightest channel per pixel (1 for a black image): a physically
    based renderer's colours are radiance (Mitsuba's: I / (pi r^2) falloff, ~1e-3 here), so errors are
    measured after scaling."""
    hi = float(np.percentile(np.max(np.nan_to_num(color), axis=-1), 99.9))
    return 1.0 / hi if hi > 0 and math.isfinite(hi) else 1.0


def flip(test: np.ndarray, ref: np.ndarray) -> float | None:
    """Mean LDR ꟻLIP of `test` against `ref` (values in [0, 1] taken as display values); None if unavailable."""
    try:
        import flip_evaluator
    except ImportError:
        return None
    if np.array_equal(test, ref):
        return 0.0
    _, mean, _ = flip_evaluator.evaluate(
        np.ascontiguousarray(ref, dtype=np.float32), np.ascontiguousarray(test, dtype=np.float32), "LDR",
        inputsRGB=True, applyMagma=False, computeMeanError=True,
    )  # fmt: skip
    return float(mean)


def geometry_errors(test: RenderResult, ref: RenderResult) -> dict[str, float]:
    """Hit/id mismatch fractions and relative t error (over pixels hitting the same shape)."""
    n = ref.hit.size
    same = ref.hit & test.hit & (ref.shape_id == test.shape_id)
    out = {
        "mask_mismatch": float(np.count_nonzero(ref.hit != test.hit) / n),
        "id_mismatch": float(np.count_nonzero(ref.shape_id != test.shape_id) / n),
        "t_rel_mean": 0.0,
        "t_rel_max": 0.0,
        "compared": int(np.count_nonzero(same)),
    }
    if out["compared"]:
        rel = np.abs(test.t[same] - ref.t[same]) / np.abs(ref.t[same])
        out["t_rel_mean"] = float(np.mean(rel))
        out["t_rel_max"] = float(np.max(rel))
    return out


def harness_geometry(scene: Scene, rules: Rules, ref: RenderResult, res: RenderResult) -> dict[str, Any]:
    """The harness's own geometry check (``minirt check``'s tolerances: silhouette band, t and normal
    bounds from the oracle's declared precision): its verdict and the pixels beyond tolerance."""
    from minirt.harness.geometry import check_geometry

    g = check_geometry(scene, rules, ref, res)
    f = g.figures
    beyond = sum(int(f.get(k, 0)) for k in ("mask_mismatch_outside_band", "id_mismatch", "depth_violations",
                                             "normal_violations"))  # fmt: skip
    return {"geometry_check": g.verdict, "geometry_beyond_tolerance": beyond}


def _color(scene: Scene, rules: Rules, res: RenderResult, ref: RenderResult) -> dict[str, Any]:
    return color_errors(res.color, ref.color)


def _color_exposure(scene: Scene, rules: Rules, res: RenderResult, ref: RenderResult) -> dict[str, Any]:
    e = exposure(ref.color)
    return {**color_errors(res.color, ref.color, e), "exposure": e}


def _geometry_color(scene: Scene, rules: Rules, res: RenderResult, ref: RenderResult) -> dict[str, Any]:
    return {**geometry_errors(res, ref), **color_errors(res.color, ref.color)}


def _geometry_check(scene: Scene, rules: Rules, res: RenderResult, ref: RenderResult) -> dict[str, Any]:
    return {**geometry_errors(res, ref), **harness_geometry(scene, rules, ref, res)}


# A series' error kind (Series.error): its render (res) against the converged one (ref), on the sweep's
# scene under the series' rules. "color_exposure" returns the exposure it matched: the sweep records it
# with the converged answer.
ERRORS: dict[str, Callable[[Scene, Rules, RenderResult, RenderResult], dict[str, Any]]] = {
    "color": _color,
    "color_exposure": _color_exposure,
    "geometry+color": _geometry_color,
    "geometry+check": _geometry_check,
}
