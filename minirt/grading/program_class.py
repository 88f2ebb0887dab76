"""A class of programs graded at once: each student's program (a C++ source of the exercise, or whatever a
command line runs) rendered over the suite in the sandbox and diagnosed as ``grade --program`` does
(minirt.grading.program), one job per student, one row per student.

``minirt grade --class DIR --program-file raytracer.cpp`` finds the students as image class grading does
(minirt.grading.classroom: the same untrusted-folder rules, the same skipped entries), then runs
``grade_programs``: the jobs here or on Dask (minirt.jobs.batch), and the class's files -- grades.csv,
grades.json and index.html, the names image class grading writes. A student whose program is missing, does
not compile, hangs or crashes is that student's row (verdict ``error``, or ``differs`` when only some
scenes failed), with the reason; the class goes on. The files carry no timings: the same class and suite
write the same bytes.
"""

from __future__ import annotations

import shlex
import stat
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from minirt.errors import MinirtError
from minirt.grading.classroom import Skipped, common_mistakes, folder_problem
from minirt.grading.grade import DIFFERS, ERROR, MATCH
from minirt.model.rules import Rules
from minirt.model.scene import Scene

# A student's reason as the CSV and the class table show it: the first scenes' errors, this many.
REASONS_SHOWN = 2


@dataclass(frozen=True)
class ProgramSource:
    """How each student's program is found and run: ``file``, the name of the file in the student's folder
    (a C++ source is compiled with ``edition``/``adapter``); or ``command``, a command line with ``{dir}``
    (the student's folder) and/or ``{file}`` (that file), besides ``{scene}`` and ``{out}``."""

    file: str | None
    command: str | None = None
    edition: str | None = None
    adapter: Path | None = None
    timeout: float | None = None
    sandbox: bool = True

    @property
    def is_cpp(self) -> bool:
        from minirt.oracles.program import SOURCE_SUFFIXES

        return self.command is None and self.file is not None and Path(self.file).suffix.lower() in SOURCE_SUFFIXES

    @property
    def cpp_edition(self) -> str | None:
        """The edition each student's C++ source is built for (``default_edition``); None for a command."""
        from minirt.oracles.program import default_edition

        return default_edition(self.edition, self.adapter) if self.is_cpp else None

    def check(self) -> None:
        """Bad input before any work, as one line naming the option."""
        from minirt.oracles.program import EDITIONS

        if self.file is not None and (not self.file or "/" in self.file or self.file in (".", "..")):
            raise MinirtError(f"--program-file {self.file!r}: a file's name in each student's folder, no '/'")
        if self.command is None:
            if self.file is None:
                raise MinirtError("--class with a program: give --program-file NAME (or --program-command CMD)")
            if not self.is_cpp:
                raise MinirtError(
                    f"--program-file {self.file}: not a C++ source (.cpp, .cc, .cxx); say how to run it with "
                    "--program-command, e.g. 'python3 {file} {scene} {out}'"
                )
        else:
            words = self.command
            if "{dir}" not in words and "{file}" not in words:
                raise MinirtError(f"--program-command {words!r}: needs {{dir}} (the student's folder) or {{file}}")
            if "{file}" in words and self.file is None:
                raise MinirtError("--program-command uses {file}: give --program-file NAME too")
            if "{out}" not in words or ("{scene}" not in words and "{scene_json}" not in words):
                raise MinirtError(f"--program-command {words!r}: needs {{scene}} (or {{scene_json}}) and {{out}}")
            if self.edition is not None or self.adapter is not None:
                raise MinirtError("--edition and --adapter go with a C++ --program-file, not --program-command")
        if self.edition is not None and self.edition not in EDITIONS:
            raise MinirtError(f"--edition {self.edition}: one of {', '.join(EDITIONS)}")
        if self.adapter is not None and not self.adapter.is_file():
            raise MinirtError(f"--adapter {self.adapter}: no such file")
        if self.cpp_edition == "2013" and self.adapter is None:
            raise MinirtError("--edition 2013: its classes' constructors are the student's; give --adapter FILE")

    def describe(self) -> dict[str, Any]:
        return {
            "file": self.file,
            "command": self.command,
            "edition": self.cpp_edition,
            "adapter": str(self.adapter) if self.adapter else None,
            "sandbox": self.sandbox,
        }


def file_problem(path: Path) -> str | None:
    """Why the student's program file is not used (missing, a link, not a regular file), or None."""
    try:
        st = path.lstat()
    except FileNotFoundError:
        return f"no {path.name} in the student's folder"
    except OSError as e:
        return f"{path.name}: cannot read ({e.strerror or e})"
    if stat.S_ISLNK(st.st_mode):
        return f"{path.name} is a symbolic link; links are not followed (only what is in the class folder is graded)"
    if not stat.S_ISREG(st.st_mode):
        return f"{path.name} is not a regular file"
    return None


def student_spec(source: ProgramSource, student: Path):
    """The ProgramSpec of one student's program, or the reason there is none (a str)."""
    from minirt.oracles.program import ProgramSpec, make_spec

    problem = folder_problem(student)
    if problem is not None:
        return problem
    folder = student.absolute()
    file = folder / source.file if source.file else None
    if file is not None:
        problem = file_problem(file)
        if problem is not None:
            return problem
    if source.command is None:  # a source (make_spec would take a path with a space for a command line)
        return ProgramSpec(str(file), "cpp", source=file, edition=source.cpp_edition, adapter=source.adapter,
                           timeout=source.timeout, sandbox=source.sandbox)  # fmt: skip
    try:
        text = source.command.replace("{dir}", shlex.quote(str(folder)))
        if file is not None:
            text = text.replace("{file}", shlex.quote(str(file)))
        return make_spec(text, None, None, source.timeout, source.sandbox)
    except MinirtError as e:
        return str(e).splitlines()[0]


@dataclass(frozen=True)
class ProgramJob:
    """One student's program to grade: everything a worker process needs."""

    student: str  # the student's folder
    source: ProgramSource
    suite: tuple[tuple[str, Scene, Rules], ...]  # (scene file, scene, rules) as the suite gives them
    profile_given: bool = False  # --profile given: a 2014 source keeps it instead of the edition's rules


@dataclass
class ProgramRow:
    """One student of a class of programs: the verdict, the rules the suite's images name together
    (``rules``; ``undetermined``: those they cannot decide, with the values that fit), the pixels no
    rule explains, why it failed (``reason``), and the program's whole grade document (``grade``, as
    ``grade --program --json`` writes it; None when there is no program to run)."""

    student: str
    verdict: str
    rules: dict[str, str] = field(default_factory=dict)
    undetermined: dict[str, list[str]] = field(default_factory=dict)
    mismatch_pixels: int | None = None
    reason: str = ""
    scenes: list[dict[str, Any]] = field(default_factory=list)  # scene, verdict, mismatch_pixels, error
    sentences: dict[str, str] = field(default_factory=dict)
    grade: dict[str, Any] | None = None

    def as_dict(self) -> dict[str, Any]:
        return {
            "student": self.student,
            "verdict": self.verdict,
            "rules": self.rules,
            "undetermined": self.undetermined,
            "mismatch_pixels": self.mismatch_pixels,
            "reason": self.reason,
            "scenes": self.scenes,
            "grade": self.grade,
        }


def _reason(doc: dict[str, Any]) -> str:
    """A program's failures in one line: the compile error, or its first scenes' errors."""
    compiled = (doc.get("program") or {}).get("compile")
    if compiled is not None and not compiled.get("ok"):
        return next((s["error"] for s in doc["scenes"] if s["error"]), "the program does not compile")
    errors = [s["error"] for s in doc["scenes"] if s["error"]]
    if len(errors) == len(doc["scenes"]) > 1 and len(set(errors)) == 1:
        return f"every scene: {errors[0]}"
    failed = [f"{s['scene']}: {s['error']}" for s in doc["scenes"] if s["error"]]
    more = f" (and {len(failed) - REASONS_SHOWN} more)" if len(failed) > REASONS_SHOWN else ""
    return "; ".join(failed[:REASONS_SHOWN]) + more


def grade_student(job: ProgramJob) -> ProgramRow:
    """Grade one student's program over the suite (in whichever process runs it)."""
    from minirt.grading import program as gp

    name = Path(job.student).name
    spec = student_spec(job.source, Path(job.student))
    if isinstance(spec, str):
        return ProgramRow(name, ERROR, reason=spec)
    suite = [(f, sc, gp.given_rules(r, spec, job.profile_given)) for f, sc, r in job.suite]
    g = gp.grade_program(spec, suite, job.source.timeout)
    doc = g.as_dict()
    d = doc["diagnosis"]
    scenes = [{k: s[k] for k in ("scene", "verdict", "mismatch_pixels", "error")} for s in doc["scenes"]]
    said = {e["rule"]: e["sentence"] for e in d["explained"] if e["rule"] in d["rules"]}
    pixels = None if g.verdict == ERROR else d["mismatch_pixels"]  # no image drawn: nothing to count
    return ProgramRow(name, g.verdict, d["rules"], d["undetermined"], pixels, _reason(doc), scenes,
                      said, doc)  # fmt: skip


def row_fits(job: ProgramJob, row: ProgramRow) -> None:
    """Raise ValueError unless ``row`` (from a worker) is a row of ``job``'s student with a known verdict."""
    if not isinstance(row, ProgramRow):
        raise ValueError(f"not a program's row: {type(row).__name__}")
    if row.student != Path(job.student).name:
        raise ValueError(f"a row of {row.student!r}, not of this student")
    if row.verdict not in (MATCH, DIFFERS, ERROR):
        raise ValueError(f"an unknown verdict {row.verdict!r}")


@dataclass(frozen=True)
class ProgramClassGrades:
    """What ``grade_programs`` wrote: grades.json's content and the class page."""

    summary: dict[str, Any]
    index: Path


def grade_programs(
    people: list[Path],
    source: ProgramSource,
    suite: list[tuple[str, Scene, Rules]],
    out_dir: Path,
    *,
    profile_given: bool = False,
    workers: int = 0,
    scheduler: str | None = None,
    on_start: Callable[[int, int], None] | None = None,
    on_done: Callable[[ProgramJob, ProgramRow], None] | None = None,
    skipped: list[Skipped] | None = None,
) -> ProgramClassGrades:
    """Grade every student's program over ``suite`` ((file, scene, rules)) and write grades.csv, grades.json
    and index.html into ``out_dir`` (a folder that exists). ``workers``: local processes (0: one per core,
    none for fewer than ``PER_WORKER`` students), or a Dask ``scheduler``. ``on_start(total, workers)`` once,
    ``on_done(job, row)`` as each student is graded. A job that fails inside its worker is an error row."""
    from minirt.io.images import write_json
    from minirt.jobs import batch as jobs

    workers = workers or jobs.default_workers(len(people), per_worker=PER_WORKER)
    if on_start:
        on_start(len(people), workers)
    # absolute: a worker process (or a cluster's, with the same paths) need not share this one's folder
    todo = [ProgramJob(str(s.absolute()), source, tuple(suite), profile_given) for s in people]

    def failed(job: ProgramJob, message: str) -> ProgramRow:
        return ProgramRow(Path(job.student).name, ERROR, reason=message)

    rows = jobs.run(grade_student, todo, workers=workers, scheduler=scheduler, on_done=on_done, on_error=failed,
                    check=row_fits)  # fmt: skip
    summary = class_dict(rows, source, [sc.name for _, sc, _ in suite], skipped)
    write_csv(out_dir / "grades.csv", rows)
    write_json(out_dir / "grades.json", summary)
    index = write_programs_page(rows, summary, out_dir)
    return ProgramClassGrades(summary, index)


# A program's job is the whole suite (seconds to a minute): a worker process pays for its start-up (Python,
# Dr.Jit, ~2 s) with two students already.
PER_WORKER = 2


def class_dict(
    rows: list[ProgramRow], source: ProgramSource, scenes: list[str], skipped: list[Skipped] | None = None
) -> dict[str, Any]:
    """grades.json's content: the program's source, the suite's scenes, the verdicts' counts, the rule
    settings most students share, one row per student, and what was skipped in the class folder."""
    counts = {v: sum(r.verdict == v for r in rows) for v in (MATCH, DIFFERS, ERROR)}
    mistakes = [{k: m[k] for k in ("rule", "value", "students")} for m in common_mistakes(rows)]
    return {
        "kind": "programs",
        "program": source.describe(),
        "students": [r.student for r in rows],
        "scenes": scenes,
        "verdicts": counts,
        "common_mistakes": mistakes,
        "grades": [r.as_dict() for r in rows],
        "skipped": [k.as_dict() for k in skipped or []],
    }


def write_csv(path: Path, rows: list[ProgramRow]) -> None:
    """grades.csv: one row per student. Every cell is untrusted text made safe for a spreadsheet
    (minirt.io.untrusted.csv_cell)."""
    import csv
    import io

    from minirt.io.atomic import atomic_path
    from minirt.io.untrusted import csv_cell

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["student", "verdict", "rules", "undetermined", "mismatch_pixels", "scenes_failed", "reason"])
    for r in rows:
        rules = " ".join(f"{k}={v}" for k, v in sorted(r.rules.items()))
        undecided = " ".join(f"{k}={'|'.join(v)}" for k, v in sorted(r.undetermined.items()))
        failed = sum(bool(s["error"]) for s in r.scenes)
        pixels = "" if r.mismatch_pixels is None else str(r.mismatch_pixels)
        w.writerow([csv_cell(c) for c in (r.student, r.verdict, rules, undecided, pixels, str(failed), r.reason)])
    with atomic_path(path) as tmp:
        tmp.write_text(buf.getvalue(), encoding="utf-8")


def write_programs_page(rows: list[ProgramRow], summary: dict[str, Any], out_dir: Path) -> Path:
    """index.html: the verdicts' counts, the most common rule settings (each with its sentence), and a row
    per student -- verdict, rules named, rules undecided, unexplained pixels, each scene's verdict, the
    reason it failed."""
    from minirt.grading.page import VERDICT_CLASS, VERDICTS
    from minirt.pages.assets import page_parts, write_page

    said: dict[tuple[str, str], str] = {}
    for r in rows:
        said.update({(k, r.rules[k]): s for k, s in r.sentences.items() if k in r.rules})
    mistakes = [dict(m, sentence=said.get((m["rule"], m["value"]), "")) for m in summary["common_mistakes"]]
    index = Path(out_dir) / "index.html"
    write_page(
        index, "grade_programs.html", page_parts("grade.js", "report.css", "grade.css"), rows=rows,
        summary=summary, mistakes=mistakes, verdicts=VERDICTS, vclass=VERDICT_CLASS,
        skipped=[(str(k.get("folder", "")), str(k.get("reason", ""))) for k in summary.get("skipped") or []],
    )  # fmt: skip
    return index
