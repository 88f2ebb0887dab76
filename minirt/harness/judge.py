"""The judge of last resort: a certified oracle settles the pixels float oracles cannot, or dispute.

A certified oracle is a backend whose decisions are the exact model's (``certified = True``; found in the
registry by that capability, never by name). Its render carries, per pixel, whether the pixel is *robust*
-- every decision of its ray tree certified even with every ray, hit point and plane widened by far more
than float64's rounding -- and the bounds any tracer within that widening must give: t, the normal and
the colour (``aux`` "robust", "t_lo", "t_hi", "normal_lo", "normal_hi", "color_lo", "color_hi"); t and the
normal also where only the primary ray's decisions are robust ("robust_geometry"). There:

- the reference is *certified wrong* (``reference_errors``) where its hit/miss or shape id differs from the
  certified one, or its t, normal or 8-bit colour lies outside those bounds (the colour widened by
  ``COLOR_MARGIN`` for its own float64 sums, then rounded to 8 bits as the check does);
- a float oracle that disagrees with the reference where the reference is certified right is *imprecise*
  there: its disagreement is its own (``review``).

Pixels that are not robust (a decision within the widening of flipping), exact ties and pixels not traced
are not settled: neither the reference nor the oracle is blamed there. ``review`` makes a float oracle's
check FAIL where the judge certifies the reference wrong, and its FAIL a WARN where the judge certifies the
reference everywhere it can: a FAIL stands only where the reference is certified wrong. ``certify`` gives
the certified oracle's own check the same verdict: FAIL exactly when the reference is certified wrong.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from minirt.harness import backends
from minirt.harness.results import Check, worst
from minirt.harness.tolerances import THRESHOLDS
from minirt.model.result import RenderResult, to8
from minirt.model.rules import Rules
from minirt.model.scene import Scene

# The reference's colour is a float64 sum of a few terms per level, each rounded: its error is below 2^-40 of
# the colours' sizes (at most a few units), far below this; the certified bounds do not include it.
COLOR_MARGIN = 2.0**-30
# A normal's components: the reference's (p - C) / r errs by a few ulps of 1 beyond its hit point's error,
# which the bounds include.
NORMAL_MARGIN = 2.0**-40
KINDS = ("hit", "id", "t", "normal", "color")


def certified_oracle() -> str | None:
    """The first registered oracle that is certified and available (None: none)."""
    for name in backends.oracle_names():
        b = backends.get(name)
        if getattr(b, "certified", False) and b.available()[0]:
            return name
    return None


def is_certified(name: str) -> bool:
    b = backends.find(name)
    return bool(b is not None and getattr(b, "certified", False))


@dataclass
class Ruling:
    """What the judge found of one reference render (and, reviewing, of one oracle's disagreement)."""

    judge: str
    settled: np.ndarray  # (H, W) bool: robust pixels, traced and not ties: where the judge speaks
    reference_wrong: np.ndarray  # (H, W) bool: the reference certified wrong
    kinds: dict[str, int] = field(default_factory=dict)  # certified-wrong pixels per kind (KINDS)
    disputed: np.ndarray | None = None  # the oracle's disagreements under review
    oracle_wrong: np.ndarray | None = None  # disputed, settled for the reference: the oracle's imprecision
    seconds: float = 0.0

    def figures(self) -> dict[str, Any]:
        h, w = self.settled.shape
        out: dict[str, Any] = {
            "judge": self.judge,
            "pixels": h * w,
            "settled_pixels": int(self.settled.sum()),
            "reference_wrong": int(self.reference_wrong.sum()),
            "reference_wrong_by_kind": self.kinds,
            "reference_wrong_first": _first(self.reference_wrong),
        }
        if self.disputed is not None and self.oracle_wrong is not None:
            out["disputed"] = int(self.disputed.sum())
            out["oracle_imprecise"] = int(self.oracle_wrong.sum())
            out["oracle_imprecise_first"] = _first(self.oracle_wrong)
            out["unsettled"] = int((self.disputed & ~self.settled).sum())
        out["seconds"] = round(self.seconds, 3)
        return out


def _first(mask: np.ndarray, n: int = 10) -> list[list[int]]:
    """The first ``n`` pixels of a mask as (x, y), row-major."""
    ys, xs = np.nonzero(mask)
    return [[int(x), int(y)] for x, y in zip(xs[:n], ys[:n], strict=True)]


def reference_errors(ref: RenderResult, exact: RenderResult) -> tuple[np.ndarray, np.ndarray, dict[str, int]]:
    """(settled, wrong, kinds): the pixels the certified render ``exact`` settles, those where ``ref`` is
    certified wrong, and how many of those per kind (module docstring)."""
    a = exact.aux
    h, w = ref.height, ref.width
    traced = a.get("rendered", np.ones((h, w), dtype=bool)) & ~a.get("exact_tie", np.zeros((h, w), bool))
    settled = traced & a["robust"]
    # the primary ray's decisions may be robust where a deeper one is not: hit, id, t and normal settled there
    geometry = traced & a.get("robust_geometry", a["robust"])
    hit = ref.hit != exact.hit
    ids = ref.hit & exact.hit & (ref.shape_id != exact.shape_id)
    both = ref.hit & exact.hit & ~ids
    with np.errstate(invalid="ignore"):
        t = both & ~((ref.t >= a["t_lo"]) & (ref.t <= a["t_hi"]))
        inside = (ref.normal >= a["normal_lo"] - NORMAL_MARGIN) & (ref.normal <= a["normal_hi"] + NORMAL_MARGIN)
        normal = both & ~inside.all(-1)
    c8 = ref.color8().astype(int)
    lo8, hi8 = to8(a["color_lo"] - COLOR_MARGIN).astype(int), to8(a["color_hi"] + COLOR_MARGIN).astype(int)
    color = ((c8 < lo8) | (c8 > hi8)).any(-1)
    masks = {"hit": hit, "id": ids, "t": t, "normal": normal, "color": color}
    wrong = np.zeros((h, w), dtype=bool)
    kinds = {}
    for k in KINDS:
        m = (settled if k == "color" else geometry) & masks[k]
        kinds[k] = int(m.sum())
        wrong |= m
    return settled, wrong, kinds


def render_certified(scene: Scene, rules: Rules, name: str | None = None) -> RenderResult | None:
    """The certified oracle's render of the scene under ``rules`` (None: no certified oracle, or it failed)."""
    name = name or certified_oracle()
    if name is None:
        return None
    res = backends.render(name, scene, rules)
    return res if res.ok else None


def rule(ref: RenderResult, exact: RenderResult, disputed: np.ndarray | None = None) -> Ruling:
    settled, wrong, kinds = reference_errors(ref, exact)
    r = Ruling(exact.backend, settled, wrong, kinds, seconds=float(exact.meta.get("timings", {}).get("total", 0.0)))
    if disputed is not None:
        r.disputed = disputed
        r.oracle_wrong = disputed & settled & ~wrong
    return r


def disputed_pixels(checks: dict[str, Check], ref: RenderResult) -> np.ndarray:
    """The pixels where a float oracle's checks found it at odds with the reference: hit/miss and ids outside
    its band, t and normals beyond its tolerances, colours beyond a level off edges, lit/unlit flips."""
    h, w = ref.height, ref.width
    out = np.zeros((h, w), dtype=bool)
    g = checks.get("geometry")
    if g is not None and g.images:
        im = g.images
        judged = ~im["band"]
        out |= im["mask_outside_band"] | im["id_mismatch"]
        with np.errstate(invalid="ignore"):
            dt = im["depth_rel_err"] * np.abs(np.where(ref.hit, ref.t, 0.0))
            out |= judged & (dt > im["t_tolerance"])
            out |= judged & (im["normal_deg"] > im["normal_tolerance"])
    s = checks.get("shading")
    if s is not None and s.images:
        im = s.images
        if "color8_diff" in im:
            out |= (im["color8_diff"] > THRESHOLDS["color8_levels"].value) & ~im["edges"]
        if "lit_mismatch" in im:
            out |= im["lit_mismatch"]
        if "diffuse_rel_err" in im:
            out |= (im["diffuse_rel_err"] > THRESHOLDS["diffuse_rel"].value) & ~im["not_judged"]
    return out


def review(bc, scene: Scene, rules: Rules, certified: str | None = None, renders: dict | None = None):
    """A float oracle's check (minirt.harness.results.BackendCheck) with the judge's ruling under the rules the
    oracle follows: where the judge certifies the reference wrong the check FAILs, whatever the oracle's own
    bands let through; otherwise a FAIL of its geometry or shading is the oracle's imprecision where the judge
    settles the disagreement for the reference (a WARN saying so). A skip or an error, a check that failed
    elsewhere (pre-flight, samples) and a certified oracle's own check are returned as they are. The ruling
    is kept as the check "judge" (figures and masks). ``renders``: a dict the certified renders are kept
    in, by rules, to be reused by the next review of the same scene."""
    certified = certified or certified_oracle()
    failing = [k for k, c in bc.checks.items() if c.verdict == "fail"]
    if bc.verdict not in ("pass", "warn", "fail") or certified is None or is_certified(bc.backend):
        return bc
    if bc.reference is None or any(k not in ("geometry", "shading") for k in failing):
        return bc
    followed = backends.rules_for(bc.backend, rules)
    renders = {} if renders is None else renders
    if followed not in renders:
        renders[followed] = render_certified(scene, followed, certified)
    exact = renders[followed]
    if exact is None:
        return bc
    r = rule(bc.reference, exact, disputed_pixels(bc.checks, bc.reference))
    images = {"reference_wrong": r.reference_wrong, "oracle_imprecise": r.oracle_wrong, "settled": r.settled}
    if r.reference_wrong.any():
        # certified wrong: a FAIL, whatever the oracle's own check could see (a change inside its bands)
        where = ", ".join(f"{k} {n}" for k, n in r.kinds.items() if n)
        reason = f"the reference certified wrong at {int(r.reference_wrong.sum())} pixel(s) ({where}) by {certified}"
        bc.checks["judge"] = Check("fail", r.figures(), reason, images=images)
        bc.reason = f"judge: {reason}" + (f"; {bc.reason}" if bc.reason else "")
        bc.verdict = "fail"
        return bc
    if bc.verdict != "fail":
        return bc
    n, unsettled = int(r.oracle_wrong.sum()), int((r.disputed & ~r.settled).sum())
    reason = (f"{bc.backend}'s imprecision: it disagrees with the reference at {int(r.disputed.sum())} pixel(s); "
              f"exact arithmetic ({certified}) settles {n} for the reference"
              + (f", {unsettled} within the reference's own rounding (unsettled)" if unsettled else "")
              + f", and finds the reference right wherever it can judge (was: {bc.reason})")  # fmt: skip
    bc.checks["judge"] = Check("warn", r.figures(), reason, images=images)
    for k in failing:
        c = bc.checks[k]
        c.verdict, c.reason = "warn", f"settled against {bc.backend} by the judge: {c.reason}"
    bc.verdict = worst([c.verdict for c in bc.checks.values()])
    bc.reason = reason
    return bc


def certify(bc, exact: RenderResult | None = None):
    """A certified oracle's own check with the judge's verdict: FAIL exactly where the reference is certified
    wrong (at robust pixels, beyond its bounds, any kind); a FAIL of the harness's per-pixel comparison that
    the judge does not confirm -- a pixel the bounds allow -- is a WARN saying so."""
    exact = exact or bc.result
    if bc.reference is None or exact is None or not exact.ok or "robust" not in exact.aux:
        return bc
    r = rule(bc.reference, exact)
    images = {"reference_wrong": r.reference_wrong, "settled": r.settled}
    if r.reference_wrong.any():
        where = ", ".join(f"{k} {n}" for k, n in r.kinds.items() if n)
        reason = f"the reference certified wrong at {int(r.reference_wrong.sum())} pixel(s) ({where})"
        bc.checks["judge"] = Check("fail", r.figures(), reason, images=images)
        bc.verdict = "fail"
        bc.reason = f"judge: {reason}" + (f"; {bc.reason}" if bc.reason else "")
        return bc
    bc.checks["judge"] = Check("pass", r.figures(), images=images)
    if bc.verdict == "fail":
        for c in bc.checks.values():
            if c.verdict == "fail":
                c.verdict, c.reason = "warn", f"within the reference's certified bounds: {c.reason}"
        bc.verdict = worst([c.verdict for c in bc.checks.values()])
        bc.reason = f"not confirmed by the judge (the reference within its certified bounds): {bc.reason}"
    return bc
