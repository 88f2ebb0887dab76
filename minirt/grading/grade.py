"""Grading another tracer's image of a scene: a verdict, the rule settings that explain it, and why.

``grade_image`` reads the image, checks its size, runs the diagnosis (minirt.diagnose.search) and returns a
``Grade``: ``match`` when the image is the scene's model as given (every pixel within one 8-bit level,
or ``FLOAT_TOL`` for a float image, ill-conditioned pixels left out), else ``differs`` with the rules
that reproduce it, each with the pixels it explains and a sentence a student understands.
``grade_class`` does the same for a folder of students (DIR/<student>/<scene stem>.<ext>), sharing one
render cache, and never stops for one bad file: that row gets verdict ``error`` and its reason.

Nothing here prints; the CLI does. JSON carries no timings, so the same command writes the same bytes.
"""

from __future__ import annotations

import shlex
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from minirt import diagnose as dg
from minirt.errors import MinirtError
from minirt.io.images import ImageHeader, read_student_image
from minirt.jobs import memory
from minirt.model import rules as rules_mod
from minirt.model.rules import Rules
from minirt.model.scene import Scene

MATCH, DIFFERS, ERROR = "match", "differs", "error"
EXIT = {MATCH: 0, DIFFERS: 1, ERROR: 2}


def _corner() -> str:
    return "pixel corners ((x/W − 0.5, −y/H + 0.5, 0), the exercise's loop)"


def _two_ways(value: Any, yours: str, here: str) -> Callable[[Any, Any], str]:
    """A two-valued rule's sentence: ``yours`` where the image's setting is ``value`` (the exercise's is the
    other one), ``here`` where the image has the other one and the scene asks for ``value``."""
    return lambda v, ex: yours if v == value else here


# One sentence per rule and value, in the words of the exercise: "yours" is the image's setting.
SENTENCES: dict[str, Callable[[Any, Any], str]] = {
    "background": lambda yours, ex: (
        {
            "on-miss": "your rays that miss everything return the background colour; ",
            "on-hit": "you add the background colour at every hit; ",
            "none": "you never add the background colour; ",
        }[yours]
        + {
            "on-hit": "the exercise's pseudo-code adds it at every hit (the last line of TraceRay) "
            "and leaves misses black.",
            "on-miss": "here a ray that misses returns the background and hits get none of it.",
            "none": "here the background is never added.",
        }[ex]
    ),
    "near_root_only": _two_ways(
        False,
        "you take the far root of a ball when the near one is behind the ray, so you see balls from inside; "
        "the exercise takes only the smaller root, provided it is not negative (Appendix 2), so a ball is "
        "invisible from inside.",
        "you take only the near root of a ball, so a ball is invisible from inside; here the far root counts too.",
    ),
    "shadow_range": _two_ways(
        "to-light",
        "your shadow rays are blocked only by shapes before the light; the exercise's pseudo-code counts "
        "any intersection of the shadow ray, even beyond the light.",
        "any shape on your shadow ray blocks it, even beyond the light; here only shapes before the light do.",
    ),
    "two_sided": _two_ways(
        True,
        "you turn every normal to face the incoming ray; the exercise uses a plane's normal as given, so a "
        "plane seen from behind is lit from its front side's view.",
        "you use a plane's normal as given; here normals are turned to face the ray.",
    ),
    "clamp": lambda yours, ex: (
        {
            True: "you clamp the light terms: no diffuse light below zero and no highlight where s·n ≤ 0; ",
            False: "you add s·n and (r·s)^n as they are, negative values included; ",
            "specular": "you add the highlight only where r·s > 0 and the diffuse term unclamped; ",
        }[yours]
        + {
            False: "the exercise adds both as they are (an even power lights the wrong side too).",
            True: "here both terms are clamped.",
            "specular": "here only the highlight is cut at r·s > 0.",
        }[ex]
    ),
    "offset": lambda yours, ex: (
        f"your secondary rays start {_offset_words(yours)}; the exercise's hint moves them "
        f"{_offset_words(ex)} to avoid hitting their own surface."
    ),
    "offset_along": _two_ways(
        "ray",
        "you move the start of shadow and reflected rays along their own direction; the exercise's hint moves "
        "it along the surface normal.",
        "you move the start of secondary rays along the normal; here they move along their own direction.",
    ),
    "ray_origin": _two_ways(
        "camera",
        "your primary rays start at the camera; the exercise's start on the image plane z = 0 (Ray(planePoint, "
        "planePoint − camera)), so shapes between the camera and the image plane are not seen.",
        "your primary rays start on the image plane; here they start at the camera.",
    ),
    "pixel_sample": _two_ways(
        "center",
        "your primary rays go through pixel centres; the exercise samples " + _corner() + ".",
        "your primary rays go through pixel corners; here they go through pixel centres.",
    ),
    "specular_exponent": lambda yours, ex: f"your highlight is (r·s)^{yours}; the exercise's is (r·s)^{ex}.",
    "pixel_shift": lambda yours, ex: (
        f"your pixel grid is shifted by ({yours[0]:g}, {yours[1]:g}) pixels: the ray of pixel (x, y) passes "
        f"where the exercise's ray of pixel (x + {yours[0]:g}, y + {yours[1]:g}) does (an off-by-one in the loop?)."
    ),
    "t_max": lambda yours, ex: (
        f'your closest-hit search ignores hits beyond t = {yours:g} (it starts at a finite "infinity"), so '
        "what lies farther is not drawn; the exercise counts every hit, however far."
        if yours != float("inf")
        else f"you count every hit however far; here hits beyond t = {ex:g} are ignored."
    ),
    "raw_normals_ball": lambda yours, ex: _raw_words("ball", "p − c not divided by its radius", yours, ex),
    "raw_normals_plane": lambda yours, ex: _raw_words("plane", "normal as written in the scene", yours, ex),
    "shadow_rays": _two_ways(
        False,
        "you never test for shadows: every point gets its diffuse and highlight terms, even behind another "
        "shape (a shadow test that is always true or never runs, e.g. `if (t = MAX)`); the exercise casts a "
        "shadow ray to the light from every hit.",
        "you cast shadow rays; here no point is ever in shadow.",
    ),
    "ball_normal": _two_ways(
        "inward",
        "your ball normal points into the ball (c − p instead of p − c): the lit side gets a negative diffuse "
        "term and secondary rays start inside; the exercise's normal is (p − c)/r (Appendix 2).",
        "your ball normal points out of the ball; here it points in.",
    ),
    "light": _two_ways(
        "direction",
        "you use the light's position as the direction towards it: s is the same at every point, not "
        "(light − p) normalised; the exercise's s points from each hit point to the light.",
        "your s points from each hit point to the light; here it is the light's position taken as a direction.",
    ),
    "hit_point": _two_ways(
        "origin",
        "you compute the hit point as t·d, leaving out the ray's start: p = t·d instead of p = o + t·d, so "
        "normals, light directions and secondary rays come from the wrong point.",
        "your hit point is o + t·d; here it is t·d.",
    ),
    "specular_s": _two_ways(
        "-s",
        "your highlight uses −s (the direction from the light to the point) in (r·s)^n; the exercise's s points "
        "from the point to the light, so your highlight sits on the wrong side where the power is odd or cut.",
        "your highlight uses s; here −s.",
    ),
    "encoding": lambda yours, ex: (
        f"you write a colour c as {_enc_words(yours)}; the exercise writes {_enc_words(ex)} (AdjustColor)."
    ),
    "gamma": lambda yours, ex: (
        f"you {'store the colour linearly' if yours == 'linear' else f'apply {_gamma_words(yours)} before writing'}"
        f"; the exercise {'writes it linearly, without gamma' if ex == 'linear' else f'applies {_gamma_words(ex)}'}."
    ),
    "rows": _two_ways(
        "bottom-up",
        "your image is upside down: rows are stored bottom-up (a BMP's native order) while the exercise's "
        "bitmap(x, y) has y = 0 at the top.",
        "your rows are stored top-down; here bottom-up.",
    ),
    "channels": _two_ways(
        "bgr",
        "your red and blue channels are swapped (BGR order, as a BMP stores pixels); "
        "the exercise's colours are R, G, B.",
        "your channels are R, G, B; here B, G, R.",
    ),
    "transpose": _two_ways(
        True,
        "your image is transposed: x and y are swapped (bitmap(y, x) instead of bitmap(x, y)).",
        "your image is not transposed; here it is.",
    ),
}


def _raw_words(kind: str, what: str, yours: str, ex: str) -> str:
    """rules raw_normals_ball and raw_normals_plane."""
    uses = {
        "shading": "in the diffuse term s·n",
        "reflection": "when you reflect the ray (r = d − 2(d·n)n)",
        "both": "in the diffuse term s·n and in the reflection",
    }
    head = (
        f"you use the {kind}'s normal without normalising it {uses[yours]}"
        if yours != "none"
        else (f"you use the {kind}'s unit normal")
    )
    tail = "the exercise's normal is of unit length ((p − c)/r, Appendix 2)" if ex == "none" else f"here: {ex}"
    return f"{head} (a {kind}'s {what}); {tail}."


def _offset_words(v: Any) -> str:
    if v == "error-bound":
        return "by a floating-point error bound of the hit point"
    return "exactly at the hit point" if v == 0 else f"{v:g} away from the hit point"


def _enc_words(v: str) -> str:
    return {"round": "floor(c·255 + 0.5)", "floor256": "min(255, floor(256·c))", "floor": "floor(c·255)"}[v]


def _gamma_words(v: str) -> str:
    return {"srgb": "the sRGB transfer curve", "2.2": "a gamma of 2.2 (c^(1/2.2))"}.get(v, v)


def sentence(rule: str, yours: Any, given: Any) -> str:
    s = SENTENCES[rule](yours, given)
    return s[0].upper() + s[1:]


# ---------------------------------------------------------------------------------------------
@dataclass
class Grade:
    scene: Scene
    scene_file: str
    image: str
    verdict: str
    reason: str = ""
    diagnosis: dg.Diagnosis | None = None
    target: dg.Target | None = None
    notes: list[str] = field(default_factory=list)
    size_override: tuple[int, int] | None = None

    @property
    def exit_code(self) -> int:
        return EXIT[self.verdict]

    def reproduce(self) -> str:
        """The command whose PNG is the image (as far as the diagnosis explains it)."""
        return shlex.join(["minirt", "render", self.scene_file, *self._settings()])

    def probe_command(self, x: int, y: int) -> str:
        """The command that traces pixel (x, y) step by step under the diagnosis's rules, beside the image's
        value, and says where the image departs (``minirt probe --image``)."""
        return shlex.join(
            ["minirt", "probe", self.scene_file, str(x), str(y), "--image", self.image, *self._settings()]
        )

    def _settings(self) -> list[str]:
        """The size and rule arguments under which the reference renders the image as the diagnosis explains it."""
        args = []
        if self.size_override:
            args += ["--width", str(self.size_override[0]), "--height", str(self.size_override[1])]
        if self.diagnosis:
            for name, value in sorted(self.diagnosis.reproducing.items()):
                args += ["--rule", f"{name}={value}"]
        return args

    def summary(self) -> str:
        if self.verdict == ERROR:
            return self.reason
        d = self.diagnosis
        if self.verdict == MATCH:
            return f"the image is the scene's model as given ({d.pixels} pixels)"
        k = len(d.unexplained)
        where = f", in {k} group{'s' if k != 1 else ''} by where they lie" if k else ""
        undecided = f"; cannot decide {', '.join(sorted(d.undetermined))}" if d.undetermined else ""
        if not d.changed and not d.undetermined:
            return f"{d.as_given_pixels} of {d.pixels} pixels differ; no rule setting explains them{where}"
        rules = ", ".join(f"{k}={v}" for k, v in sorted(d.changed.items())) or "rules the image cannot decide"
        rest = f"; {d.mismatch_pixels} pixels still unexplained{where}" if d.mismatch_pixels else ""
        return f"{d.as_given_pixels} of {d.pixels} pixels differ; explained by {rules}{undecided}{rest}"

    def as_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "verdict": self.verdict,
            "scene": self.scene.name if self.scene else None,
            "scene_file": self.scene_file,
            "image": self.image,
            "summary": self.summary(),
            "notes": self.notes,
        }
        d = self.diagnosis
        if self.verdict == ERROR or d is None:
            out["reason"] = self.reason
            return out
        w, h = self.scene.camera.width, self.scene.camera.height
        out.update(
            {
                "size": [w, h],
                "pixels": d.pixels,
                "image_format": "float" if self.target.is_float else "8-bit",
                "tolerance": f"{dg.FLOAT_TOL:g} per channel" if self.target.is_float else "1 level per channel",
                "ill_conditioned_pixels": int(d.ill.sum()),
                "as_given": {
                    "mismatch_pixels": d.as_given_pixels,
                    "rules": {n: rules_mod.format_rule_value(n, v) for n, v in d.given.as_dict().items()},
                },
                "diagnosis": {
                    # the rules the image decides; ``undetermined`` those it cannot, with the values that fit
                    "rules": d.changed,
                    "undetermined": d.undetermined,
                    "undetermined_sentence": d.one_of.sentence if d.one_of else None,
                    "mismatch_pixels": d.mismatch_pixels,
                    # pixels the answer draws wrong that the scene's own rules drew right
                    "broken_pixels": d.broken_pixels,
                    # evidence by leave-one-out: ``pixels`` wrong without the rule, ``against`` right without
                    # it, ``neither``: changed by it and matching neither value (minirt.diagnose.evidence)
                    "explained": [
                        {
                            "rule": e.rule,
                            "value": e.value,
                            "pixels": e.pixels,
                            "against": e.against,
                            "neither": e.neither,
                            "decided": e.rule not in d.undetermined,
                            # a number read off the image: the values that fit as well (the named one is
                            # the simplest inside)
                            **({"interval": list(e.interval)} if e.interval else {}),
                            "sentence": sentence(e.rule, getattr(d.best, e.rule), getattr(d.given, e.rule)),
                        }
                        for e in d.explained
                    ],
                    # rules the search took that the image does not bear out, put back to the scene's value
                    "rejected": [r.as_dict() for r in d.rejected],
                    "search": {"steps": d.steps, "renders": d.renders},
                    # where the pixels no rule setting explains lie (minirt.diagnose.rest), largest group first
                    "unexplained": [u.as_dict() for u in d.unexplained],
                },
                "indistinguishable": d.indistinguishable,
                "reproduce": self.reproduce(),
            }
        )
        return out


GRADE_RESIZE = "grade with --size {w}x{h}"


def load_target(
    path: str | Path, scene: Scene | None = None, resize: str = GRADE_RESIZE, notes: list[str] | None = None
) -> dg.Target:
    """The image to grade. With ``scene``, its header's size is checked against the scene's (``size_notes``;
    ``resize`` is the advice for another size, given the image's {w} and {h}) and the memory a grade of
    it needs (``GRADE_RESIZE``; else only its pixels') against what is available, before a pixel is
    decoded: a file that claims 100000x100000 pixels costs a header's read, not the machine's memory."""

    def before_decoding(header: ImageHeader) -> None:
        if scene is None:
            return
        size_notes(scene, header.width, header.height, str(path), resize)
        w, h = scene.camera.width, scene.camera.height
        if resize == GRADE_RESIZE:
            memory.require(
                memory.grade_bytes(w * h),
                f"grading {path} ({w}x{h})",
                "grade on a machine with more memory, or a smaller render of the same scene (--size)",
            )
        else:  # only its pixels are held
            memory.require(
                w * h * 3 * (4 if header.is_float else 1),
                f"reading {path} ({w}x{h})",
                "use a machine with more memory, or a smaller render of the same scene",
            )

    pixels, is_float = read_student_image(path, before_decoding, notes)  # notes: how the image was read
    return dg.Target(pixels, is_float, str(path))


def check_size(scene: Scene, target: dg.Target, image: str) -> list[str]:
    """The image's size against the scene's: fine, transposed (a note), or a one-line error."""
    rows, cols = target.shape
    return size_notes(scene, cols, rows, image)


def size_notes(scene: Scene, cols: int, rows: int, image: str, resize: str = GRADE_RESIZE) -> list[str]:
    """An image of ``cols`` x ``rows`` against the scene's size: [] when it is the scene's, a note when it is
    transposed, else a one-line MinirtError (``resize``: how to grade another size)."""
    w, h = scene.camera.width, scene.camera.height
    if (cols, rows) == (w, h):
        return []
    if (cols, rows) == (h, w):
        return [f"the image is {cols}x{rows} for a {w}x{h} scene: x and y are swapped (transposed)"]
    raise MinirtError(
        f"{image}: the image is {cols}x{rows}, the scene {scene.source or scene.name} is {w}x{h} "
        f"(render at the scene's size, or {resize.format(w=cols, h=rows)})"
    )


def grade_image(
    scene: Scene,
    scene_file: str,
    image: str | Path,
    rules: Rules,
    cache: dg.VariantCache | None = None,
    size_override: tuple[int, int] | None = None,
) -> Grade:
    """Grade one image of one scene (raises MinirtError for bad input)."""
    scene = scene.with_overrides(samples=1)  # the exercise traces one ray per pixel
    notes: list[str] = []  # how the image was read (16-bit holding 8-bit levels), then its size
    target = load_target(image, scene, notes=notes)  # the size and the memory checked before the image is decoded
    notes += check_size(scene, target, str(image))
    # one image on its own: its search traces the scene's one-step variants on its subset of pixels only
    # (VariantCache.share); a class passes the cache its images share
    d = dg.diagnose(scene, rules, target, cache or dg.VariantCache(share=False))
    verdict = MATCH if d.as_given_pixels == 0 else DIFFERS
    g = Grade(scene, scene_file, str(image), verdict, diagnosis=d, target=target, notes=notes)
    g.size_override = size_override
    return g


# ---------------------------------------------------------------------------------------------
@dataclass
class ClassRow:
    student: str
    scene: str
    verdict: str
    rules: dict[str, str]
    mismatch_pixels: int | None
    as_given_pixels: int | None
    reason: str = ""
    page: str = ""
    grade: Grade | None = field(default=None, repr=False)
    sentences: dict[str, str] = field(default_factory=dict, repr=False)  # rule -> the sentence for the student
    page_html: bytes | None = field(default=None, repr=False)  # the page's bytes, for the cache (``grade_class``)
    # the groups of pixels no rule setting explains (Grade's diagnosis.unexplained, without their masks)
    unexplained: list[dict[str, Any]] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        out = self._row()
        if self.unexplained:  # rows without any keep the bytes they had before such groups existed
            out["unexplained"] = self.unexplained
        return out

    def _row(self) -> dict[str, Any]:
        return {
            "student": self.student,
            "scene": self.scene,
            "verdict": self.verdict,
            "rules": self.rules,
            "mismatch_pixels": self.mismatch_pixels,
            "as_given_pixels": self.as_given_pixels,
            "reason": self.reason,
            "page": self.page,
        }


def difference_levels(g: Grade, color: np.ndarray, rules: Rules) -> np.ndarray:
    """Per pixel, the largest channel difference between the image and ``color`` written under
    ``rules`` (8-bit levels, or float units x 255), in the scene's layout; the full size's worth of
    255 where the image's layout does not fit."""
    d = g.target.difference(color, rules)
    if d is None:
        return np.full(color.shape[:2], 255.0)
    return d * 255.0 if g.target.is_float else d.astype(np.float64)
