"""The JSON documents minirt writes, as pydantic models: the source of the shipped JSON Schemas.

The writers build plain dicts (minirt.harness.results, minirt.grading.grade, minirt.pages.report,
minirt.sweep.run, minirt.reference.probe, the render sidecar in minirt.io.images) and minirt.io.jsonout
writes them; these models describe the result, so a reader (or a test) can validate a file with any JSON
Schema validator. Each model lists the keys a reader can rely on; open parts (a check's figures, a backend's
metadata) allow more keys. A number that may be absent or non-finite is ``number | null``; beside a null from
a non-finite value stands ``<key>_reason`` (minirt.io.jsonout).

``python -m minirt.io.documents`` rewrites ``minirt/io/schemas/*.schema.json`` from these models (a test checks
that the shipped files are up to date).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from minirt.io.jsonout import SCHEMA_VERSION

SCHEMAS = Path(__file__).resolve().parent / "schemas"
DIALECT = "https://json-schema.org/draft/2020-12/schema"

CheckVerdict = Literal["pass", "warn", "fail", "error", "skip"]
GradeVerdict = Literal["match", "differs", "error"]
Num = float | None  # absent, or non-finite with a "<key>_reason" beside it
RuleValues = dict[str, Any]  # rule name -> value (bool, number, text or a pair)


class _Open(BaseModel):
    """A part of a document that may carry more keys than are listed (figures, metadata, reasons)."""

    model_config = ConfigDict(extra="allow")


class _Document(_Open):
    schema_version: Literal[1] = Field(description="The document layout's version; bumped on incompatible changes.")


# ---------------------------------------------------------------------------------------------
# check.json (minirt check --json) and report.json


class Inconclusive(BaseModel):
    """Whether a geometry check could have failed on most of what it judges (THRESHOLDS inconclusive_fraction).
    Non-empty ``reasons``: the check is WARN with a reason starting "inconclusive: ", never PASS."""

    reasons: list[str] = Field(description="Why the check could not fail on most pixels; empty when conclusive.")
    hit_pixels: int = Field(description="Pixels either side calls a hit.")
    judged_pixels: int = Field(description="Pixels both call a hit on the same shape, outside the band.")
    band_fraction: float = Field(description="Fraction of the hit pixels inside the band (not judged).")
    depth_range: float = Field(description="max - min t over the reference's hits.")
    t_wide_fraction: float = Field(description="Fraction of judged pixels whose t tolerance >= depth_range.")
    normal_wide_fraction: float = Field(description="Fraction of judged pixels whose normal tolerance >= 90 deg.")
    limit: float = Field(description="The fraction above which the check is inconclusive.")


class Check(_Open):
    """One check of one backend (preflight, geometry, shading, stochastic, samples): its verdict, and its
    figures as further keys."""

    verdict: CheckVerdict
    reason: str = ""
    inconclusive: Inconclusive | None = Field(default=None, description="Geometry: could the check have failed.")
    thresholds: dict[str, str] = Field(default_factory=dict, description="Each threshold applied, with its reason.")


class RuleDiagnosis(_Open):
    """The rule settings that explain the oracle's colour image (absent figures when it did not run)."""

    ran: bool
    reason: str = ""
    rules_explaining: dict[str, str] = Field(default_factory=dict)
    explained: dict[str, int] = Field(default_factory=dict)
    mismatch_pixels: int = 0
    pixels: int = 0


class BackendCheck(_Open):
    """One oracle against the reference on one scene; the checks by name, each a Check."""

    verdict: CheckVerdict
    inconclusive: bool = Field(
        default=False, description="WARN only because checks could not fail on most of what they judge."
    )
    reason: str = ""
    preflight: Check | None = None
    geometry: Check | None = None
    shading: Check | None = None
    stochastic: Check | None = None
    samples: Check | None = None
    rule_effects: dict[str, int] = Field(default_factory=dict)
    rule_diagnosis: RuleDiagnosis
    rules_followed: RuleValues = Field(default_factory=dict)
    seconds: float
    version: Any = None


class SceneCheck(_Open):
    scene: str
    file: str = Field(description="The scene file as given; a bundled scene by its name (exercise).")
    verdict: CheckVerdict
    description: str = ""
    reason: str = ""
    backends: dict[str, BackendCheck]


class Threshold(BaseModel):
    value: float
    why: str


class CheckDocument(_Document):
    """``minirt check --json FILE``: every scene's verdicts and figures, and the thresholds applied."""

    verdict: CheckVerdict
    scenes: list[SceneCheck]
    thresholds: dict[str, Threshold]


class ReportMeta(_Open):
    command: str
    date: str
    machine: Any = None
    versions: dict[str, Any] = Field(default_factory=dict)
    assets: list[str] = Field(default_factory=list, description="The report's image files, relative to it.")


class ReportDocument(CheckDocument):
    """``minirt report``'s report.json: the check document, the page's metadata, and the embedded sweep."""

    report: ReportMeta
    sweep: dict[str, Any] | None = Field(default=None, description="sweep.json as read from --sweep DIR.")


# ---------------------------------------------------------------------------------------------
# minirt grade --json, and grades.json of a class


class Explained(_Open):
    rule: str
    value: str
    pixels: int
    sentence: str


class Unexplained(_Open):
    pixels: int
    shapes: list[int] = Field(description="Indices in the scene's [[shapes]] (-1: no shape, the background).")
    conditions: dict[str, Any] = Field(description="What holds for the group's pixels (t_above, lit, ...).")
    sentence: str
    example: list[int] = Field(description="(x, y) of one pixel of the group, for minirt probe --image.")


class Diagnosis(_Open):
    rules: dict[str, str] = Field(description="The rule settings, changed from the scene's, that explain the image.")
    mismatch_pixels: int
    explained: list[Explained]
    search: dict[str, Any] = Field(default_factory=dict)
    unexplained: list[Unexplained] = Field(
        default_factory=list, description="The pixels no rule setting explains, in groups, largest first."
    )


class AsGiven(_Open):
    mismatch_pixels: int
    rules: dict[str, str]


class GradeDocument(_Document):
    """``minirt grade SCENE IMAGE --json FILE``. A verdict "error" carries the reason and no diagnosis."""

    verdict: GradeVerdict
    scene: str | None
    scene_file: str
    image: str
    summary: str
    notes: list[str] = Field(default_factory=list)
    reason: str = ""
    size: list[int] | None = Field(default=None, description="[width, height] graded.")
    pixels: int | None = None
    image_format: Literal["8-bit", "float"] | None = None
    tolerance: str | None = None
    ill_conditioned_pixels: int | None = None
    as_given: AsGiven | None = None
    diagnosis: Diagnosis | None = None
    indistinguishable: list[dict[str, Any]] = Field(default_factory=list)
    reproduce: str | None = Field(default=None, description="The minirt render command whose PNG is the image.")


class ClassRow(_Open):
    student: str
    scene: str
    verdict: GradeVerdict
    rules: dict[str, str]
    mismatch_pixels: int | None
    as_given_pixels: int | None
    reason: str = ""
    page: str = Field(default="", description="The image's page, relative to grades.json.")


class Mistake(_Open):
    rule: str
    value: str
    students: int
    images: int
    differing_images: int


class SkippedEntry(_Open):
    folder: str = Field(description="The entry's name in the class folder, exactly.")
    reason: str = Field(description="Why it was not graded: hidden (its name starts with a dot), not a folder.")


class ClassDocument(_Document):
    """``minirt grade --class DIR``'s grades.json (and its --json): one row per student and scene."""

    students: list[str]
    scenes: list[str]
    verdicts: dict[GradeVerdict, int]
    common_mistakes: list[Mistake]
    common_unexplained: list[dict[str, Any]] = Field(
        default_factory=list,
        description="Groups of unexplained pixels across the class (same scene, shapes and conditions), most "
        "students first; left out when there are none.",
    )
    grades: list[ClassRow]
    skipped: list[SkippedEntry] = Field(
        default_factory=list, description="Entries of the class folder that are not students, and why."
    )


class ProgramRow(_Open):
    student: str
    verdict: GradeVerdict
    rules: dict[str, str] = Field(
        description="The rules the suite's images name together, values as --rule takes them."
    )
    undetermined: dict[str, list[str]] = Field(description="Rules the images cannot decide -> the values that fit.")
    mismatch_pixels: int | None = Field(description="Pixels no rule setting explains; null when no image was drawn.")
    reason: str = Field(description="Why it failed: no program, the compiler's first error, the scenes' errors.")
    scenes: list[dict[str, Any]] = Field(description="Per suite scene: scene, verdict, mismatch_pixels, error.")
    grade: dict[str, Any] | None = Field(description="The program's whole grade, as grade --program --json writes it.")


class ProgramMistake(_Open):
    rule: str
    value: str
    students: int


class ProgramClassDocument(_Document):
    """``minirt grade --class DIR --program-file NAME``'s grades.json (and its --json): one row per student."""

    kind: Literal["programs"]
    program: dict[str, Any] = Field(description="The program's file, command, edition, adapter and sandbox.")
    students: list[str]
    scenes: list[str]
    verdicts: dict[GradeVerdict, int]
    common_mistakes: list[ProgramMistake]
    grades: list[ProgramRow]
    skipped: list[SkippedEntry] = Field(default_factory=list)


# ---------------------------------------------------------------------------------------------
# sweep.json


class SweepRow(_Open):
    backend: str
    knob: str | None
    value: Any = None
    cost: Any = None
    status: str
    reason: str = ""
    seconds_median: Num = None
    runs: list[Num] = Field(default_factory=list)
    metric: str | None = None
    error: dict[str, Any] = Field(default_factory=dict)
    pareto: bool = False


class SweepJobs(_Open):
    """How the series ran: one after the other here (workers 1), or at once (their times share cores)."""

    workers: int = Field(description="Local processes the series ran in at once (1: one after the other).")
    scheduler: str | None = Field(description="The Dask scheduler's address, or null for this machine.")
    where: str = Field(description="The machine the times were taken on (host/cores), or the scheduler.")
    cached: int = Field(description="Series taken from --cache instead of rendered.")


class SweepDocument(_Document):
    """``minirt sweep``'s sweep.json: every setting's time and error, fits and the Pareto front."""

    scene: str
    source: str | None = None
    size: list[int]
    repeats: int
    rules: RuleValues
    jobs: SweepJobs | None = None
    rows: list[SweepRow]
    slopes: dict[str, Any] = Field(default_factory=dict)
    pareto: dict[str, Any] = Field(default_factory=dict)


# ---------------------------------------------------------------------------------------------
# render sidecars and probe


class RenderSidecar(_Document):
    """``minirt render``'s SCENE.BACKEND[+VARIANT].json beside the images: the backend's metadata."""

    backend: str
    status: str
    reason: str = ""
    width: int
    height: int
    scene: str | None = None
    rules: RuleValues = Field(default_factory=dict)
    version: Any = None


class ProbeOffset(_Open):
    """Where a secondary ray starts at this hit, and what could go wrong there (minirt.reference.hazards.offset_at)."""

    offset: float | Literal["error-bound"]
    along: str = "normal"
    rounding: float | None = Field(default=None, description="The hit point's rounding u·‖p‖₁ in the traced precision.")
    below_rounding: bool = Field(default=False, description="The offset's normal part is below it: acne risk.")
    jumps: list[dict[str, Any]] = Field(
        default_factory=list, description="Other shapes' surfaces between the point and a secondary ray's origin."
    )


class ProbeLevel(_Open):
    depth: int
    ray: dict[str, list[float]]
    shapes: list[dict[str, Any]]
    hit: dict[str, Any] | None
    terms: dict[str, Any]
    offset: ProbeOffset | None = None


class ProbeDocument(_Document):
    """``minirt probe SCENE X Y --json``: one pixel traced step by step."""

    scene: str
    pixel: list[int]
    rules: RuleValues
    levels: list[ProbeLevel]
    color: list[float]
    color_clamped: list[float]
    color8: list[int]
    offset: ProbeOffset | None = None
    image: dict[str, Any] | None = None


# ---------------------------------------------------------------------------------------------
# fuzz.json


class FuzzFailure(BaseModel):
    scene: str = Field(description="The scene's name; its file, check JSON and images are in the output folder.")
    family: str
    backend: str
    verdict: Literal["fail", "error"]
    reason: str


class DefectFigures(BaseModel):
    summary: str = Field(description="The tracer bug the defect stands for.")
    changes: int = Field(description="Scenes where the defect changes what some oracle's check judges.")
    changes_judged: int = Field(
        description="... on pixels that check judges (outside its bands, ties and edges), the scene conclusive."
    )
    caught: int = Field(description="Scenes where an oracle it changes FAILed.")
    rate: float | None = Field(description="caught / changes; null when it changed no scene.")
    rate_judged: float | None = Field(description="The same over the scenes in changes_judged.")
    missed: list[str]
    missed_judged: list[str]


class FuzzDocument(_Document):
    """``minirt fuzz``'s fuzz.json (and its --json): the campaign's verdicts, failures and defect catch rates.
    No timings: the same command gives the same bytes, whether its jobs ran or came from the cache."""

    seed: int
    families: list[str]
    size: list[int]
    backends: list[str]
    scenes: int
    jobs: int = Field(description="Scenes x oracles.")
    verdicts: dict[CheckVerdict, int]
    inconclusive: int = Field(description="WARN verdicts whose only cause is a check that could not fail.")
    failures: list[FuzzFailure]
    by_family: dict[str, dict[CheckVerdict, int]]
    defects: dict[str, DefectFigures] = Field(default_factory=dict)


DOCUMENTS: dict[str, type[_Document]] = {
    "check": CheckDocument,
    "report": ReportDocument,
    "grade": GradeDocument,
    "grades": ClassDocument,
    "program_grades": ProgramClassDocument,
    "sweep": SweepDocument,
    "render": RenderSidecar,
    "probe": ProbeDocument,
    "fuzz": FuzzDocument,
}


def schema(name: str) -> dict[str, Any]:
    """The JSON Schema of document ``name`` (one of DOCUMENTS), as shipped."""
    model = DOCUMENTS[name]
    s = model.model_json_schema()
    return {
        "$schema": DIALECT,
        "$id": f"minirt/{name}.schema.json",
        "x-minirt-schema-version": SCHEMA_VERSION,
        **s,
    }


def schema_text(name: str) -> str:
    return json.dumps(schema(name), indent=2, sort_keys=True, allow_nan=False) + "\n"


def shipped(name: str) -> dict[str, Any]:
    """The shipped schema file of document ``name``."""
    return json.loads((SCHEMAS / f"{name}.schema.json").read_text(encoding="utf-8"))


def write_schemas(folder: Path = SCHEMAS) -> list[Path]:
    """Every document's schema as ``folder/NAME.schema.json`` (``make schemas``), through minirt.io.atomic."""
    from minirt.io.atomic import write_all

    return write_all({folder / f"{name}.schema.json": schema_text(name) for name in DOCUMENTS})


if __name__ == "__main__":
    for p in write_schemas():
        print(f"wrote {p.name}")
