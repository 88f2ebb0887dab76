"""A class folder is untrusted input: `minirt grade --class` on folders a hostile student could make.

Student folders named as spreadsheet formulas (``=1+1``, ``+SUM(1,2)``, ``@SUM(1)``, ``=HYPERLINK(...)``,
``-2+3``, a leading tab or carriage return) and with ESC/BEL in their names are graded, and their names reach
grades.csv neutralised (read back with the csv module: no cell starts with a formula character, no control
byte anywhere) and the pages escaped; a student folder or an image that is a symbolic link -- out of the
class folder, or to another student -- and an image that is a FIFO are rows with verdict "error" and the
reason, never graded, and the linked picture is on no published page; a hidden folder is listed as
skipped, with its reason, in grades.json, on the class page and on the terminal. Hypothesis then makes
folder names of any bytes (non-UTF-8 included) and checks the class folder's survey, the CSV and the
class page on them.

Images are 16x16 renders of scenes/rules.toml by tests/support/plain.py (tests/support/students.py).
"""

from __future__ import annotations

import csv
import io
import json
import os
import re
import string
import unicodedata
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import jsonschema
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from support.inproc import minirt
from support.students import student_image

from minirt.grading import classroom
from minirt.grading.grade import ClassRow
from minirt.grading.page import write_class_page
from minirt.io import documents
from minirt.io.images import read_image_u8, write_image
from minirt.io.untrusted import FORMULA_START, csv_cell
from minirt.model import rules as R
from minirt.model.scene import load_scene

ROOT = Path(__file__).resolve().parents[2]
SIZE = 16
FORMULAS = ["=1+1", "+SUM(1,2)", "@SUM(1)", '=HYPERLINK("evil.example","click")', "-2+3", "\tTAB", "\rCR"]
TERMINAL = "esc\x1b[31mred\x07bell"  # ESC (a colour escape) and BEL in a folder's name
LINKED = {
    "linked-out": "the student folder is a symbolic link to ../outside",
    "linked-peer": "the student folder is a symbolic link to alice",
    "image-out": "rules.png is a symbolic link to ../../outside/rules.png",
    "image-peer": "rules.png is a symbolic link to ../alice/rules.png",
}


def controls(text: str, allowed: str = "\n") -> list[str]:
    """The control, format and surrogate characters of ``text`` (but ``allowed``)."""
    return [c for c in text if unicodedata.category(c) in ("Cc", "Cf", "Cs") and c not in allowed]


@pytest.fixture(scope="module")
def hostile(tmp_path_factory) -> SimpleNamespace:
    tmp = tmp_path_factory.mktemp("class-hostile")
    scenes = tmp / "scenes"
    scenes.mkdir()
    text = (ROOT / "scenes" / "rules.toml").read_text()
    text = text.replace("[camera]\n", f"[camera]\nwidth = {SIZE}\nheight = {SIZE}\n", 1)
    (scenes / "rules.toml").write_text(text)
    sc = load_scene(scenes / "rules.toml").with_overrides(samples=1)
    assert (sc.camera.width, sc.camera.height) == (SIZE, SIZE)
    right = student_image(sc, R.resolve(sc))
    staff = student_image(sc, replace(R.resolve(sc), rows="bottom-up"))  # another picture: the "reference"
    assert (right != staff).any()

    c = tmp / "class"
    for name in ["alice", *FORMULAS, TERMINAL, ".hidden"]:
        (c / name).mkdir(parents=True)
        write_image(c / name / "rules.png", right)
    (tmp / "outside").mkdir()
    write_image(tmp / "outside" / "rules.png", staff)
    (c / "linked-out").symlink_to("../outside")
    (c / "linked-peer").symlink_to("alice")
    for name, target in (("image-out", "../../outside/rules.png"), ("image-peer", "../alice/rules.png")):
        (c / name).mkdir()
        (c / name / "rules.png").symlink_to(target)
    (c / "fifo").mkdir()
    os.mkfifo(c / "fifo" / "rules.png")  # would block a reader forever
    (c / "notes.txt").write_text("not a student")

    out = tmp / "out"
    p = minirt("grade", "--class", c, "--scenes", scenes, "--out", out, "--workers", "1")
    return SimpleNamespace(tmp=tmp, dir=c, out=out, p=p, right=right, staff=staff)


def _rows(hostile) -> list[dict[str, str]]:
    return list(csv.DictReader(io.StringIO((hostile.out / "grades.csv").read_text(encoding="utf-8"))))


def test_the_class_is_graded(hostile):
    p = hostile.p
    assert p.returncode == 0, p.stderr
    assert "Traceback" not in p.stdout + p.stderr
    n = 1 + len(FORMULAS) + 1 + len(LINKED) + 1  # alice, the formulas, the terminal name, the links, the FIFO
    assert f"graded {n} students x 1 scenes: {n - len(LINKED) - 1} match, 0 differ, {len(LINKED) + 1} error" in p.stdout


def test_csv_cells_are_never_formulas(hostile):
    """Read back with the csv module: every name is there, neutralised by OWASP's rule; no cell starts
    with a character a spreadsheet evaluates, and the file holds no control byte but its line ends."""
    raw = (hostile.out / "grades.csv").read_bytes()
    text = raw.decode("utf-8")
    assert controls(text) == [], controls(text)
    rows = _rows(hostile)
    cells = [cell for row in rows for cell in row.values()]
    assert [c for c in cells if c.startswith(FORMULA_START)] == []
    students = {r["student"] for r in rows}
    assert {"'=1+1", "'+SUM(1,2)", "'@SUM(1)", '\'=HYPERLINK("evil.example","click")', "'-2+3"} <= students
    assert {"\\x09TAB", "\\x0dCR", "esc\\x1b[31mred\\x07bell"} <= students  # escaped: no tab or CR leads
    by = {r["student"]: r for r in rows}
    for name in [*FORMULAS, TERMINAL]:
        assert by[csv_cell(name)]["verdict"] == "match", by[csv_cell(name)]  # graded like anyone else
    assert ".hidden" not in students


def test_links_are_error_rows_and_never_followed(hostile):
    by = {r["student"]: r for r in _rows(hostile)}
    for name, said in LINKED.items():
        assert by[name]["verdict"] == "error", by[name]
        assert by[name]["reason"].startswith(said) and "not followed" in by[name]["reason"], by[name]
        assert by[name]["mismatch_pixels"] == ""
    assert by["fifo"]["verdict"] == "error" and "not a regular file" in by["fifo"]["reason"], by["fifo"]
    assert by["alice"]["verdict"] == "match"


def test_no_linked_picture_is_published(hostile):
    """The staff's picture (outside the class folder) is on no page; alice's own is (the check can fail)."""
    pictures = [read_image_u8(p)[..., :3] for p in sorted((hostile.out / "pages" / "assets").glob("*.png"))]
    assert any(im.shape == hostile.right.shape and np.array_equal(im, hostile.right) for im in pictures)
    assert not any(im.shape == hostile.staff.shape and np.array_equal(im, hostile.staff) for im in pictures)
    pages = {p.name for p in (hostile.out / "pages").glob("*.html")}
    assert not [p for p in pages if p.startswith(("linked", "image-", "fifo"))], pages


def test_pages_hold_no_control_bytes(hostile):
    for page in [hostile.out / "index.html", *sorted((hostile.out / "pages").glob("*.html"))]:
        text = page.read_bytes().decode("utf-8")
        assert controls(text) == [], (page.name, controls(text))
    index = (hostile.out / "index.html").read_text(encoding="utf-8")
    assert "esc\\x1b[31mred\\x07bell" in index and "\\x09TAB" in index
    assert "=HYPERLINK(&#34;evil.example&#34;,&#34;click&#34;)" in index  # text on a page, escaped as HTML


def test_hidden_folder_is_listed_as_skipped(hostile):
    data = json.loads((hostile.out / "grades.json").read_text())
    jsonschema.Draft202012Validator(documents.shipped("grades")).validate(data)
    assert data["skipped"] == [
        {"folder": ".hidden", "reason": classroom.HIDDEN},
        {"folder": "notes.txt", "reason": "not a folder (a student's images are in DIR/<student>/)"},
    ]
    assert ".hidden" not in data["students"] and TERMINAL in data["students"]  # JSON keeps names exactly
    index = (hostile.out / "index.html").read_text(encoding="utf-8")
    assert re.search(r'Not graded \(2 in the class folder\):\s*<span class="mono">\.hidden</span>: hidden', index)
    assert f"skipped .hidden: {classroom.HIDDEN}" in hostile.p.stderr


def test_grading_leaves_the_class_folder_alone(hostile):
    """Nothing is written into the class folder or beside it: the links and the FIFO are as they were."""
    assert os.readlink(hostile.dir / "linked-out") == "../outside"
    assert sorted(p.name for p in (hostile.tmp / "outside").iterdir()) == ["rules.png"]
    assert (hostile.dir / "fifo" / "rules.png").is_fifo()


# ---------------------------------------------------------------------------------------------
# Any folder name (hypothesis): bytes a file system allows, non-UTF-8 included

NAME = st.binary(min_size=1, max_size=24).filter(lambda b: b"/" not in b and b"\0" not in b and b not in (b".", b".."))
LEADS = st.sampled_from(["=", "+", "-", "@", "\t", "\r", "\x1b", "\x07", "\u202e", ".", ""])
TEXT = st.builds(
    lambda lead, rest: lead + rest, LEADS, st.text(string.printable + "\x1b\x07\x00\u202e\x85é", max_size=24)
)


@settings(max_examples=60, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(names=st.lists(NAME, min_size=1, max_size=6, unique=True))
def test_any_folder_names(names, tmp_path_factory):
    """Every folder is a student or skipped (hidden); the CSV read back has one row per student with the
    name as csv_cell makes it, no formula and no control byte; the class page is UTF-8 with none either."""
    c = tmp_path_factory.mktemp("names")
    for b in names:
        os.mkdir(os.path.join(os.fsencode(c), b))
    found, skipped = classroom.survey(c)
    decoded = sorted(os.fsdecode(b) for b in names)
    assert sorted(p.name for p in found) + sorted(k.folder for k in skipped) == sorted(
        [n for n in decoded if not n.startswith(".")]
    ) + sorted(n for n in decoded if n.startswith("."))
    assert all(k.reason == classroom.HIDDEN for k in skipped)
    rows = [ClassRow(p.name, "rules", "error", {}, None, None, reason=f"no image in {p.name}") for p in found]
    if not rows:
        return
    classroom.write_csv(c / "grades.csv", rows)
    text = (c / "grades.csv").read_bytes().decode("utf-8")
    assert controls(text) == []
    back = list(csv.DictReader(io.StringIO(text)))
    assert [r["student"] for r in back] == [csv_cell(r.student) for r in rows]
    assert not [v for r in back for v in r.values() if v.startswith(FORMULA_START)]
    summary = classroom.class_dict(rows, ["rules"], skipped)
    html = write_class_page(rows, summary, c / "out").read_bytes().decode("utf-8")
    assert controls(html) == []


@settings(max_examples=300, deadline=None, derandomize=True)
@given(text=TEXT)
def test_csv_cell(text):
    """OWASP's rule on any text: never a formula lead, never a control character; text that needs neither
    is kept as it is, and a neutralised cell is the escaped text after one quote."""
    cell = csv_cell(text)
    assert not cell.startswith(FORMULA_START) and controls(cell, "") == []
    if text.isprintable() and not text.startswith(FORMULA_START):
        assert cell == text
    if cell.startswith("'") and not text.startswith("'"):
        assert cell[1:].startswith(("=", "+", "-", "@"))
