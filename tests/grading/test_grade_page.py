"""The grade pages (minirt.grading.page): a student's image of scenes/rules.toml with two mistakes (pixel
centres and rows bottom-up) graded and written as a page; a scene and an image path carrying markup; a class
of three (one right, one wrong rule, one with a missing image and a corrupt file) through `minirt grade
--class`; then both pages opened in headless Chromium (test_report's helpers)."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from dataclasses import replace
from html import unescape
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from support.browser import assert_all_images_loaded, console, distinct_colours, loaded_page, screenshot

from minirt.grading import classroom
from minirt.grading import grade as grading
from minirt.grading.grade import ClassRow, Grade
from minirt.grading.page import safe_stem, write_class_page, write_grade_page
from minirt.io.images import read_image_u8, write_image
from minirt.model import bitmap
from minirt.model import rules as R
from minirt.model.scene import load_scene
from minirt.reference.tracer import render

ROOT = Path(__file__).resolve().parents[2]
W, H = 64, 48
MISTAKES = {"pixel_sample": "center", "rows": "bottom-up"}
PAYLOAD = "<script>x</script>"
ESCAPED = "&lt;script&gt;x&lt;/script&gt;"


def student_image(scene_file: Path, path: Path, **rules) -> None:
    sc = load_scene(scene_file).with_overrides(width=W, height=H)
    r = replace(R.resolve(sc), **rules)
    write_image(path, bitmap.bitmap(render(sc, r.traced()).color, r))


def grade(scene_file: Path, image: Path) -> Grade:
    sc = load_scene(scene_file).with_overrides(width=W, height=H)
    return grading.grade_image(sc, str(scene_file), image, R.resolve(sc), size_override=(W, H))


def srcs(html: str) -> list[str]:
    return re.findall(r'<img[^>]* src="([^"]+)"', html)


@pytest.fixture(scope="module")
def single(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("grade")
    scene_file = ROOT / "scenes" / "rules.toml"
    image = tmp / "student.png"
    student_image(scene_file, image, **MISTAKES)
    g = grade(scene_file, image)
    page = write_grade_page(g, tmp / "page")
    return SimpleNamespace(g=g, page=page, html=page.read_text(), tmp=tmp)


def test_page_and_images(single):
    assert single.page == single.tmp / "page" / "index.html"
    assert single.g.verdict == "differs" and single.g.diagnosis.changed == MISTAKES
    found = srcs(single.html)
    assert len(found) >= 6  # image, model, (best = image), 2 heat maps, colour bar, one per explaining rule
    for s in found:
        assert re.fullmatch(r"assets/[A-Za-z0-9._-]+\.png", s) and (single.page.parent / s).is_file(), s
    names = {p.name for p in (single.page.parent / "assets").iterdir()}
    assert all(n.startswith("index-") or n == "levels-colorbar.png" for n in names), names
    # the pictures at one scale: the 64x48 images shown 5x, without smoothing
    assert 'width="320" height="240" class="px"' in single.html
    # the heat maps are in the scene's layout, at its size
    assert read_image_u8(single.page.parent / "assets" / "index-diff-given.png").shape[:2] == (H, W)


def test_page_content(single):
    g, html = single.g, unescape(single.html)
    d = g.diagnosis
    assert "DIFFERS" in html and g.summary() in html and g.image in html and "rules" in html
    assert g.reproduce() in html and "<code>" in single.html
    assert "pixel_sample=center" in html and "rows=bottom-up" in html
    for e in d.explained:
        assert grading.sentence(e.rule, getattr(d.best, e.rule), getattr(d.given, e.rule)) in html
        assert f"evidence: {e.pixels} pixel(s) wrong without it" in re.sub(r"</?b>", "", html)
    assert f"{d.as_given_pixels} of {d.pixels} pixels differ" in html
    assert f"{int(d.ill.sum())} ill-conditioned pixel(s)" in html
    assert "clipped at 32" in html and "Cannot tell apart in this scene" in html
    assert "1 level per channel" in html


def test_same_grade_same_bytes(single, tmp_path):
    a = write_grade_page(single.g, tmp_path / "a", stem="alice rules/../x", assets="img")
    b = write_grade_page(single.g, tmp_path / "b", stem="alice rules/../x", assets="img")
    assert a.name == "alice_rules_.._x.html" and a.read_bytes() == b.read_bytes()
    fa = {p.name: p.read_bytes() for p in (a.parent / "img").iterdir()}
    fb = {p.name: p.read_bytes() for p in (b.parent / "img").iterdir()}
    assert fa == fb and len(fa) >= 5
    assert all(s.startswith("img/") for s in srcs(a.read_text()))


def test_markup_in_scene_and_path_is_escaped(tmp_path):
    text = (ROOT / "scenes" / "rules.toml").read_text()
    scene_file = tmp_path / "evil.toml"
    scene_file.write_text(text.replace('name = "rules"', f'name = "{PAYLOAD}"', 1))
    assert load_scene(scene_file).name == PAYLOAD
    image = tmp_path / f"st{PAYLOAD.replace('/', '_')}.png"
    student_image(scene_file, image, rows="bottom-up")
    page = write_grade_page(grade(scene_file, image), tmp_path / "out", stem=PAYLOAD)
    html = page.read_text()
    assert PAYLOAD not in html and "<script>x" not in html
    assert html.count(ESCAPED) >= 2  # title and heading
    assert "st&lt;script&gt;x&lt;_script&gt;.png" in html  # the image's path
    assert len(re.findall(r"<script\b", html, re.I)) == 1  # the page's own
    assert page.name == "script_x_script.html"
    assert re.search(r"script-src 'sha256-[A-Za-z0-9+/=]+';", html)
    assert not re.search(r"(https?:)?//[a-z0-9.-]+\.[a-z]{2,}/", html)


def test_error_grade(tmp_path):
    sc = load_scene(ROOT / "scenes" / "rules.toml")
    g = Grade(sc, "scenes/rules.toml", "x.png", "error", reason=f"x.png: cannot read image {PAYLOAD}")
    html = write_grade_page(g, tmp_path).read_text()
    assert "ERROR" in html and f"cannot read image {ESCAPED}" in html and not srcs(html)


def test_stems():
    assert safe_stem("alice-rules") == "alice-rules"
    assert safe_stem("../..") == "_.._.."
    assert safe_stem("") == "page" and safe_stem("ü") == "page"
    assert re.fullmatch(r"[A-Za-z0-9._-]+", safe_stem("a b/c\\d<e>f\u202eg"))


def test_class_page_names_do_not_collide(single, tmp_path):
    g = single.g
    d = g.diagnosis
    rows = [ClassRow(s, "rules", g.verdict, d.changed, d.mismatch_pixels, d.as_given_pixels, grade=g)
            for s in ("a b", "a_b", "A_B")]  # fmt: skip
    rows.append(ClassRow("c", "rules", "error", {}, None, None, reason=f"no image {PAYLOAD}"))
    summary = classroom.class_dict(rows, ["rules"])
    index = write_class_page(rows, summary, tmp_path)
    assert [r.page for r in rows] == ["pages/a_b-rules.html", "pages/a_b-rules-2.html", "pages/A_B-rules-3.html", ""]
    html = index.read_text()
    for r in rows[:3]:
        assert (tmp_path / r.page).is_file() and f'href="{r.page}"' in html
    assert f"no image {ESCAPED}" in html and PAYLOAD not in html
    pages = [(tmp_path / r.page).read_text() for r in rows[:3]]
    # pictures are named by their pixels and written once for the class: three pages of one grade share all
    names = sorted(p.name for p in (tmp_path / "pages" / "assets").iterdir())
    assert names.count("levels-colorbar.png") == 1, names
    assert srcs(pages[0]) == srcs(pages[1]) == srcs(pages[2])
    assert len(names) == len(set(srcs(pages[0]))), names
    assert all('href="../index.html"' in p for p in pages)
    for p in pages:
        for s in srcs(p):
            assert (tmp_path / "pages" / s).is_file(), s


# ---------------------------------------------------------------------------------------------
# A class through the command line


@pytest.fixture(scope="module")
def klass(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("class")
    scenes = tmp / "scenes"
    scenes.mkdir()
    for name in ("rules", "exercise"):
        (scenes / f"{name}.toml").write_text((ROOT / "scenes" / f"{name}.toml").read_text())
    cls = tmp / "class"
    for student in ("alice", "bob", "carol"):
        (cls / student).mkdir(parents=True)
    for name in ("rules", "exercise"):
        student_image(scenes / f"{name}.toml", cls / "alice" / f"{name}.png")
        student_image(scenes / f"{name}.toml", cls / "bob" / f"{name}.png", rows="bottom-up")
    (cls / "carol" / "exercise.png").write_bytes(b"\x89PNG\r\n\x1a\n not really a PNG")  # and no rules.png
    out = tmp / "out"
    cmd = [str(Path(sys.executable).parent / "minirt"), "grade", "--class", str(cls), "--scenes", str(scenes),
           "--size", f"{W}x{H}", "--out", str(out), "--quiet"]  # fmt: skip
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=tmp, timeout=300, check=False)
    assert r.returncode == 0, r.stderr[-3000:]
    index = out / "index.html"
    return SimpleNamespace(
        out=out, index=index, html=index.read_text(), data=json.loads((out / "grades.json").read_text())
    )


def test_class_index(klass):
    grades = {(g["student"], g["scene"]): g for g in klass.data["grades"]}
    assert {k: g["verdict"] for k, g in grades.items()} == {
        ("alice", "exercise"): "match", ("alice", "rules"): "match",
        ("bob", "exercise"): "differs", ("bob", "rules"): "differs",
        ("carol", "exercise"): "error", ("carol", "rules"): "error",
    }  # fmt: skip
    assert grades[("bob", "rules")]["page"] == "pages/bob-rules.html"
    assert grades[("carol", "rules")]["page"] == ""
    links = re.findall(r'<a [^>]*href="([^"]+)"', klass.html)
    assert len(links) == 4
    for link in links:
        assert (klass.out / link).is_file(), link
        page = (klass.out / link).read_text()
        for s in srcs(page):
            assert (klass.out / link).parent.joinpath(s).is_file(), (link, s)
    html = unescape(klass.html)
    assert "no image rules.png" in html and "carol" in html
    assert re.search(r'class="num total-error">2<', klass.html)
    assert re.search(r'class="num total-match">2<', klass.html)
    # the most common mistake, with its sentence
    assert "rows=bottom-up" in html and grading.sentence("rows", "bottom-up", "top-down") in html


# ---------------------------------------------------------------------------------------------
# In a real browser


def check_in_browser(index: Path, tmp: Path, html: str) -> None:
    url = index.resolve().as_uri()
    dom, attrs = loaded_page(tmp, url, "data-ready")
    assert_all_images_loaded(attrs, html)
    assert attrs["data-errors"] == "0" and attrs["data-csp-violations"] == "0", attrs
    assert not console(dom), console(dom)
    px = screenshot(tmp, url, 1100, 1400)
    colours = distinct_colours(px)
    assert colours > 100 and px.std() > 10 and (px > 245).all(-1).mean() < 0.5, (colours, px.std())


def test_page_in_a_browser(single, tmp_path):
    check_in_browser(single.page, tmp_path, single.html)


def test_class_index_in_a_browser(klass, tmp_path):
    check_in_browser(klass.index, tmp_path, klass.html)


def test_float_transposed_image(tmp_path):
    """An EXR stored transposed: the image is shown as stored (H x W), the rest in the scene's layout."""
    scene_file = ROOT / "scenes" / "rules.toml"
    sc = load_scene(scene_file).with_overrides(width=W, height=H)
    color = render(sc, R.resolve(sc).traced()).color
    image = tmp_path / "t.exr"
    write_image(image, np.swapaxes(np.clip(color, 0.0, 1.0), 0, 1).astype(np.float32))
    g = grade(scene_file, image)
    assert g.diagnosis.changed == {"transpose": "true"}
    page = write_grade_page(g, tmp_path / "out")
    html = unescape(page.read_text())
    assert "transposed" in html and "float image" in html and "this layout does not fit" in html
    assert 'width="240" height="320"' in html and 'width="320" height="240"' in html
    for s in srcs(html):
        assert (page.parent / s).is_file(), s
    assert read_image_u8(page.parent / "assets" / "index-rule0-transpose.png").shape[:2] == (H, W)
