"""A backend that gives only a colour image -- a student's program (minirt.oracles.program) -- checked
against the reference: no geometry buffers, so no geometry check; its image compared with the
reference's level by level, as any oracle of the exercise's model is (minirt.harness.shading).

- Pre-flight: the image is there, of the reference's size.
- Geometry: SKIP, with the reason: there is no hit mask, t, normal or shape id to compare. Never PASS.
- Shading: minirt.harness.shading's ``shading_exercise`` on the 8-bit images, off the pixels no per-pixel
  comparison judges: the reference's edge classes (silhouettes, shadow edges, terminators, down the ray
  tree) and the band of primary rays whose hit/miss, closest-shape or inside decision is within
  ``BAND_EPS`` of flipping. A backend that records no precision of its own (a program does not) gets the
  rule diagnosis's band (minirt.diagnose.EPS_REL: the decisions a float32 tracer may take either way), so
  a program traced in float32 is not failed for its rounding, and the check and ``minirt grade`` leave the
  same primary pixels out. A colour that is NaN or infinite where the reference's is finite, off those
  pixels, is a numerical failure: FAIL, counted.
- Honesty: a comparison that judges less than half the image (THRESHOLDS "inconclusive_fraction", the
  geometry check's own limit) could not have failed on most of it: WARN, inconclusive, never PASS.
- A scene of several samples a pixel: a program's samples are not the reference's (their positions are its
  own), so a per-pixel comparison would fail correct images on every edge: SKIP, with the reason.
"""

from __future__ import annotations

import numpy as np

from minirt.diagnose import EPS_REL
from minirt.harness import backends
from minirt.harness.references import ReferenceCache
from minirt.harness.results import INCONCLUSIVE, Check
from minirt.harness.shading import edge_classes, edge_pixels, shading_exercise
from minirt.harness.tolerances import THRESHOLDS
from minirt.model import bitmap
from minirt.model.result import RenderResult
from minirt.model.rules import Rules
from minirt.model.scene import Scene

BAND_EPS = EPS_REL  # see the module's docstring: the rule diagnosis's ill-conditioned primary rays


def gives_only_an_image(res: RenderResult) -> bool:
    """A result with a colour image and none of the geometry buffers a geometry check compares."""
    return res.color is not None and all(getattr(res, n) is None for n in ("hit", "shape_id", "t", "normal"))


def preflight_image(ref: RenderResult, res: RenderResult) -> Check:
    if (res.width, res.height) != (ref.width, ref.height) or res.color.shape[:2] != (ref.height, ref.width):
        h, w = res.color.shape[:2]
        return Check("fail", reason=f"image {w}x{h}, expected {ref.width}x{ref.height}")
    return Check("pass")


def check_image_only(scene: Scene, rules: Rules, name: str, refs: ReferenceCache, res: RenderResult) -> dict:
    """The checks of a backend's image-only result (``gives_only_an_image``): pre-flight, geometry (SKIP),
    shading, in that order, by name (see the module's docstring). ``rules``: the rules it follows."""
    ref = refs.get(rules, samples=1)
    who = backends.display_name(name)
    checks = {"preflight": preflight_image(ref, res)}
    geometry = f"{who} gives only an image: no hit mask, t, normal or shape id to compare"
    checks["geometry"] = Check("skip", reason=geometry)
    if checks["preflight"].verdict == "fail":
        return checks
    if scene.samples > 1:
        checks["shading"] = Check(
            "skip",
            reason=f"the scene takes {scene.samples} samples a pixel, and {who}'s samples are not the reference's: "
            "no per-pixel comparison (check a scene of one sample a pixel)",
        )
        return checks
    margin = refs.rays(rules).margins(bound=BAND_EPS)["margin"].reshape(ref.height, ref.width)
    band = margin < BAND_EPS
    classes = edge_classes(ref)
    edges = edge_pixels(classes, band)
    shading = shading_exercise(ref, res, classes, edges)
    shading.figures["band_pixels"] = int(band.sum())
    shading.thresholds["band"] = (
        f"primary-ray margin < {BAND_EPS:.3g}: the decisions a float32 tracer may take either way "
        "(minirt.diagnose.EPS_REL); a program records no precision of its own"
    )
    checks["shading"] = _honest(shading, ref, res, edges)
    return checks


def _honest(shading: Check, ref: RenderResult, res: RenderResult, edges: np.ndarray) -> Check:
    """The shading check with its two verdicts an image-only comparison adds: a non-finite colour off the
    edges fails; a comparison that judges less than half the image is inconclusive (WARN), never PASS."""
    bad = bitmap.channel_any(~np.isfinite(res.color) & np.isfinite(ref.color)) & ~edges
    shading.figures["nonfinite_color"] = int(bad.sum())
    if bad.any():
        said = f"NaN or infinite colour at {int(bad.sum())} pixel(s) off the edges"
        shading.reason = f"{said}; {shading.reason}" if shading.verdict == "fail" else said
        shading.verdict = "fail"
        return shading
    limit = THRESHOLDS["inconclusive_fraction"]
    judged = shading.figures["compared_pixels"] / max(ref.hit.size, 1)
    shading.thresholds["inconclusive"] = f"{limit.value}: {limit.why}"
    if shading.verdict == "pass" and judged < 1.0 - limit.value:
        shading.verdict = "warn"
        shading.reason = (
            f"{INCONCLUSIVE}the edges and the band hold {1.0 - judged:.0%} of the pixels, more than "
            f"{limit.value:.0%}: the colour is compared on {shading.figures['compared_pixels']} only"
        )
    return shading
