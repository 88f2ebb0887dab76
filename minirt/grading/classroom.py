"""A class graded at once: every student's image of every scene, as independent jobs, with a page per image,
the class table, the CSV and the most common mistakes.

``minirt grade --class`` finds the class (``find_class``), reads the scenes under its flags, then runs
``grade_folder``: the jobs (``grade_class``), the class's files, and what it prints comes back to it.
Sits above the grade of one image (minirt.grading.grade) and its page (minirt.grading.page)."""

from __future__ import annotations

import hashlib
import os
import re
import stat
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from minirt import diagnose as dg
from minirt.errors import MinirtError
from minirt.io.atomic import atomic_path
from minirt.io.images import STUDENT_EXTENSIONS
from minirt.model.rules import Rules
from minirt.model.scene import Scene

if TYPE_CHECKING:
    from minirt.jobs.cache import Cache
from minirt.grading.grade import DIFFERS, ERROR, MATCH, ClassRow, grade_image, sentence

# A class folder is untrusted: a student writes what is in their folder. Nothing in it is followed out of it:
# a student folder or an image that is a symbolic link is a row with verdict "error" (a link to another
# student's image, or to the staff's reference, would otherwise be graded -- and its picture published);
# only regular files are read. Hidden entries (".git", ".hidden") and entries that are not folders are
# listed as skipped, with the reason, in grades.json and on the class page (grades.csv keeps one row per
# student and scene).
HIDDEN = "hidden (its name starts with a dot)"


@dataclass(frozen=True)
class Skipped:
    """An entry of the class folder that is not a student: its name and why it was not graded."""

    folder: str
    reason: str

    def as_dict(self) -> dict[str, str]:
        return {"folder": self.folder, "reason": self.reason}


def _link_reason(path: Path, what: str) -> str:
    from minirt.io.untrusted import printable

    try:
        target = f" to {printable(os.readlink(path), 200)}"
    except OSError:
        target = ""
    return f"{what} is a symbolic link{target}; links are not followed (only what is in the class folder is graded)"


def find_image(folder: Path, stem: str) -> Path | None:
    """The student's image of scene ``stem``: any supported extension (the first in a fixed order) --
    whatever is there under that name, not followed if a link (``image_problem`` says what is wrong)."""
    for ext in STUDENT_EXTENSIONS:
        for cand in (folder / f"{stem}{ext}", folder / f"{stem}{ext.upper()}"):
            if os.path.lexists(cand):
                return cand
    return None


def image_problem(img: Path) -> str | None:
    """Why the file ``img`` of a student's folder is not read (a link, not a regular file), or None."""
    try:
        st = img.lstat()
    except OSError as e:
        return f"{img.name}: cannot read ({e.strerror or e})"
    if stat.S_ISLNK(st.st_mode):
        return _link_reason(img, img.name)
    if not stat.S_ISREG(st.st_mode):
        kind = "a folder" if stat.S_ISDIR(st.st_mode) else "a FIFO, a device or a socket"
        return f"{img.name} is not a regular file ({kind})"
    try:
        str(img).encode("utf-8")
    except UnicodeEncodeError:  # bytes that are not UTF-8 in a name: OpenImageIO cannot open the path
        return "the image's path is not UTF-8 text, which the image reader needs (rename the folder or file)"
    return None


def folder_problem(student: Path) -> str | None:
    """Why a student's folder is not looked into (a symbolic link, or not listable), or None."""
    if student.is_symlink():
        return _link_reason(student, "the student folder")
    try:
        with os.scandir(student):  # opened, not read: a folder of a million files costs nothing here
            pass
    except OSError as e:
        return f"cannot list the student folder ({e.strerror or e})"
    return None


def survey(class_dir: Path) -> tuple[list[Path], list[Skipped]]:
    """The class folder's entries: its student folders (sorted; a symbolic link among them is a student,
    graded as an error row, never followed) and what was skipped (hidden entries, entries that are not
    folders), sorted by name."""
    if not class_dir.is_dir():
        raise MinirtError(f"--class {class_dir}: no such folder")
    try:
        with os.scandir(class_dir) as listing:
            entries = sorted(listing, key=lambda e: e.name)
    except OSError as e:
        raise MinirtError(f"--class {class_dir}: cannot list the folder ({e.strerror or e})") from None
    found: list[Path] = []
    skipped: list[Skipped] = []
    for e in entries:
        try:
            is_dir, is_link = e.is_dir(follow_symlinks=False), e.is_symlink()
        except OSError:
            is_dir = is_link = False
        if e.name.startswith("."):
            if is_dir or is_link:
                skipped.append(Skipped(e.name, HIDDEN))
        elif is_dir or is_link:
            found.append(Path(e.path))
        else:
            skipped.append(Skipped(e.name, "not a folder (a student's images are in DIR/<student>/)"))
    return found, skipped


def students(class_dir: Path) -> list[Path]:
    """The student folders of the class folder (``survey``); none is bad input."""
    found, _ = survey(class_dir)
    if not found:
        raise MinirtError(f"--class {class_dir}: no student folders inside (expected DIR/<student>/<scene>.png)")
    return found


def skipped_entries(class_dir: Path) -> list[Skipped]:
    """What the class folder holds besides its students (``survey``): for grades.json and the class page."""
    return survey(class_dir)[1]


def _names(student: Path) -> set[str]:
    """The stems of the files in a student's folder (links included, not followed: a linked image is an
    error row), none when the folder itself is a link or cannot be listed."""
    if folder_problem(student) is not None:
        return set()
    try:
        with os.scandir(student) as entries:
            return {Path(e.name).stem for e in entries if not e.is_dir(follow_symlinks=False)}
    except OSError:
        return set()  # gone or unreadable since: its rows say so


def find_class(class_dir: Path, scenes_dir: Path | None = None) -> tuple[list[Path], list[Path]]:
    """The class's student folders and the scene files (of ``scenes_dir``, default the bundled scenes) that
    some student has an image of; bad input names --class or --scenes."""
    from minirt.model.bundled import BUNDLED

    people = students(class_dir)
    folder = scenes_dir or BUNDLED
    if not folder.is_dir():
        raise MinirtError(f"--scenes {folder}: no such folder")
    files = sorted(folder.glob("*.toml"))
    submitted = set().union(*(_names(s) for s in people))
    files = [f for f in files if f.stem in submitted]
    if not files:
        raise MinirtError(f"--class {class_dir}: no image is named after a scene in {folder} (e.g. exercise.png)")
    return people, files


def grade_one_row(student: Path, scene: Scene, scene_file: str, rules: Rules, cache: dg.VariantCache) -> ClassRow:
    stem = Path(scene_file).stem

    def error(reason: str) -> ClassRow:
        return ClassRow(student.name, stem, ERROR, {}, None, None, reason=reason)

    problem = folder_problem(student)
    if problem is not None:
        return error(problem)
    img = find_image(student, stem)
    if img is None:
        return error(f"no image {stem}.png (or .bmp, .ppm, …)")
    problem = image_problem(img)
    if problem is not None:
        return error(problem)
    try:
        g = grade_image(scene, scene_file, img, rules, cache)
    except MinirtError as e:
        return error(str(e).splitlines()[0])
    d = g.diagnosis
    said = {n: sentence(n, getattr(d.best, n), getattr(d.given, n)) for n in d.changed}
    return ClassRow(
        student.name,
        stem,
        g.verdict,
        d.changed,
        d.mismatch_pixels,
        d.as_given_pixels,
        grade=g,
        sentences=said,
        unexplained=[u.as_dict() for u in d.unexplained],
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
    from minirt.grading.page import write_row_page

    row = grade_one_row(Path(job.student), job.scene, job.scene_file, job.rules, process_cache(job.cache_bytes))
    write_row_page(row, Path(job.out_dir), job.page_stem)
    row.grade = None
    if job.keep_page and row.page:
        row.page_html = (Path(job.out_dir) / row.page).read_bytes()
    return row


ASSET_LINK = re.compile(r'"assets/([A-Za-z0-9._-]+\.png)"')  # a class page's pictures (named by their pixels)


def row_fits(job: ClassJob, row: ClassRow) -> None:
    """Raise ValueError unless ``row`` -- from a worker or the cache -- is a row of ``job``: a ClassRow of
    its student and scene, without the grade's arrays, whose page (if any) is the job's own page name --
    a page path read from a cache entry is where its bytes are written back, so it is never taken as is."""
    from minirt.grading.page import safe_stem
    from minirt.jobs.data import Schema

    Schema(ClassRow, (ClassRow,)).check(row)
    if (row.student, row.scene) != (Path(job.student).name, Path(job.scene_file).stem):
        raise ValueError(f"a row of {row.student!r}, {row.scene!r}, not of this image")
    if row.verdict not in (MATCH, DIFFERS, ERROR):
        raise ValueError(f"an unknown verdict {row.verdict!r}")
    if row.page not in ("", f"pages/{safe_stem(job.page_stem, 'index')}.html"):
        raise ValueError(f"a page {row.page!r} that is not the image's")


def class_cache(folder: Path, out_dir: Path) -> Cache:
    """The cache of ``grade_class``'s jobs (minirt.jobs.cache, as data): a row is reused for the same image
    bytes, scene, rules, page name and versions, and its page is written back from the cached bytes -- when
    the row fits its job (``row_fits``) and every picture its page links is still in ``out_dir/pages/assets``
    (pictures are named by their pixels' hash, so a file of that name is that picture); otherwise the image
    is graded again. Error rows are never kept."""
    from minirt.harness.backends import versions
    from minirt.jobs.cache import Cache, data_codec, digest
    from minirt.jobs.data import Schema

    v = versions([])

    def key(job: ClassJob) -> str:
        return digest({"kind": "grade", "image": job.image_digest, "scene": repr(job.scene), "rules": repr(job.rules),
                       "scene_file": Path(job.scene_file).name, "page": job.page_stem, "minirt": v["minirt"],
                       "drjit": v["drjit"]})  # fmt: skip

    def accept(job: ClassJob, row: ClassRow) -> bool:
        row_fits(job, row)
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

    codec = data_codec(Schema(ClassRow, (ClassRow,)))
    return Cache(folder, key, codec, keep=lambda row: row.verdict != ERROR, accept=accept)


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
    was spread (minirt.jobs.batch: ``workers`` processes here, or a Dask ``scheduler``'s). A call that fails
    inside a worker is an ``error`` row, like a missing image. ``cache_bytes``: each process's render
    cache (``memory.class_cache_bytes`` sizes it to the machine)."""
    from minirt.grading.page import page_stems
    from minirt.jobs import batch as jobs

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

    return jobs.run(grade_job, todo, workers=workers, scheduler=scheduler, on_done=done, on_error=failed, cache=cache,
                    check=row_fits)  # fmt: skip


@dataclass(frozen=True)
class ClassGrades:
    """What ``grade_folder`` wrote: the class document (grades.json's content, with the pages' links), the
    class page, and how many of its ``total`` images came from the cache (None without one)."""

    summary: dict[str, Any]
    index: Path
    total: int
    cached: int | None


def grade_folder(
    people: list[Path],
    scenes: list[tuple[str, Scene, Rules]],
    out_dir: Path,
    *,
    workers: int = 0,
    scheduler: str | None = None,
    cache: Path | None = None,
    quiet: bool = True,
    on_start: Callable[[int, int], None] | None = None,
    on_done: Callable[[ClassJob, ClassRow], None] | None = None,
    skipped: list[Skipped] | None = None,
) -> ClassGrades:
    """Grade every student's image of every scene (``scenes``: (file, scene, rules)) and write the class's
    files into ``out_dir`` (a folder that exists): a page per image, index.html, grades.csv, grades.json.

    ``workers``: local processes (0: one per core, none with fewer than 16 images), or a Dask ``scheduler``;
    each process's render cache is sized to this machine's memory (a class that cannot fit is refused).
    ``cache``: a folder keeping each image's row by content hash (``class_cache``). ``on_start(total,
    workers)`` once the work is sized, ``on_done(job, row)`` as each image is graded (a progress bar);
    ``quiet``: no progress of the pages written after the jobs. ``skipped``: the class folder's entries that
    are not students (``skipped_entries``), listed in grades.json and on the class page."""
    from minirt.grading.page import write_class_page
    from minirt.io.images import write_json
    from minirt.jobs import batch as jobs
    from minirt.jobs import memory

    total = len(people) * len(scenes)
    workers = workers or jobs.default_workers(total)
    budget = PROCESS_CACHE_BYTES  # a cluster's workers: their memory is not ours to measure
    if scheduler is None:
        biggest = max(scenes, key=lambda x: x[1].camera.width * x[1].camera.height)[1].camera
        n = max(1, workers)
        budget = memory.class_cache_bytes(
            biggest.width * biggest.height, n, budget,
            f"grading a class at {biggest.width}x{biggest.height} in {n} process{'es' if n > 1 else ''}",
        )  # fmt: skip
    if on_start:
        on_start(total, workers)
    store = None if cache is None else class_cache(cache, out_dir)
    rows = grade_class(
        people, scenes, out_dir, workers=workers, scheduler=scheduler, on_done=on_done, cache=store,
        cache_bytes=budget,
    )  # fmt: skip
    summary = class_dict(rows, [Path(f).stem for f, _, _ in scenes], skipped)
    index = write_class_page(rows, summary, out_dir, quiet=quiet)
    summary["grades"] = [r.as_dict() for r in rows]  # with the pages' links
    write_csv(out_dir / "grades.csv", rows)
    write_json(out_dir / "grades.json", summary)
    return ClassGrades(summary, index, total, None if store is None else store.hits)


def _image_digest(student: Path, scene_file: str) -> str:
    img = find_image(student, Path(scene_file).stem)
    if img is None or folder_problem(student) or image_problem(img):
        return ""  # an error row, never cached
    try:  # streamed, and never through a link swapped in since
        fd = os.open(img, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
        with os.fdopen(fd, "rb") as f:
            return hashlib.file_digest(f, "sha256").hexdigest()
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


def common_unexplained(rows: list[ClassRow], top: int = 10) -> list[dict[str, Any]]:
    """The groups of unexplained pixels across the class, most students first: groups of one scene on the
    same shapes with the same conditions (a threshold's value aside: t > 29.3 and t > 29.4 are one group,
    shown as their range) -> students, images, pixels, and the sentence of the largest one."""
    seen: dict[tuple, dict[str, Any]] = {}
    for r in rows:
        for u in r.unexplained:
            conds = u.get("conditions", {})
            key = (r.scene, tuple(u.get("shapes", [])), tuple(sorted((k, _shape_of(v)) for k, v in conds.items())))
            e = seen.setdefault(key, {"scene": r.scene, "shapes": list(key[1]), "students": set(), "images": 0,
                                      "pixels": 0, "largest": -1, "sentence": "", "ranges": {}})  # fmt: skip
            e["students"].add(r.student)
            e["images"] += 1
            e["pixels"] += int(u.get("pixels", 0))
            if int(u.get("pixels", 0)) > e["largest"]:
                e["largest"], e["sentence"] = int(u.get("pixels", 0)), str(u.get("sentence", ""))
            for k, v in conds.items():
                if _shape_of(v) == "number":
                    lo, hi = e["ranges"].get(k, (v, v))
                    e["ranges"][k] = (min(lo, v), max(hi, v))
                else:
                    e["ranges"][k] = v
    out = []
    for e in seen.values():
        conds = {k: _range(v) for k, v in e["ranges"].items()}
        out.append({"scene": e["scene"], "shapes": e["shapes"], "conditions": conds, "students": len(e["students"]),
                    "images": e["images"], "pixels": e["pixels"], "sentence": e["sentence"]})  # fmt: skip
    out.sort(key=lambda m: (-m["students"], -m["pixels"], m["scene"], m["shapes"], repr(m["conditions"])))
    return out[:top]


def _range(v: Any) -> Any:
    """A condition across images: its value, or [lowest, highest] of a threshold that differs."""
    if not isinstance(v, tuple):
        return v
    return v[0] if v[0] == v[1] else list(v)


def _shape_of(v: Any) -> Any:
    """A condition's value as a group's key: yes/no and shape indices as they are, a threshold as "number"."""
    return "number" if isinstance(v, float) and not isinstance(v, bool) else v


def class_dict(rows: list[ClassRow], scenes: list[str], skipped: list[Skipped] | None = None) -> dict[str, Any]:
    """grades.json's content: the students, scenes, counts, common mistakes, one row per student and scene,
    and the class folder's entries that were skipped (``survey``), each with its reason."""
    counts: dict[str, int] = {MATCH: 0, DIFFERS: 0, ERROR: 0}
    for r in rows:
        counts[r.verdict] += 1
    return {
        "students": sorted({r.student for r in rows}),
        "scenes": scenes,
        "verdicts": counts,
        "common_mistakes": common_mistakes(rows),
        "grades": [r.as_dict() for r in rows],
        "skipped": [k.as_dict() for k in skipped or []],
    } | ({"common_unexplained": common} if (common := common_unexplained(rows)) else {})


def write_csv(path: Path, rows: list[ClassRow]) -> None:
    """grades.csv: one row per student and scene. Every cell is untrusted text made safe for a spreadsheet
    (minirt.io.untrusted.csv_cell: control characters as escapes, a would-be formula given a leading ``'``)."""
    import csv
    import io

    from minirt.io.atomic import atomic_path
    from minirt.io.untrusted import csv_cell

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["student", "scene", "verdict", "rules", "mismatch_pixels", "as_given_pixels", "reason"])
    for r in rows:
        rules = " ".join(f"{k}={v}" for k, v in sorted(r.rules.items()))
        cells = [r.student, r.scene, r.verdict, rules, _blank(r.mismatch_pixels), _blank(r.as_given_pixels), r.reason]
        w.writerow([csv_cell(c) for c in cells])
    with atomic_path(path) as tmp:
        tmp.write_text(buf.getvalue(), encoding="utf-8")


def _blank(v: int | None) -> str:
    return "" if v is None else str(v)
