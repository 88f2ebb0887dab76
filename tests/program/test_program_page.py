"""``minirt grade --program SPEC --out FILE``: one HTML file with every scene's pictures inside it (the
program's image, the model under the diagnosed rules, the differences), the program's one diagnosis, the
reason of a scene the program failed, the compiler's message; the same bytes on every run, and no page at
all (or the old one, untouched) when the run is refused."""

from __future__ import annotations

import base64
import re
import sys
from pathlib import Path

import numpy as np
from support.browser import assert_all_images_loaded, console, loaded_page
from support.inproc import minirt as here
from support.programs import grading_suite, minirt, program_cache  # noqa: F401 (program_cache: a fixture)

from minirt.grading import program as gp
from minirt.grading.page import as8
from minirt.grading.program_page import write_program_page
from minirt.io.images import read_image_u8
from minirt.oracles.program import make_spec

ROOT = Path(__file__).resolve().parents[2]
TRACER = ROOT / "tests" / "support" / "numpy_tracer.py"
# pixel_sample=center shows on hundreds of pixels of each scene at 48^2; the NumPy tracer draws both as the model
SIZE = 48
DATA_PNG = re.compile(r'<img src="data:image/png;base64,([A-Za-z0-9+/=]+)"')
# A program that fails on one scene (three_balls) with a message holding markup, and runs the NumPy
# tracer (given as its first argument, so the sandbox shows it) on the others.
FAILS_ON_THREE_BALLS = """\
import runpy, sys, tomllib
doc = tomllib.load(open(sys.argv[2], "rb"))
if doc["scene"]["name"] == "three_balls":
    sys.exit("boom: <b>three</b> balls are too many")
tracer = sys.argv.pop(1)
runpy.run_path(tracer, run_name="__main__")
"""


def suite(stems=("rules", "three_balls")):
    return grading_suite(stems, SIZE)


def pictures(html: str, tmp_path: Path) -> list[np.ndarray]:
    """Every picture inside the page, decoded, in the page's order."""
    out = []
    for k, b64 in enumerate(DATA_PNG.findall(html)):
        f = tmp_path / f"picture{k}.png"
        f.write_bytes(base64.b64decode(b64))
        out.append(read_image_u8(f))
    return out


def test_the_page_shows_every_scene_and_the_one_diagnosis(tmp_path):
    spec = make_spec(f"{sys.executable} {TRACER} --rule pixel_sample=center {{scene}} {{out}}")
    g = gp.grade_program(spec, suite())
    assert g.diagnosis.rules == {"pixel_sample": "center"}
    html = write_program_page(g, tmp_path / "page.html").read_text()
    assert "pixel_sample=center" in html and g.as_dict()["diagnosis"]["explained"][0]["sentence"][:40] in html
    assert html.count('class="panel scene"') == 2 and "rules" in html and "three_balls" in html
    # per scene: the program's image, the model under pixel_sample=center, the difference, the difference
    # before the diagnosis; then the colour bar
    got = pictures(html, tmp_path)
    assert len(got) == 2 * 4 + 1
    for k, s in enumerate(g.scenes):
        image, model, diff, before = got[4 * k : 4 * k + 4]
        assert np.array_equal(image[..., :3], as8(s.target.pixels, s.target.is_float))
        # the model under the diagnosed rules is the program's image here (it explains every pixel) ...
        assert np.array_equal(model[..., :3], image[..., :3])
        # ... so the difference is flat, and the one before the diagnosis is not
        assert len(np.unique(diff.reshape(-1, diff.shape[-1]), axis=0)) == 1
        assert len(np.unique(before.reshape(-1, before.shape[-1]), axis=0)) > 1
    assert "http://" not in html.replace("http://www.w3.org", "") and "https://" not in html
    # in a browser: every picture loads under the page's Content Security Policy, nothing is refused
    dom, attrs = loaded_page(tmp_path, (tmp_path / "page.html").resolve().as_uri(), "data-verdict")
    assert attrs.get("data-ready") == "1" and attrs["data-csp-violations"] == "0" and attrs["data-errors"] == "0"
    assert_all_images_loaded(attrs, html)
    assert not console(dom), console(dom)


def test_a_scene_the_program_fails_shows_its_reason_and_the_others_their_pictures(tmp_path):
    prog = tmp_path / "fails.py"
    prog.write_text(FAILS_ON_THREE_BALLS)
    g = gp.grade_program(make_spec(f"{sys.executable} {prog} {TRACER} {{scene}} {{out}}"), suite())
    assert [s.verdict for s in g.scenes] == ["match", "error"]
    html = write_program_page(g, tmp_path / "page.html").read_text()
    assert "The program drew no image: the program failed with exit status 1: boom: &lt;b&gt;three&lt;/b&gt;" in html
    assert "<b>three</b>" not in html  # the program's words are text, never markup
    assert html.endswith("</html>\n")  # written whole
    assert len(DATA_PNG.findall(html)) == 3 + 1  # rules: the image, the model, the difference (no "before"); the bar


def test_a_compile_error_is_on_the_page_with_the_compilers_message(tmp_path):
    src = tmp_path / "raytracer.cpp"
    src.write_text("int main() { return undeclared_name_in_student_code; }\n")
    g = gp.grade_program(make_spec(str(src)), suite(("rules",)))
    assert g.compile is not None and not g.compile["ok"]
    html = write_program_page(g, tmp_path / "page.html").read_text()
    assert "does not compile" in html and "undeclared_name_in_student_code" in html
    assert '<pre class="compiler">' in html
    assert "The program drew no image: nothing to diagnose." in html and "nothing to explain" not in html
    assert "Cannot tell apart" not in html and len(DATA_PNG.findall(html)) == 0  # no picture, no colour bar


def test_the_cli_writes_the_page_and_the_json_the_same_bytes_every_run(tmp_path):
    spec = f"{sys.executable} {TRACER} --rule pixel_sample=center {{scene}} {{out}}"
    args = ["grade", "--program", spec, "rules", "--size", "24x24", "-q"]
    p = minirt(*args, "--out", "out/a.html", "--json", "a.json", cwd=tmp_path)
    assert p.returncode == 1, p.stderr
    q = minirt(*args, "--out", "out/b.html", cwd=tmp_path)
    assert q.returncode == 1, q.stderr
    a, b = (tmp_path / "out" / "a.html").read_bytes(), (tmp_path / "out" / "b.html").read_bytes()
    assert a == b and b"pixel_sample=center" in a
    assert '"pixel_sample": "center"' in (tmp_path / "a.json").read_text()
    assert sorted(f.name for f in (tmp_path / "out").iterdir()) == ["a.html", "b.html"]  # no leftovers


def test_a_refused_run_leaves_no_page_and_an_old_one_untouched(tmp_path):
    old = tmp_path / "old.html"
    old.write_text("the page of an earlier run")
    spec = f"{sys.executable} {TRACER} {{scene}} {{out}}"
    for args, words in (
        (["grade", "--program", "missing.cpp", "--out", "new.html"], "missing.cpp: no such file"),
        (["grade", "--program", spec, "rules", "--size", "0x9", "--out", "old.html"], "--size"),
        (["grade", "--program", spec, "no_such_scene", "--out", "old.html"], "no_such_scene"),
        (["grade", "--program", spec, "rules", "--out", "."], "is a folder"),
    ):
        p = here(*args, cwd=tmp_path)  # in this process: an exit status and a line, no process needed
        assert p.returncode == 2 and words in p.stderr, (args, p.stderr)
        assert "Traceback" not in p.stderr and len(p.stderr.strip().splitlines()) == 1, p.stderr
    assert not (tmp_path / "new.html").exists() and old.read_text() == "the page of an earlier run"
    assert [f.name for f in tmp_path.iterdir() if f.name.startswith(".")] == []  # no temporary file left


def test_every_part_of_the_diagnosis_is_on_the_page(tmp_path):
    from minirt.diagnose import JointDiagnosis
    from minirt.diagnose.evidence import Rejected

    ((_, scene, rules),) = suite(("rules",))
    d = JointDiagnosis(
        rules={"specular_exponent": "16"},
        undetermined={"offset": ["0.0001", "0.001"]},
        explained=[
            {"rule": "specular_exponent", "value": "16", "pixels": 321, "against": 4, "neither": 5,
             "per_scene": {"rules": 321}, "decided": True},
            {"rule": "offset", "value": "0.0001", "pixels": 17, "against": 0, "neither": 0,
             "per_scene": {"rules": 17}, "decided": False},
        ],
        rejected=[Rejected("two_sided", "true", 3, 9, 1)],
        unexplained=[{"scene": "rules", "pixels": 12, "sentence": "on the ball, lit, near its silhouette"}],
        indistinguishable=[{"rule": "specular_s", "value": "-s", "as": "s", "why": "an even exponent, unclamped"}],
        mismatch_pixels=12,
        broken_pixels=7,
        changes={"specular_exponent": 16, "offset": 1e-4},
    )  # fmt: skip
    scene_grade = gp.SceneGrade(scene, "rules.toml", "", "error", reason="the program timed out after 20 s",
                                rules=rules)  # fmt: skip
    g = gp.ProgramGrade(make_spec("python3 t.py {scene} {out}"), [scene_grade], d)
    html = write_program_page(g, tmp_path / "page.html").read_text()
    for said in (
        "specular_exponent=16</td><td>321</td><td>4</td><td>5</td>",
        'offset=0.0001 <span class="muted small">(one of several)</span>',
        "<b>One of:</b> the suite&#39;s images cannot decide offset: 0.0001 or 0.001",
        "two_sided=true</td><td>3</td><td>9</td><td>1</td>",
        "7 pixel(s) that the exercise's model draws right are wrong under these rules",
        "12 pixel(s) over the suite remain unexplained",
        "on the ball, lit, near its silhouette",
        '<td class="mono">specular_s</td><td class="mono">-s</td><td class="mono">s</td><td>an even exponent',
        "The program drew no image: the program timed out after 20 s",
    ):
        assert said in html, said


def test_a_2014_source_is_compared_with_its_editions_model_and_the_page_says_so(tmp_path):
    text = (ROOT / "scenes" / "samples" / "raytracer2014.cpp").read_text()
    mended = text.replace("#define PIXEL 0.0", "#define PIXEL 0.5").replace(
        "#define FROM_PLANE 1", "#define FROM_PLANE 0"
    )
    src = tmp_path / "raytracer.cpp"
    src.write_text(mended)  # only its offset (1e-4) is not the edition's
    spec = make_spec(str(src))
    scenes = [(f, sc, gp.given_rules(r, spec, False)) for f, sc, r in suite(("three_balls",))]
    g = gp.grade_program(spec, scenes)
    html = write_program_page(g, tmp_path / "page.html").read_text()
    assert g.verdict == "match" and "the 2014 edition's model" in html and "the exercise's model" not in html
    # and a command line, graded against the scene's own rules, is said to be compared with the exercise's
    g = gp.grade_program(make_spec(f"{sys.executable} {TRACER} {{scene}} {{out}}"), suite(("three_balls",)))
    html = write_program_page(g, tmp_path / "page2.html").read_text()
    assert "the exercise's model" in html and "2014 edition's model" not in html
