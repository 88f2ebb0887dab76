"""Hard cases through the student's code (``grade --program SPEC --fuzz N``): a program that follows the
exercise meets the campaign's hard scenes without a numerical failure; one without an offset has acne there,
reported as acne with the scene file that shows it; NaN pixels are counted as such."""

from __future__ import annotations

import json
import sys
from dataclasses import replace
from pathlib import Path

import pytest
from support.programs import minirt

from minirt.cli import program_fuzz
from minirt.grading import hard_cases
from minirt.model.bundled import scene_and_rules
from minirt.model.rules import PROFILES
from minirt.model.scene import load_scene
from minirt.oracles.program import make_spec

ROOT = Path(__file__).resolve().parents[2]
TRACER = ROOT / "tests" / "support" / "numpy_tracer.py"
SIZE = "48"  # the suite's rules show at 48^2; the hard scenes' hazards are drawn for whatever size is given
# The hard scenes are compared under the rules of the graded suite's first scene with the diagnosis'
# changes applied (program_fuzz.run_fuzz). Graded over one scene that diagnoses what the whole suite does,
# a program meets the same hard scenes under the same rules as after the whole suite, for a fraction of
# the grade's CPU: rules, the whole suite's first scene, diagnoses the exercise as the exercise (rules
# {}), and three_balls names offset=0.0 alone, as the suite does. (The whole suite by default:
# tests/program/test_program_cli.py.)


def program(*rules: str) -> str:
    return f"{sys.executable} {TRACER} {' '.join(f'--rule {r}' for r in rules)} {{scene}} {{out}}"


def test_the_exercise_has_no_numerical_failure_and_the_same_bytes_twice(tmp_path):
    docs = []
    for k in range(2):
        p = minirt("grade", "--program", program(), "rules", "--size", SIZE, "--fuzz", "5", "--json", f"g{k}.json",
                   "-q", cwd=tmp_path)  # fmt: skip
        assert p.returncode == 0, p.stderr
        assert "fuzz: 5 hard scenes, 0 with numerical failures or errors" in p.stdout
        docs.append((tmp_path / f"g{k}.json").read_bytes())
    assert docs[0] == docs[1]
    assert json.loads(docs[0])["diagnosis"]["rules"] == {}
    fuzz = json.loads(docs[0])["fuzz"]
    assert [c["family"] for c in fuzz["scenes"]] == ["start", "grazing", "contact", "far", "scaled"]
    assert all(c["verdict"] == "ok" and c["failures"] == 0 and c["scene_file"] == "" for c in fuzz["scenes"])
    assert not list(tmp_path.glob("*.toml"))  # nothing to reproduce, nothing written


def test_no_offset_is_acne_with_its_scene_to_reproduce(tmp_path):
    p = minirt("grade", "--program", program("offset=0"), "three_balls", "--size", SIZE, "--fuzz", "3",
               "--fuzz-dir", "hard", "--json", "-", "-q", cwd=tmp_path)  # fmt: skip
    assert p.returncode == 1, p.stderr
    doc = json.loads(p.stdout)
    assert doc["diagnosis"]["rules"] == {"offset": "0.0"}
    # offset 0's exact answer has no self-shadowing: compared under the robust stand-in for it
    assert doc["fuzz"]["rules"]["offset"] == "error-bound"
    contact = next(c for c in doc["fuzz"]["scenes"] if c["family"] == "contact")
    assert contact["verdict"] == "fails"
    assert contact["pixels"]["acne"] > max(contact["pixels"]["lost_shadow"], contact["pixels"]["nan"])
    assert "acne" in contact["sentence"]
    written = tmp_path / contact["scene_file"]
    assert written == tmp_path / "hard" / "contact_1_0.toml" and written.is_file()
    # the file holds the rules it was compared under: rendered or graded again, it is the same comparison
    _, rules = scene_and_rules(load_scene(written))
    assert rules.offset == "error-bound" and rules.pixel_sample == PROFILES["exercise"].pixel_sample


NAN_ROW = """
import subprocess, sys
subprocess.run([sys.executable, {tracer!r}, *sys.argv[1:]], check=True)
path = sys.argv[-1] + ".pfm"
data = bytearray(open(path, "rb").read())
start = len(data) - 48 * 48 * 12  # the first row the file stores: 48 pixels of three little-endian float32
data[start : start + 48 * 12] = bytes.fromhex("0000c07f") * (48 * 3)
open(path, "wb").write(data)
"""


def test_nan_pixels_are_counted_as_nan(tmp_path, monkeypatch):
    monkeypatch.setenv("MINIRT_PROGRAM_CACHE", str(tmp_path / "programs"))
    script = tmp_path / "nan_tracer.py"
    script.write_text(NAN_ROW.format(tracer=str(TRACER)))
    spec = make_spec(f"{sys.executable} {script} {{scene}} {{out}}")
    rules = hard_cases.hard_rules(PROFILES["exercise"], {})
    cases = program_fuzz.hard_scenes(2, SIZE, rules)
    graded = hard_cases.grade_hard_cases(spec, cases, tmp_path / "hard")
    for case in graded:
        assert case.pixels["nan"] == 48 and case.verdict == "fails", case.as_dict()
        assert Path(case.scene_file).read_text() == next(c[2] for c in cases if c[0] == case.scene)


@pytest.mark.parametrize("kind", hard_cases.KINDS)
def test_every_kind_has_its_sentence(kind):
    case = hard_cases.HardCase("s", "start", hard_cases.FAILS, dict.fromkeys(hard_cases.KINDS, 0) | {kind: 7})
    assert case.sentence().startswith("7 pixels") and case.failures == 7


@pytest.mark.parametrize("profile", sorted(PROFILES))
def test_a_hard_scene_reads_back_with_the_rules_it_is_compared_under(profile):
    """The campaign draws a profile per scene; the file written holds the program's rules instead."""
    rules = replace(PROFILES[profile], t_max=30000.0, raw_normals_ball="both", specular_exponent=16)
    for _, _, text, _scene, own in program_fuzz.hard_scenes(6, "24", rules):
        assert own == rules and 'profile = "exercise"' in text


def test_a_program_that_draws_nothing_is_not_fuzzed(tmp_path):
    script = tmp_path / "crash.py"
    script.write_text("import sys\nsys.exit(3)\n")
    p = minirt("grade", "--program", f"{sys.executable} {script} {{scene}} {{out}}", "--size", SIZE, "--fuzz", "4",
               "--json", "-", "-q", cwd=tmp_path)  # fmt: skip
    fuzz = json.loads(p.stdout)["fuzz"]
    assert fuzz["not_run"] == "the program drew no image of the suite" and fuzz["scenes"] == []
    assert not (tmp_path / "fuzz").exists()
