"""Every JSON document the commands write is strict JSON, carries schema_version, and validates against
the JSON Schema shipped in minirt/io/schemas/ -- and those schemas are the ones the models generate.

The documents come from the commands as a user runs them (their entry point, minirt.cli.app.main, in this
process; small images): render sidecars (reference and Embree), check --json - (Embree's tolerance
maxima are infinite: null with a reason), report.json with an embedded sweep, sweep.json, grade --json,
a class's grades.json (one row an error), probe --json, fuzz.json with a defect.
"""

from __future__ import annotations

import copy
import json
import shutil
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import jsonschema
import pytest
from support.inproc import minirt

from minirt.io import documents

ROOT = Path(__file__).resolve().parents[2]


def run(*args, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    return minirt(*args, cwd=cwd)  # the command's entry point, in this process (tests/support/inproc.py)


def strict_loads(text: str):
    def reject(c):
        raise ValueError(f"not strict JSON: {c}")

    return json.loads(text, parse_constant=reject)


@pytest.fixture(scope="module")
def docs(tmp_path_factory) -> SimpleNamespace:
    tmp = tmp_path_factory.mktemp("docs")
    small = ["--width", "16", "--height", "12"]
    p = run("render", "scenes/exercise.toml", "-b", "reference,embree", "-o", tmp / "r", *small, "-q")
    assert p.returncode == 0, p.stderr
    sidecars = sorted((tmp / "r").glob("*.json"))
    p = run("check", "scenes/exercise.toml", "-b", "embree", "--size", "16x12", "--json", "-", "-q")
    assert p.returncode == 0, p.stderr
    check = p.stdout
    p = run("sweep", "scenes/exercise.toml", "-b", "reference", "--size", "8", "--repeats", "1", "-o", tmp / "sw", "-q")
    assert p.returncode == 0, p.stderr
    p = run(
        "report",
        "scenes/exercise.toml",
        "-b",
        "embree",
        "--size",
        "16x12",
        "-o",
        tmp / "rep",
        "--sweep",
        tmp / "sw",
        "-q",
    )
    assert p.returncode == 0, p.stderr
    p = run("grade", "scenes/rules.toml", "scenes/samples/rules.student.png", "--json", "-", "-q")
    assert p.returncode == 1, p.stderr  # the sample differs
    grade = p.stdout
    klass = tmp / "class"
    (klass / "ann").mkdir(parents=True)
    (klass / "bob").mkdir()
    shutil.copy(ROOT / "scenes/samples/rules.student.png", klass / "ann" / "rules.png")
    (klass / "bob" / "rules.png").write_text("not a png")
    p = run("grade", "--class", klass, "-o", tmp / "grades", "--workers", "1", "-q")
    assert p.returncode == 0, p.stderr
    p = run(
        "fuzz", "-n", "2", "--size", "8x8", "-b", "embree", "--defects", "t-scaled", "-o", tmp / "fz", "--workers", "1"
    )
    assert p.returncode == 0, p.stderr
    fuzz = (tmp / "fz" / "fuzz.json").read_text()
    programs = tmp / "programs"
    (programs / "ann").mkdir(parents=True)
    shutil.copy(ROOT / "tests/support/numpy_tracer.py", programs / "ann" / "tracer.py")
    (programs / "bob").mkdir()  # hands in nothing: an error row
    command = f"{sys.executable} {{file}} {{scene}} {{out}}"
    p = run("grade", "--class", programs, "--program-file", "tracer.py", "--program-command", command, "--size", "16",
            "-o", tmp / "program_grades", "--workers", "1", "-q")  # fmt: skip
    assert p.returncode == 0, p.stderr
    p = run("probe", "exercise", "8", "6", *small, "--json")
    assert p.returncode == 0, p.stderr
    return SimpleNamespace(
        tmp=tmp,
        texts={
            "render": [f.read_text() for f in sidecars],
            "check": [check],
            "report": [(tmp / "rep" / "report.json").read_text()],
            "sweep": [(tmp / "sw" / "sweep.json").read_text()],
            "grade": [grade],
            "grades": [(tmp / "grades" / "grades.json").read_text()],
            "program_grades": [(tmp / "program_grades" / "grades.json").read_text()],
            "probe": [p.stdout],
            "fuzz": [fuzz],
        },
    )


@pytest.mark.parametrize("name", sorted(documents.DOCUMENTS))
def test_real_outputs_validate_against_the_shipped_schema(docs, name):
    schema = documents.shipped(name)
    jsonschema.Draft202012Validator.check_schema(schema)
    validator = jsonschema.Draft202012Validator(schema)
    texts = docs.texts[name]
    assert texts
    for text in texts:
        data = strict_loads(text)  # no NaN / Infinity anywhere
        assert data["schema_version"] == 1
        errors = [f"{list(e.path)}: {e.message}" for e in validator.iter_errors(data)]
        assert not errors, errors
        # the schema is not vacuous: a wrong version and a missing required key are caught
        bad = copy.deepcopy(data)
        bad["schema_version"] = 2
        assert not validator.is_valid(bad)
        required = schema["required"]
        bad = {k: v for k, v in data.items() if k != required[-1]}
        assert not validator.is_valid(bad), required[-1]


def test_non_finite_figures_are_null_with_their_reason(docs):
    check = strict_loads(docs.texts["check"][0])
    tol = check["scenes"][0]["backends"]["embree"]["geometry"]["tolerance"]
    assert tol["t_abs_max"] is None  # infinite over the pixels Embree misses
    assert tol["t_abs_max_reason"].startswith("infinite: ")
    assert "Infinity" not in docs.texts["check"][0] and "Infinity" not in docs.texts["report"][0]


def test_a_verdict_outside_the_schema_is_caught(docs):
    v = jsonschema.Draft202012Validator(documents.shipped("grade"))
    g = strict_loads(docs.texts["grade"][0])
    assert g["verdict"] == "differs" and v.is_valid(g)
    g["verdict"] = "maybe"
    assert not v.is_valid(g)


def test_shipped_schemas_are_up_to_date():
    names = {p.name for p in documents.SCHEMAS.glob("*.schema.json")}
    assert names == {f"{n}.schema.json" for n in documents.DOCUMENTS}
    for name in documents.DOCUMENTS:
        shipped = (documents.SCHEMAS / f"{name}.schema.json").read_text(encoding="utf-8")
        assert shipped == documents.schema_text(name), (
            f"minirt/io/schemas/{name}.schema.json is stale: run python -m minirt.io.documents"
        )
