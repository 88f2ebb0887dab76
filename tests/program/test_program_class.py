"""A class of programs (``grade --class DIR --program-file NAME``): C++ solutions of the 2014 edition -- the
bundled sample, a corrected copy, one that does not compile, one that hangs -- and small Python programs, one
row per student with the diagnosis or the reason it failed; the files the same bytes on a re-run and on the
embedded Dask cluster."""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

import pytest
from support.inproc import minirt as here
from support.programs import grading_suite, minirt

from minirt.grading import classroom
from minirt.grading import program_class as pc

ROOT = Path(__file__).resolve().parents[2]
TRACER = ROOT / "tests" / "support" / "numpy_tracer.py"
SAMPLE_2014 = ROOT / "scenes" / "samples" / "raytracer2014.cpp"
SIZE = 48  # the sample's two primary-ray bugs show on hundreds of pixels of each grading scene at 48^2
HANG = 1.0  # seconds a scene of the hanging program may take: it is killed at this, three times


def _defines(text: str, **values: str) -> str:
    for name, value in values.items():
        start = text.index(f"#define {name} ")
        text = text[:start] + f"#define {name} {value}" + text[text.index("\n", start) :]
    return text


def suite(stems=("rules", "three_balls", "exercise")):
    return grading_suite(stems, SIZE)


@pytest.fixture(scope="module")
def cpp_class(tmp_path_factory):
    """DIR/<student>/raytracer.cpp for five students, graded once for the module's tests."""
    mp = pytest.MonkeyPatch()
    mp.setenv("MINIRT_PROGRAM_CACHE", str(tmp_path_factory.mktemp("programs")))
    root = tmp_path_factory.mktemp("cpp")
    text = SAMPLE_2014.read_text()
    sources = {
        "ann": text,  # the sample: pixel corners, rays from the image plane
        "ben": _defines(text, OFFSET="1e-3", PIXEL="0.5", FROM_PLANE="0"),  # the edition, exactly
        "cat": text.replace("void add_shape(const Shape& s) {", "void add_shape(const Shape& s) { undeclared();"),
        "dan": text.replace(
            "void raytrace(Bitmap& bitmap, int depth) const {",
            "void raytrace(Bitmap& bitmap, int depth) const { for (volatile int i = 0;;) (void)i;",
        ),
    }
    for name, source in sources.items():
        (root / "class" / name).mkdir(parents=True)
        (root / "class" / name / "raytracer.cpp").write_text(source)
    (root / "class" / "eve").mkdir()  # handed in nothing
    (root / "class" / "ida n").mkdir()  # a space in the folder's name; ben's source (its build is reused)
    (root / "class" / "ida n" / "raytracer.cpp").write_text(sources["ben"])
    (root / "class" / "fay").symlink_to(root / "class" / "ann")  # another's folder, linked: not followed
    (root / "class" / "gus").mkdir()
    (root / "class" / "gus" / "raytracer.cpp").symlink_to(SAMPLE_2014)  # a link out of the class folder
    (root / "class" / ".git").mkdir()
    people = classroom.students(root / "class")
    skipped = classroom.skipped_entries(root / "class")
    out = root / "out"
    out.mkdir()
    source = pc.ProgramSource("raytracer.cpp", timeout=HANG)
    graded = pc.grade_programs(people, source, suite(), out, workers=1, skipped=skipped)
    yield graded, out
    mp.undo()


def rows_of(graded) -> dict[str, dict]:
    return {r["student"]: r for r in graded.summary["grades"]}


def test_each_student_is_one_row_with_the_diagnosis_or_the_reason(cpp_class):
    graded, _out = cpp_class
    rows = rows_of(graded)
    assert list(rows) == ["ann", "ben", "cat", "dan", "eve", "fay", "gus", "ida n"]
    assert rows["ann"]["verdict"] == "differs"
    assert rows["ann"]["rules"] == {"pixel_sample": "corner", "ray_origin": "image-plane"}
    assert rows["ann"]["undetermined"] == {} and rows["ann"]["mismatch_pixels"] == 0
    assert rows["ben"]["verdict"] == "match" and rows["ben"]["rules"] == {}
    assert [s["verdict"] for s in rows["ben"]["scenes"]] == ["match"] * 3
    # the compiler's own first message, naming the line
    assert rows["cat"]["verdict"] == "error" and "does not compile" in rows["cat"]["reason"]
    assert "undeclared" in rows["cat"]["reason"] and "raytracer.cpp:" in rows["cat"]["reason"]
    assert rows["cat"]["grade"]["program"]["compile"]["ok"] is False
    # a program that hangs costs its scenes' limits and is that student's error; the class went on
    assert rows["dan"]["verdict"] == "error" and rows["dan"]["reason"].startswith("every scene: ")
    assert "did not finish in 1 s" in rows["dan"]["reason"]
    assert rows["eve"] == {**rows["eve"], "verdict": "error", "reason": "no raytracer.cpp in the student's folder"}
    assert rows["eve"]["grade"] is None and rows["eve"]["mismatch_pixels"] is None
    assert rows["fay"]["verdict"] == "error" and "the student folder is a symbolic link" in rows["fay"]["reason"]
    assert rows["gus"]["reason"].startswith("raytracer.cpp is a symbolic link; links are not followed")
    assert rows["ida n"]["verdict"] == "match"
    assert graded.summary["verdicts"] == {"match": 2, "differs": 1, "error": 5}
    assert graded.summary["skipped"] == [{"folder": ".git", "reason": "hidden (its name starts with a dot)"}]
    assert graded.summary["program"]["edition"] == "2014"


def test_the_class_files_say_the_same(cpp_class):
    graded, out = cpp_class
    with open(out / "grades.csv", newline="") as f:
        table = list(csv.DictReader(f))
    assert [r["student"] for r in table] == ["ann", "ben", "cat", "dan", "eve", "fay", "gus", "ida n"]
    assert table[0]["rules"] == "pixel_sample=corner ray_origin=image-plane" and table[0]["verdict"] == "differs"
    assert table[3]["scenes_failed"] == "3" and table[1]["scenes_failed"] == "0"
    assert json.loads((out / "grades.json").read_text())["grades"][0]["rules"] == rows_of(graded)["ann"]["rules"]
    page = (out / "index.html").read_text()
    assert "pixel_sample=corner" in page and "undeclared" in page and ".git" in page
    mistakes = {(m["rule"], m["value"]): m["students"] for m in graded.summary["common_mistakes"]}
    assert mistakes == {("pixel_sample", "corner"): 1, ("ray_origin", "image-plane"): 1}


def _python_class(root: Path) -> Path:
    cls = root / "class"
    text = TRACER.read_text()
    programs = {
        "alice": text,
        "bob": text.replace('"pixel_sample": "corner"', '"pixel_sample": "center"'),
        "carol": "import sys\nsys.exit(3)\n",  # crashes on every scene
        "dora": text.replace('"specular_exponent": 8', '"specular_exponent": 16'),
    }
    for name, body in programs.items():
        (cls / name).mkdir(parents=True)
        (cls / name / "tracer.py").write_text(body)
    return cls


def test_a_class_of_python_programs_from_the_command_line_same_bytes_on_dask(tmp_path):
    cls = _python_class(tmp_path)
    command = f"{sys.executable} {{file}} {{scene}} {{out}}"
    # The rules scene alone, not the whole suite: a worker's job is a student's whole suite, however long,
    # so the workers and the files carry the same things for an eighth of the program runs and diagnoses.
    # At 48^2 the rules scene alone tells pixel_sample=center and specular_exponent=16 from every other
    # change (bob's and dora's diagnoses name exactly them, below). The suite by default:
    # test_a_class_is_graded_over_the_whole_program_suite_by_default.
    common = ["grade", "--class", str(cls), "--program-file", "tracer.py", "--program-command", command,
              "rules", "--size", str(SIZE), "-q"]  # fmt: skip
    files = {}
    for workers in ("1", "2"):
        out = tmp_path / f"out{workers}"
        p = minirt(*common, "--workers", workers, "-o", str(out), "--json", str(out / "class.json"), cwd=tmp_path)
        assert p.returncode == 0, p.stderr
        assert "graded 4 programs over 1 scene: 1 match, 2 differ, 1 error" in p.stdout
        files[workers] = {n: (out / n).read_bytes() for n in ("grades.csv", "grades.json", "index.html")}
    assert files["1"] == files["2"]
    doc = json.loads(files["1"]["grades.json"])
    rows = {r["student"]: r for r in doc["grades"]}
    assert rows["alice"]["verdict"] == "match"
    assert rows["bob"]["rules"] == {"pixel_sample": "center"}
    assert rows["dora"]["rules"] == {"specular_exponent": "16"}
    assert rows["carol"]["reason"] == "rules: the program failed with exit status 3"
    assert doc["program"]["command"] == command
    assert doc["scenes"] == ["rules"]


def test_a_class_is_graded_over_the_whole_program_suite_by_default(tmp_path):
    """No SCENE: every student's program over the program suite at its size. A program that exits at
    once shows it at the cost of starting Python once a scene."""
    from minirt.grading.suite import program_suite

    cls = tmp_path / "class"
    (cls / "carol").mkdir(parents=True)
    (cls / "carol" / "tracer.py").write_text("import sys\nsys.exit(3)\n")
    command = f"{sys.executable} {{file}} {{scene}} {{out}}"
    p = minirt("grade", "--class", str(cls), "--program-file", "tracer.py", "--program-command", command,
               "-o", "out", "--json", "class.json", "-q", cwd=tmp_path)  # fmt: skip
    names = [s.name for s in program_suite()]
    assert p.returncode == 0, p.stderr
    assert f"graded 1 program over {len(names)} scenes: 0 match, 0 differ, 1 error" in p.stdout
    doc = json.loads((tmp_path / "class.json").read_text())
    assert doc["scenes"] == names
    (row,) = doc["grades"]
    assert row["reason"] == "every scene: the program failed with exit status 3"
    assert [s["scene"] for s in row["scenes"]] == names


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["--class", "C", "--program-file", "a/tracer.cpp"], "a file's name in each student's folder"),
        (["--class", "C", "--program-file", "tracer.py"], "say how to run it with --program-command"),
        (["--class", "C", "--program-command", "python3 t.py {scene} {out}"], "needs {dir}"),
        (["--class", "C", "--program-command", "python3 {file} {scene} {out}"], "give --program-file NAME too"),
        (["--class", "C", "--program-file", "r.cpp", "--edition", "2013"], "give --adapter FILE"),
        (["--program-file", "r.cpp"], "grade a class: --class DIR"),
        (["--fuzz", "3", "rules", "x.png"], "--fuzz and --fuzz-dir go with --program"),
        (["--class", "missing", "--program-file", "r.cpp"], "--class missing: no such folder"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, args, words):
    (tmp_path / "C" / "someone").mkdir(parents=True)
    p = here("grade", *args, cwd=tmp_path)  # in this process: an exit status and a line, no process needed
    assert p.returncode == 2 and words in p.stderr and "Traceback" not in p.stderr, p.stderr
    assert not (tmp_path / "grades").exists()  # nothing written before the input was found good


def test_the_class_page_loads_clean_in_a_browser(cpp_class, tmp_path):
    from support.browser import console, loaded_page

    _, out = cpp_class
    dom, attrs = loaded_page(tmp_path, (out / "index.html").resolve().as_uri(), "data-ready")
    assert attrs["data-errors"] == "0" and attrs["data-csp-violations"] == "0", attrs
    assert not console(dom), console(dom)
    # the counts' header, cat, dan, eve, fay and gus, and each of cat's and dan's three scenes (the others drew none)
    assert dom.stdout.count('class="badge v-fail"') == 1 + 5 + 2 * 3


def test_a_class_given_an_adapter_is_of_the_2013_edition_and_graded_without_the_2014_course_scenes(tmp_path):
    from minirt.cli.program import load_suite

    adapter = tmp_path / "adapter.cpp"
    adapter.write_text("// the course's adapter\n")
    given = pc.ProgramSource("raytracer.cpp", adapter=adapter)
    given.check()
    assert given.cpp_edition == "2013" and given.describe()["edition"] == "2013"
    plain = pc.ProgramSource("raytracer.cpp")
    assert (
        plain.cpp_edition == "2014"
        and pc.ProgramSource("t.py", command="python3 {file} {scene} {out}").cpp_edition is None
    )

    def course_scenes(source) -> int:
        stems = [Path(f).stem for f, _, _ in load_suite(None, "24x24", None, [], source.cpp_edition)]
        return sum(s.startswith("course2014_") for s in stems)

    assert course_scenes(given) == 0 and course_scenes(plain) == 6
