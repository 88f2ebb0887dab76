"""`minirt grade` as a user runs it (its entry point, cwd the repository; a child process where only a
process shows it: all of stdout, Dask workers of its own): exit codes (0 match, 1 differs, 2 bad input
with exactly one `minirt: error:` line and no traceback), a transposed image, strict JSON on standard
output, the reproduce command as the acceptance test of a diagnosis, a bundled scene by name, and class
mode (a missing and a corrupt image are rows, the same command writes the same bytes).

Student images come from tests/support/plain.py (tests/support/students.py) on small copies of bundled scenes (48x48).
"""

from __future__ import annotations

import csv
import io
import json
import shlex
import shutil
import subprocess
import sys
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from support.inproc import minirt
from support.students import levels_off, student_image

from minirt.io.images import read_image_u8, write_image
from minirt.model import rules as R
from minirt.model.scene import load_scene

ROOT = Path(__file__).resolve().parents[2]
MINIRT = [sys.executable, "-m", "minirt"]
SIZE = 48
MISTAKES = {"pixel_sample": "center", "rows": "bottom-up"}


def run(*args, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    """The command's entry point in this process (tests/support/inproc.py): its exit status and both streams."""
    return minirt(*args, cwd=cwd)


def run_child(*args, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    """A child process, as a user starts it: for what only a process shows (all of its stdout and stderr,
    Dask worker processes of its own)."""
    return subprocess.run([*MINIRT, *map(str, args)], cwd=cwd, capture_output=True, text=True, timeout=300)


def strict_json(text: str):
    def reject(c):
        raise ValueError(f"not strict JSON: {c}")

    return json.loads(text, parse_constant=reject)


def scene_copy(stem: str, dest: Path, width: int = SIZE, height: int = SIZE) -> Path:
    """A bundled scene's TOML with the camera's size set (one sample per pixel)."""
    out = []
    for line in (ROOT / "scenes" / f"{stem}.toml").read_text().splitlines():
        if line.split("=")[0].strip() in ("width", "height", "samples"):
            continue
        out.append(line)
        if line.strip() == "[camera]":
            out += [f"width = {width}", f"height = {height}"]
    dest.write_text("\n".join(out) + "\n")
    sc = load_scene(dest)
    assert (sc.camera.width, sc.camera.height, sc.samples) == (width, height, 1), dest.read_text()
    return dest


def student_png(scene_file: Path, path: Path, **rules) -> np.ndarray:
    sc = load_scene(scene_file).with_overrides(samples=1)
    img = student_image(sc, replace(R.resolve(sc), **rules))
    write_image(path, img)
    return img


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> SimpleNamespace:
    tmp = tmp_path_factory.mktemp("grade-cli")
    scenes = tmp / "scenes"
    scenes.mkdir()
    rules_toml = scene_copy("rules", scenes / "rules.toml")
    exercise_toml = scene_copy("exercise", scenes / "exercise.toml")
    ns = SimpleNamespace(tmp=tmp, scenes=scenes, rules_toml=rules_toml, exercise_toml=exercise_toml)
    ns.match = tmp / "match.png"
    student_png(rules_toml, ns.match)
    ns.differs = tmp / "differs.png"
    ns.differs_img = student_png(rules_toml, ns.differs, **MISTAKES)
    return ns


def one_error_line(p: subprocess.CompletedProcess) -> str:
    assert p.returncode == 2, (p.returncode, p.stdout, p.stderr)
    assert "Traceback" not in p.stderr + p.stdout
    lines = p.stderr.splitlines()
    assert len(lines) == 1, p.stderr
    assert lines[0].startswith("minirt: error: "), lines[0]
    return lines[0]


# ---------------------------------------------------------------------------------------------
def test_match_exits_0(work):
    p = run("grade", work.rules_toml, work.match)
    assert p.returncode == 0, p.stderr
    assert p.stderr.startswith("MATCH rules: the image is the scene's model as given"), p.stderr
    assert "Traceback" not in p.stderr


def test_differs_exits_1(work):
    p = run("grade", work.rules_toml, work.differs)
    assert p.returncode == 1, p.stderr
    assert p.stderr.startswith("DIFFERS rules:"), p.stderr
    assert "pixel_sample=center" in p.stderr and "rows=bottom-up" in p.stderr and "reproduce: minirt render" in p.stderr


def _bad_inputs(work) -> dict[str, tuple[list, str]]:
    t = work.tmp / "bad"
    t.mkdir(exist_ok=True)
    (t / "folder.png").mkdir(exist_ok=True)
    (t / "picture.gif").write_bytes(b"GIF89a" + bytes(64))
    (t / "corrupt.png").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 4)
    whole = work.match.read_bytes()
    (t / "truncated.png").write_bytes(whole[: len(whole) // 2])
    write_image(t / "small.png", np.zeros((32, 40, 3), np.uint8))
    (t / "empty_class").mkdir(exist_ok=True)
    (t / "one_class" / "s").mkdir(parents=True, exist_ok=True)
    (t / "one_class" / "s" / "rules.png").write_bytes(work.match.read_bytes())
    scene = work.rules_toml
    one_class = ["grade", "--class", t / "one_class", "--scenes", work.scenes]
    return {
        "missing image": (["grade", scene, t / "none.png"], "no such image file"),
        "folder as image": (["grade", scene, t / "folder.png"], "is a folder"),
        "unsupported extension": (["grade", scene, t / "picture.gif"], "unsupported image type .gif"),
        "corrupt png": (["grade", scene, t / "corrupt.png"], "corrupt.png: cannot read image"),
        "truncated png": (["grade", scene, t / "truncated.png"], "truncated.png: cannot read image"),
        "wrong size": (["grade", scene, t / "small.png"], "40x32"),
        "unknown scene": (["grade", "no_such_scene", work.match], "no_such_scene"),
        "class with scene": (["grade", "--class", work.tmp, scene], "--class"),
        "scenes without class": (["grade", scene, work.match, "--scenes", work.scenes], "--scenes"),
        "class on empty folder": (["grade", "--class", t / "empty_class", "--out", t / "o"], "empty_class"),
        "workers without class": (["grade", scene, work.match, "--workers", "2"], "--workers goes with --class"),
        "scheduler unreachable": (
            [*one_class, "--out", t / "o2", "--scheduler", "tcp://127.0.0.1:9"],
            "--scheduler tcp://127.0.0.1:9: cannot reach",
        ),
        "workers and scheduler": (
            [*one_class, "--out", t / "o3", "--workers", "2", "--scheduler", "tcp://127.0.0.1:9"],
            "--workers and --scheduler: give one",
        ),
        "json unwritable": (["grade", scene, work.match, "--json", "/proc/x/y.json"], "/proc/x"),
    }


BAD = [
    "missing image",
    "folder as image",
    "unsupported extension",
    "corrupt png",
    "truncated png",
    "wrong size",
    "unknown scene",
    "class with scene",
    "scenes without class",
    "class on empty folder",
    "workers without class",
    "scheduler unreachable",
    "workers and scheduler",
    "json unwritable",
]


@pytest.mark.parametrize("case", BAD)
def test_bad_input_is_one_line_exit_2(case, work):
    args, needle = _bad_inputs(work)[case]
    line = one_error_line(run(*args))
    assert needle in line, line
    if case == "wrong size":
        assert f"{SIZE}x{SIZE}" in line and "--size 40x32" in line, line


# ---------------------------------------------------------------------------------------------
def test_transposed_size_is_accepted(work, tmp_path):
    scene = scene_copy("rules", tmp_path / "wide.toml", 48, 32)
    img = student_png(scene, tmp_path / "t.png", transpose=True)
    assert img.shape == (48, 32, 3)
    p = run("grade", scene, tmp_path / "t.png")
    assert p.returncode == 1, p.stderr
    notes = [ln for ln in p.stderr.splitlines() if ln.strip().startswith("note:")]
    assert len(notes) == 1 and "transposed" in notes[0] and "32x48" in notes[0], p.stderr
    assert "transpose=true" in p.stderr


def test_json_on_stdout_is_strict(work):
    p = run_child("grade", work.rules_toml, work.differs, "--json", "-")
    assert p.returncode == 1, p.stderr
    g = strict_json(p.stdout)
    assert {"verdict", "scene", "image", "pixels", "as_given", "diagnosis", "indistinguishable", "reproduce"} <= set(g)
    assert g["verdict"] == "differs" and g["scene"] == "rules" and g["image"] == str(work.differs)
    assert g["pixels"] == SIZE * SIZE
    assert g["as_given"]["mismatch_pixels"] > 0
    d = g["diagnosis"]
    assert d["rules"] == MISTAKES and d["mismatch_pixels"] == 0
    assert {e["rule"] for e in d["explained"]} == set(MISTAKES)
    for e in d["explained"]:
        assert {"rule", "value", "pixels"} <= set(e) and e["pixels"] > 0 and e["value"] == MISTAKES[e["rule"]]
    assert isinstance(g["indistinguishable"], list)
    assert g["reproduce"].startswith("minirt render ")
    # nothing but the JSON on stdout; the summary is not printed with --json -
    assert p.stderr == ""


def test_json_file_is_strict(work, tmp_path):
    out = tmp_path / "g.json"
    p = run("grade", work.rules_toml, work.match, "--json", out)
    assert p.returncode == 0, p.stderr
    assert strict_json(out.read_text())["verdict"] == "match"


def _reproduce(reproduce: str, out: Path) -> subprocess.CompletedProcess:
    argv = shlex.split(reproduce)
    assert argv[:2] == ["minirt", "render"], argv
    return run(*argv[1:], "--out", out)


def test_reproduce_command_reproduces_the_image(work, tmp_path):
    g = strict_json(run("grade", work.rules_toml, work.differs, "--json", "-").stdout)
    p = _reproduce(g["reproduce"], tmp_path / "r")
    assert p.returncode == 0, p.stderr
    # a variant render: named by the rules that differ (minirt.io.names), the plain name left alone
    rules = "+".join(f"{k}={v}" for k, v in sorted(g["diagnosis"]["rules"].items()))
    assert not (tmp_path / "r" / "rules.reference.png").exists()
    rep = read_image_u8(tmp_path / "r" / f"rules.reference+{rules}.png")[..., :3]
    assert rep.shape == work.differs_img.shape
    assert levels_off(rep, work.differs_img) <= 0.002 * SIZE * SIZE


def test_bundled_scene_by_name(work, tmp_path):
    """`minirt grade rules IMG`: the bundled scene (256x256) graded at the image's size with --size."""
    img = student_png(work.rules_toml, tmp_path / "s.png", rows="bottom-up")
    p = run("grade", "rules", tmp_path / "s.png", "--size", f"{SIZE}x{SIZE}", "--json", "-")
    assert p.returncode == 1, p.stderr
    g = strict_json(p.stdout)
    assert g["scene"] == "rules" and g["diagnosis"]["rules"] == {"rows": "bottom-up"}
    assert f"--width {SIZE} --height {SIZE}" in g["reproduce"]
    r = _reproduce(g["reproduce"], tmp_path / "r")
    assert r.returncode == 0, r.stderr
    # a variant render: named by the rules that differ (minirt.io.names), the plain name left alone
    rules = "+".join(f"{k}={v}" for k, v in sorted(g["diagnosis"]["rules"].items()))
    assert not (tmp_path / "r" / "rules.reference.png").exists()
    rep = read_image_u8(tmp_path / "r" / f"rules.reference+{rules}.png")[..., :3]
    assert levels_off(rep, img) <= 0.002 * SIZE * SIZE
    # without --size the bundled scene's own size: a one-line error naming both and suggesting --size
    line = one_error_line(run("grade", "rules", tmp_path / "s.png"))
    assert "256x256" in line and f"--size {SIZE}x{SIZE}" in line


# ---------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def klass(work) -> SimpleNamespace:
    c = work.tmp / "class"
    for who in ("alice", "bob", "carol"):
        (c / who).mkdir(parents=True)
    student_png(work.rules_toml, c / "alice" / "rules.png")
    student_png(work.exercise_toml, c / "alice" / "exercise.png")
    student_png(work.rules_toml, c / "bob" / "rules.png", channels="bgr")
    student_png(work.exercise_toml, c / "bob" / "exercise.png", channels="bgr")
    (c / "carol" / "exercise.png").write_bytes(b"\x89PNG\r\n\x1a\nnot really")  # and no rules.png
    out = work.tmp / "class-out"
    args = ["grade", "--class", c, "--scenes", work.scenes, "--out", out]
    first = run(*args)  # six images: graded in this process (minirt.jobs.batch.default_workers)
    files = {n: (out / n).read_bytes() for n in ("grades.csv", "grades.json")}
    tree = _tree(out)
    second = run(*args)
    out2 = work.tmp / "class-out-2"
    two = run_child(*args[:-1], out2, "--workers", "2")
    return SimpleNamespace(dir=c, out=out, first=first, second=second, files=files, tree=tree, two=two, out2=out2)


def _tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_class_mode(klass):
    p = klass.first
    assert p.returncode == 0, p.stderr
    assert "Traceback" not in p.stderr + p.stdout
    assert "graded 3 students x 2 scenes: 2 match, 2 differ, 2 error" in p.stdout
    rows = list(csv.DictReader(io.StringIO(klass.files["grades.csv"].decode())))
    assert {"student", "scene", "verdict", "rules", "mismatch_pixels"} <= set(rows[0])
    got = {(r["student"], r["scene"]): r for r in rows}
    assert len(rows) == 6 and set(got) == {(s, e) for s in ("alice", "bob", "carol") for e in ("exercise", "rules")}
    assert got["alice", "rules"]["verdict"] == "match" and got["alice", "exercise"]["verdict"] == "match"
    for scene in ("rules", "exercise"):
        assert got["bob", scene]["verdict"] == "differs" and got["bob", scene]["rules"] == "channels=bgr"
        assert got["bob", scene]["mismatch_pixels"] == "0"
        assert got["carol", scene]["verdict"] == "error" and got["carol", scene]["reason"]
        assert got["carol", scene]["mismatch_pixels"] == ""
    assert "no image rules.png" in got["carol", "rules"]["reason"]
    assert "exercise.png" in got["carol", "exercise"]["reason"]
    data = strict_json(klass.files["grades.json"].decode())
    assert data["verdicts"] == {"match": 2, "differs": 2, "error": 2}
    assert data["students"] == ["alice", "bob", "carol"] and sorted(data["scenes"]) == ["exercise", "rules"]
    assert {(g["student"], g["scene"], g["verdict"]) for g in data["grades"]} == {
        (r["student"], r["scene"], r["verdict"]) for r in rows
    }
    assert data["common_mistakes"][0] == {
        "rule": "channels",
        "value": "bgr",
        "students": 1,
        "images": 2,
        "differing_images": 2,
    }


def test_class_mode_is_deterministic(klass):
    assert klass.second.returncode == 0, klass.second.stderr
    for name, first in klass.files.items():
        assert (klass.out / name).read_bytes() == first, name


def test_class_on_two_worker_processes_writes_the_same_files(klass):
    """--workers 2 (two Dask worker processes, each with its own render cache, pages written where they
    are graded) writes exactly the files of a class graded in one process: every page, picture and table."""
    assert klass.two.returncode == 0, klass.two.stderr
    assert "Traceback" not in klass.two.stderr + klass.two.stdout
    two = _tree(klass.out2)
    assert sorted(two) == sorted(klass.tree)
    assert [n for n in two if two[n] != klass.tree[n]] == []
    assert any(n.startswith("pages/assets/") for n in two) and "index.html" in two


def test_class_cache_grades_only_new_or_changed_images(klass, work, tmp_path):
    """--cache DIR: a rerun takes every unchanged image's grade from DIR and writes its page back from
    the cached bytes (the same files as grading it), and grades again an image whose bytes changed, and a
    page whose pictures are gone."""
    c = tmp_path / "class"
    shutil.copytree(klass.dir, c)
    out, cache = tmp_path / "out", tmp_path / "cache"
    args = ["grade", "--class", c, "--scenes", work.scenes, "--out", out, "--cache", cache]
    first = run(*args)
    assert first.returncode == 0, first.stderr
    assert "(0 of 6 from the cache)" in first.stdout
    tree = _tree(out)

    def pages(files, folder):  # a page names its image's path: the class folder's name set aside
        return {n: b.replace(str(folder).encode(), b"CLASS") for n, b in files.items() if n.startswith("pages/")}

    assert pages(tree, c) == pages(klass.tree, klass.dir)  # the cache changes nothing in what is written
    for page in (out / "pages").glob("*.html"):
        page.unlink()
    again = run(*args)
    assert "(4 of 6 from the cache)" in again.stdout, again.stdout  # carol's two errors are never kept
    assert _tree(out) == tree
    shutil.copy(c / "alice" / "rules.png", c / "bob" / "rules.png")  # bob fixes his channels in one scene
    fixed = run(*args)
    assert "(3 of 6 from the cache)" in fixed.stdout, fixed.stdout
    assert "3 match, 1 differ, 2 error" in fixed.stdout
    html = {n: b for n, b in _tree(out).items() if n.endswith(".html")}
    shutil.rmtree(out / "pages" / "assets")
    assert "(0 of 6 from the cache)" in run(*args).stdout  # pictures gone: graded again, never a broken page
    assert {n: b for n, b in _tree(out).items() if n.endswith(".html")} == html
    assert (out / "pages" / "assets").is_dir()


def test_cache_goes_with_class(work, tmp_path):
    line = one_error_line(run("grade", work.rules_toml, work.match, "--cache", tmp_path / "c"))
    assert "--cache goes with --class" in line
