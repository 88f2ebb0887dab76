"""Grading another tracer's image of a scene: a verdict, the rule settings that explain it, and why.

``grade_image`` reads the image, checks its size, runs the diagnosis (minirt.diagnose) and returns a
``Grade``: ``match`` when the image is the scene's model as given (every pixel within one 8-bit level,
or ``FLOAT_TOL`` for a float image, ill-conditioned pixels left out), else ``differs`` with the rules
that reproduce it, each with the pixels it explains and a sentence a student understands.
``grade_class`` does the same for a folder of students (DIR/<student>/<scene stem>.<ext>), sharing one
render cache, and never stops for one bad file: that row gets verdict ``error`` and its reason.

Nothing here prints; the CLI does. JSON carries no timings, so the same command writes the same bytes.
"""

from __future__ import annotations

import hashlib
import re
import shlex
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from minirt import diagnose as dg
from minirt import memory
from minirt import rules as rules_mod
from minirt.errors import MinirtError
from minirt.imageio import STUDENT_EXTENSIONS, atomic_path, read_student_image
from minirt.rules import Rules
from minirt.scene import Scene

if TYPE_CHECKING:
    from minirt.cache import Cache

MATCH, DIFFERS, ERROR = "match", "differs", "error"
EXIT = {MATCH: 0, DIFFERS: 1, ERROR: 2}


def _corner() -> str:
    return "pixel corners ((x/W − 0.5, −y/H + 0.5, 0), the exercise's loop)"


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
    "near_root_only": lambda yours, ex: (
        "you take the far root of a ball when the near one is behind the ray, so you see balls from inside; "
        "the exercise takes only the smaller root, provided it is not negative (Appendix 2), so a ball is "
        "invisible from inside."
        if not yours
        else "you take only the near root of a ball, so a ball is invisible from inside; here the far root counts too."
    ),
    "shadow_range": lambda yours, ex: (
        "your shadow rays are blocked only by shapes before the light; the exercise's pseudo-code counts "
        "any intersection of the shadow ray, even beyond the light."
        if yours == "to-light"
        else "any shape on your shadow ray blocks it, even beyond the light; here only shapes before the light do."
    ),
    "two_sided": lambda yours, ex: (
        "you turn every normal to face the incoming ray; the exercise uses a plane's normal as given, so a "
        "plane seen from behind is lit from its front side's view."
        if yours
        else "you use a plane's normal as given; here normals are turned to face the ray."
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
    "offset_along": lambda yours, ex: (
        "you move the start of shadow and reflected rays along their own direction; the exercise's hint moves "
        "it along the surface normal."
        if yours == "ray"
        else "you move the start of secondary rays along the normal; here they move along their own direction."
    ),
    "ray_origin": lambda yours, ex: (
        "your primary rays start at the camera; the exercise's start on the image plane z = 0 (Ray(planePoint, "
        "planePoint − camera)), so shapes between the camera and the image plane are not seen."
        if yours == "camera"
        else "your primary rays start on the image plane; here they start at the camera."
    ),
    "pixel_sample": lambda yours, ex: (
        "your primary rays go through pixel centres; the exercise samples " + _corner() + "."
        if yours == "center"
        else "your primary rays go through pixel corners; here they go through pixel centres."
    ),
    "specular_exponent": lambda yours, ex: f"your highlight is (r·s)^{yours}; the exercise's is (r·s)^{ex}.",
    "pixel_shift": lambda yours, ex: (
        f"your pixel grid is shifted by ({yours[0]:g}, {yours[1]:g}) pixels: the ray of pixel (x, y) passes "
        f"where the exercise's ray of pixel (x + {yours[0]:g}, y + {yours[1]:g}) does (an off-by-one in the loop?)."
    ),
    "encoding": lambda yours, ex: (
        f"you write a colour c as {_enc_words(yours)}; the exercise writes {_enc_words(ex)} (AdjustColor)."
    ),
    "gamma": lambda yours, ex: (
        f"you {'store the colour linearly' if yours == 'linear' else f'apply {_gamma_words(yours)} before writing'}"
        f"; the exercise {'writes it linearly, without gamma' if ex == 'linear' else f'applies {_gamma_words(ex)}'}."
    ),
    "rows": lambda yours, ex: (
        "your image is upside down: rows are stored bottom-up (a BMP's native order) while the exercise's "
        "bitmap(x, y) has y = 0 at the top."
        if yours == "bottom-up"
        else "your rows are stored top-down; here bottom-up."
    ),
    "channels": lambda yours, ex: (
        "your red and blue channels are swapped (BGR order, as a BMP stores pixels); "
        "the exercise's colours are R, G, B."
        if yours == "bgr"
        else "your channels are R, G, B; here B, G, R."
    ),
    "transpose": lambda yours, ex: (
        "your image is transposed: x and y are swapped (bitmap(y, x) instead of bitmap(x, y))."
        if yours
        else "your image is not transposed; here it is."
    ),
}


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
        cmd = ["minirt", "render", self.scene_file]
        if self.size_override:
            cmd += ["--width", str(self.size_override[0]), "--height", str(self.size_override[1])]
        if self.diagnosis:
            for name, value in sorted(self.diagnosis.changed.items()):
                cmd += ["--rule", f"{name}={value}"]
        return shlex.join(cmd)

    def summary(self) -> str:
        if self.verdict == ERROR:
            return self.reason
        d = self.diagnosis
        if self.verdict == MATCH:
            return f"the image is the scene's model as given ({d.pixels} pixels)"
        if not d.changed:
            return f"{d.as_given_pixels} of {d.pixels} pixels differ; no rule setting explains them"
        rules = ", ".join(f"{k}={v}" for k, v in sorted(d.changed.items()))
        rest = f"; {d.mismatch_pixels} pixels still unexplained" if d.mismatch_pixels else ""
        return f"{d.as_given_pixels} of {d.pixels} pixels differ; explained by {rules}{rest}"

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
                    "rules": d.changed,
                    "mismatch_pixels": d.mismatch_pixels,
                    "explained": [
                        {
                            "rule": e.rule,
                            "value": e.value,
                            "pixels": e.pixels,
                            "sentence": sentence(e.rule, getattr(d.best, e.rule), getattr(d.given, e.rule)),
                        }
                        for e in d.explained
                    ],
                    "search": {"steps": d.steps, "renders": d.renders},
                },
                "indistinguishable": d.indistinguishable,
                "reproduce": self.reproduce(),
            }
        )
        return out


def load_target(path: str | Path) -> dg.Target:
    pixels, is_float = read_student_image(path)
    return dg.Target(pixels, is_float, str(path))


def check_size(scene: Scene, target: dg.Target, image: str) -> list[str]:
    """The image's size against the scene's: fine, transposed (a note), or a one-line error."""
    w, h = scene.camera.width, scene.camera.height
    rows, cols = target.shape
    if (cols, rows) == (w, h):
        return []
    if (cols, rows) == (h, w):
        return [f"the image is {cols}x{rows} for a {w}x{h} scene: x and y are swapped (transposed)"]
    raise MinirtError(
        f"{image}: the image is {cols}x{rows}, the scene {scene.source or scene.name} is {w}x{h} "
        f"(render at the scene's size, or grade with --size {cols}x{rows})"
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
    target = load_target(image)
    notes = check_size(scene, target, str(image))
    w, h = scene.camera.width, scene.camera.height
    memory.require(
        memory.grade_bytes(w * h),
        f"grading {image} ({w}x{h})",
        "grade on a machine with more memory, or a smaller render of the same scene (--size)",
    )
    d = dg.diagnose(scene, rules, target, cache)
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

    def as_dict(self) -> dict[str, Any]:
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


def find_image(folder: Path, stem: str) -> Path | None:
    """The student's image of scene ``stem``: any supported extension (the first in a fixed order)."""
    for ext in STUDENT_EXTENSIONS:
        for cand in (folder / f"{stem}{ext}", folder / f"{stem}{ext.upper()}"):
            if cand.is_file():
                return cand
    return None


def students(class_dir: Path) -> list[Path]:
    if not class_dir.is_dir():
        raise MinirtError(f"--class {class_dir}: no such folder")
    found = sorted(p for p in class_dir.iterdir() if p.is_dir() and not p.name.startswith("."))
    if not found:
        raise MinirtError(f"--class {class_dir}: no student folders inside (expected DIR/<student>/<scene>.png)")
    return found


def grade_one_row(student: Path, scene: Scene, scene_file: str, rules: Rules, cache: dg.VariantCache) -> ClassRow:
    stem = Path(scene_file).stem
    img = find_image(student, stem)
    if img is None:
        return ClassRow(student.name, stem, ERROR, {}, None, None, reason=f"no image {stem}.png (or .bmp, .ppm, …)")
    try:
        g = grade_image(scene, scene_file, img, rules, cache)
    except MinirtError as e:
        return ClassRow(student.name, stem, ERROR, {}, None, None, reason=str(e).splitlines()[0])
    d = g.diagnosis
    said = {n: sentence(n, getattr(d.best, n), getattr(d.given, n)) for n in d.changed}
    return ClassRow(
        student.name, stem, g.verdict, d.changed, d.mismatch_pixels, d.as_given_pixels, grade=g, sentences=said
    )


@dataclass(frozen=True)
class ClassJob:
    """One image of a class to grade: everything a worker process needs, nothing it must share."""

    student: str  # the student's folder
    scene: Scene
    scene_file: str
    rules: Rules
    out_dir: str  # the class's output folder (pages/ inside)
    page_stem: str
    image_digest: str = ""  # SHA-256 of the student's image file ("" when there is none): the cache key's
    keep_page: bool = False  # return the page's bytes with the row (to cache them)
    cache_bytes: int = 2 << 30  # the budget of the process's render cache (memory.class_cache_bytes)


# Each process keeps one render cache for every image it grades (a worker's share of a class). Its budget
# is per process: two workers hold twice this at most, plus what a diagnosis holds while it runs.
PROCESS_CACHE_BYTES = 2 << 30
_process_cache: dg.VariantCache | None = None


def process_cache(budget: int = PROCESS_CACHE_BYTES) -> dg.VariantCache:
    """This process's render cache, made with ``budget`` bytes by the first call."""
    global _process_cache
    if _process_cache is None:
        _process_cache = dg.VariantCache(budget)
    return _process_cache


def grade_job(job: ClassJob) -> ClassRow:
    """Grade one image of a class and write its page (in whichever process runs it); the row comes back
    without the grade's arrays, so neither the worker nor the caller holds a class's worth of them."""
    from minirt.grade_report import write_row_page

    row = grade_one_row(Path(job.student), job.scene, job.scene_file, job.rules, process_cache(job.cache_bytes))
    write_row_page(row, Path(job.out_dir), job.page_stem)
    row.grade = None
    if job.keep_page and row.page:
        row.page_html = (Path(job.out_dir) / row.page).read_bytes()
    return row


ASSET_LINK = re.compile(r'"assets/([A-Za-z0-9._-]+\.png)"')  # a class page's pictures (named by their pixels)


def class_cache(folder: Path, out_dir: Path) -> Cache:
    """The cache of ``grade_class``'s jobs: a row is reused for the same image bytes, scene, rules, page
    name and versions, and its page is written back from the cached bytes -- when every picture it links
    is still in ``out_dir/pages/assets`` (pictures are named by their pixels' hash, so a file of that name
    is that picture); otherwise the image is graded again. Error rows are never kept."""
    from minirt.cache import Cache, digest, pickle_codec, versions

    v = versions([])

    def key(job: ClassJob) -> str:
        return digest({"kind": "grade", "image": job.image_digest, "scene": repr(job.scene), "rules": repr(job.rules),
                       "scene_file": Path(job.scene_file).name, "page": job.page_stem, "minirt": v["minirt"],
                       "drjit": v["drjit"]})  # fmt: skip

    def accept(job: ClassJob, row: ClassRow) -> bool:
        if not row.page:
            return True
        if row.page_html is None:
            return False
        assets = Path(out_dir) / "pages" / "assets"
        if not all((assets / name).is_file() for name in ASSET_LINK.findall(row.page_html.decode("utf-8"))):
            return False
        page = Path(out_dir) / row.page
        page.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(page) as tmp:
            tmp.write_bytes(row.page_html)
        return True

    return Cache(folder, key, pickle_codec, keep=lambda row: row.verdict != ERROR, accept=accept)


def grade_class(
    people: list[Path],
    scenes: list[tuple[str, Scene, Rules]],
    out_dir: Path,
    workers: int = 1,
    scheduler: str | None = None,
    on_done: Callable[[ClassJob, ClassRow], None] | None = None,
    cache: Cache | None = None,
    cache_bytes: int = PROCESS_CACHE_BYTES,
) -> list[ClassRow]:
    """Grade every student's image of every scene (``scenes``: (file, scene, rules)), writing each page
    into ``out_dir/pages/`` as it is graded; rows in student order, then scene order, however the work
    was spread (minirt.jobs: ``workers`` processes here, or a Dask ``scheduler``'s). A call that fails
    inside a worker is an ``error`` row, like a missing image. ``cache_bytes``: each process's render
    cache (``memory.class_cache_bytes`` sizes it to the machine)."""
    from minirt import jobs
    from minirt.grade_report import page_stems

    keys = [(s, f, sc, r) for s in people for f, sc, r in scenes]
    stems = page_stems((s.name, Path(f).stem) for s, f, _, _ in keys)
    todo = [
        ClassJob(
            str(s), sc, f, r, str(out_dir), stem, _image_digest(s, f) if cache else "", cache is not None, cache_bytes
        )
        for (s, f, sc, r), stem in zip(keys, stems, strict=True)
    ]

    def failed(job: ClassJob, message: str) -> ClassRow:
        return ClassRow(Path(job.student).name, Path(job.scene_file).stem, ERROR, {}, None, None, reason=message)

    def done(job: ClassJob, row: ClassRow) -> None:
        row.page_html = None  # stored by now: a class's pages are not held in memory
        if on_done:
            on_done(job, row)

    return jobs.run(grade_job, todo, workers=workers, scheduler=scheduler, on_done=done, on_error=failed, cache=cache)


def _image_digest(student: Path, scene_file: str) -> str:
    img = find_image(student, Path(scene_file).stem)
    if img is None:
        return ""
    try:
        return hashlib.sha256(img.read_bytes()).hexdigest()
    except OSError:
        return ""  # graded (and reported) as unreadable


def common_mistakes(rows: list[ClassRow]) -> list[dict[str, Any]]:
    """Rule settings across the class, most frequent first: (rule, value) -> students and images, and
    how many of those images still differ beyond tolerance (a setting such as another rounding of the
    bitmap moves pixels by one level: its images can match and still show it)."""
    seen: dict[tuple[str, str], set[str]] = {}
    images: dict[tuple[str, str], int] = {}
    differing: dict[tuple[str, str], int] = {}
    for r in rows:
        for k, v in r.rules.items():
            seen.setdefault((k, v), set()).add(r.student)
            images[(k, v)] = images.get((k, v), 0) + 1
            differing[(k, v)] = differing.get((k, v), 0) + (r.verdict == DIFFERS)
    out = [
        {"rule": k, "value": v, "students": len(s), "images": images[(k, v)], "differing_images": differing[(k, v)]}
        for (k, v), s in seen.items()
    ]
    return sorted(out, key=lambda m: (-m["students"], -m["images"], m["rule"], m["value"]))


def class_dict(rows: list[ClassRow], scenes: list[str]) -> dict[str, Any]:
    counts: dict[str, int] = {MATCH: 0, DIFFERS: 0, ERROR: 0}
    for r in rows:
        counts[r.verdict] += 1
    return {
        "students": sorted({r.student for r in rows}),
        "scenes": scenes,
        "verdicts": counts,
        "common_mistakes": common_mistakes(rows),
        "grades": [r.as_dict() for r in rows],
    }


def write_csv(path: Path, rows: list[ClassRow]) -> None:
    import csv
    import io

    from minirt.imageio import atomic_path

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["student", "scene", "verdict", "rules", "mismatch_pixels", "as_given_pixels", "reason"])
    for r in rows:
        rules = " ".join(f"{k}={v}" for k, v in sorted(r.rules.items()))
        w.writerow(
            [r.student, r.scene, r.verdict, rules, _blank(r.mismatch_pixels), _blank(r.as_given_pixels), r.reason]
        )
    with atomic_path(path) as tmp:
        tmp.write_text(buf.getvalue())


def _blank(v: int | None) -> str:
    return "" if v is None else str(v)


def difference_levels(g: Grade, color: np.ndarray, rules: Rules) -> np.ndarray:
    """Per pixel, the largest channel difference between the image and ``color`` written under
    ``rules`` (8-bit levels, or float units x 255), in the scene's layout; the full size's worth of
    255 where the image's layout does not fit."""
    d = g.target.difference(color, rules)
    if d is None:
        return np.full(color.shape[:2], 255.0)
    return d * 255.0 if g.target.is_float else d.astype(np.float64)
