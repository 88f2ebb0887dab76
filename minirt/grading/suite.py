"""The scenes a program is graded over (``minirt grade --program``): the grading set plus scenes designed
so that every pair of listed values of every rule of the table draws different pictures somewhere, and
the numbers read off images (the offset, t_max, the specular exponent) are pinned to a narrow interval.

Each designed scene (scenes/suite/*.toml, its ``description`` says how it works) exists for a question
the grading set leaves open at the suite's size:

- ``offset_coarse``, ``offset_middle``, ``offset_fine``: the secondary rays' offset. Two walls crossing at
  a hair's angle, each blocking the other's light; a point is lit only where the offset carries its
  shadow ray's start past the other wall, so the border between lit and dark is the line gap = offset.
  Three scales (gaps up to 1.2e-2, 2.5e-4 and 6e-6) read offsets from ~1e-7 to ~1e-2 to within 1 %, along
  the normal and along the ray alike (the grading set told 1e-4 from 1e-6 on 19 pixels at most, and under
  the 2014 edition's offset along the ray not at all).
- ``highlight``: the specular exponent. A bright light beside the camera spreads the highlight over the
  wall; e and e + 1 differ on hundreds of pixels up to e = 128 (the grading set: none beyond e ~ 32).
- ``horizon``: t_max, a closest-hit search that starts at a finite "infinity". A floor and a ceiling seen
  to a slanted horizon put every pixel's hit at a different distance, 120 to millions; t_max is read to
  within 1 % from ~150 to ~50000 (the grading set's hits all lie within ~100).

A program of the 2014 edition also renders the course's own six test scenes (``COURSE_2014``), and each
of those scenes says beside minirt's verdict what the course's test -- colours compared at a 10x10 grid
-- would have said (``course_grid``).

``separation`` counts the pixels by which one scene tells two values of one rule apart; the test
tests/program/test_suite_separates.py asserts a floor for every pair over the suite. The pairs no scene
can tell apart under the suite's rules are ``minirt.diagnose.SAME_UNDER_EXERCISE`` (each with its reason,
``minirt.diagnose.why_same``): a program's ``indistinguishable`` lists them when its answer holds one.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from minirt import diagnose as dg
from minirt.diagnose.search import valid_rules
from minirt.model.bundled import BUNDLED
from minirt.model.rules import Rules
from minirt.model.scene import Scene

# Every scene of the suite is rendered at this size unless --size says otherwise: each pair of rule values
# shows on at least ~100 pixels of some scene at 96^2 (tests/program/test_suite_separates.py), and a NumPy
# or C++ program renders it in well under a second.
SUITE_SIZE = (96, 96)

GRADING = ("rules", "three_balls", "exercise")  # the bundled grading set (minirt.diagnose.GRADING_SET)
DESIGNED = ("offset_coarse", "offset_middle", "offset_fine", "highlight", "horizon")  # scenes/suite/
# The 2014 course's own test scenes (its test program for sub task e, "Raytracing"), transcribed as scene
# files (scenes/suite/course2014_*.toml), in the suite of a 2014 program; at 100x100, where the course's
# 10x10 grid falls on every 10th pixel (the course rendered 800x800 and sampled every 80th).
COURSE_2014 = tuple(
    f"course2014_{n}"
    for n in (
        "ambient_sphere",
        "diffuse_plane",
        "shadows",
        "reflection_spheres",
        "reflection_on_plane",
        "reflect_large",
    )
)
COURSE_SIZE = (100, 100)
# The course's comparison: AdjustColor(bitmap(x, y)) (clamped to [0, 1]) at a 10x10 grid of pixels, each
# channel equal to the course's colour within a relative 1e-4 of the smaller (a zero must be a zero).
GRID = 10
GRID_REL = 1e-4

# A difference the suite counts: more than two 8-bit levels on some channel of the clamped colour, so that
# an 8-bit image (one level of rounding allowed) and a float one (2^-10 allowed) both show it.
SEPARATES = 2.0 / 255.0


@dataclass(frozen=True)
class SuiteScene:
    name: str
    path: Path
    size: tuple[int, int]


def suite_path(name: str) -> Path:
    """A suite scene's file: a bundled scene of the grading set, or a designed one (scenes/suite/)."""
    return BUNDLED / f"{name}.toml" if name in GRADING else BUNDLED / "suite" / f"{name}.toml"


def program_suite(edition: str | None = None) -> list[SuiteScene]:
    """The scenes ``minirt grade --program`` renders by default, in order, each with its size; a program of
    the 2014 edition also renders the course's own test scenes (``COURSE_2014``)."""
    out = [SuiteScene(n, suite_path(n), SUITE_SIZE) for n in (*GRADING, *DESIGNED)]
    if edition == "2014":
        out += [SuiteScene(n, suite_path(n), COURSE_SIZE) for n in COURSE_2014]
    return out


def course_grid(image: np.ndarray, reference: np.ndarray) -> str:
    """What the 2014 course's test would have said of a program's float image (H, W, 3) of one of its
    scenes: "pass" when every channel at its 10x10 grid (every W/10-th pixel, from 0) equals the reference's
    colour, both clamped to [0, 1] and as float32 (the course's ``Color``), within ``GRID_REL`` of the
    smaller; else "fail"."""
    h, w = reference.shape[:2]
    ys, xs = np.arange(0, h, max(1, h // GRID)), np.arange(0, w, max(1, w // GRID))
    a = np.clip(image[np.ix_(ys, xs)], 0.0, 1.0).astype(np.float32)
    b = np.clip(reference[np.ix_(ys, xs)], 0.0, 1.0).astype(np.float32)
    ok = np.abs(a - b) <= np.minimum(np.abs(a), np.abs(b)) * np.float32(GRID_REL)
    return "pass" if bool(ok.all()) else "fail"


def with_rule(rules: Rules, name: str, value: Any) -> Rules:
    """``rules`` with one rule set (offset_along = "ray" with the error-bound offset, no rule set, takes the
    2014 edition's 1e-3)."""
    r = replace(rules, **{name: value})
    if not valid_rules(r) and r.offset == "error-bound":
        r = replace(r, offset=1e-3)
    return r


def separation(scene: Scene, ra: Rules, rb: Rules, cache: dg.VariantCache) -> int:
    """Pixels where the reference's pictures of ``scene`` under ``ra`` and ``rb`` differ by more than
    ``SEPARATES`` on some channel (colours clamped to [0, 1], as an image holds them), leaving out the
    pixels ill-conditioned under either (their primary ray or shadow ray within a float32 tracer's rounding
    of another decision: the diagnosis never counts them)."""
    va, vb = cache.get(scene, ra), cache.get(scene, rb)
    d = np.abs(np.clip(va.color, 0.0, 1.0) - np.clip(vb.color, 0.0, 1.0)).max(axis=-1).reshape(-1) > SEPARATES
    where = np.flatnonzero(d)
    if where.size == 0:
        return 0
    ill = va.shadow_ill.reshape(-1)[where] | vb.shadow_ill.reshape(-1)[where]
    ill |= cache.band(scene, ra, where) | cache.band(scene, rb, where)
    return int((~ill).sum())
