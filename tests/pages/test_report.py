"""The comparison report: built from a small real check (exercise at 32x32 against Embree) and a synthetic
scene that fails, errors and carries HTML and a script in every text field; then opened in a real headless
browser (Debian's chromium), which must show a non-blank page, load every image, log nothing to the console
and run no script but the page's own."""

from __future__ import annotations

import copy
import json
import re
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from support.browser import assert_all_images_loaded, console, distinct_colours, loaded_page, screenshot

from minirt.harness.geometry import check_geometry
from minirt.harness.results import BackendCheck, CheckResult, SceneCheck, worst
from minirt.harness.run import check_scene
from minirt.harness.shading import check_shading
from minirt.io.images import read_image_u8, write_image
from minirt.model.result import RenderResult
from minirt.model.rules import resolve
from minirt.model.scene import load_scene
from minirt.pages import figures, report
from minirt.pages.assets import Assets

ROOT = Path(__file__).resolve().parents[2]
SIZE = 32
PAYLOAD = "<script>alert(1)</script><img src=x onerror=alert(2)>"
ESCAPED = "&lt;script&gt;alert(1)&lt;/script&gt;&lt;img src=x onerror=alert(2)&gt;"
DATE = "2000-01-01 00:00 UTC"


def synthetic_scene(real: SceneCheck) -> SceneCheck:
    """A scene whose 'synthetic' oracle fails (a hole in the floor outside the band, a colour shift) and whose
    'mitsuba' errors; every text field holds markup."""
    scene = load_scene(ROOT / "scenes" / "exercise.toml").with_overrides(width=SIZE, height=SIZE)
    rules = resolve(scene)
    ref = real.reference
    cand = copy.deepcopy(ref)
    cand.backend = "synthetic"  # the harness reads its precision from meta; "exercise" shading model
    cand.meta = {**cand.meta, "version": "POV-Ray <b>9</b>", "precision": {"band_eps": 1e-9, "t_rel": 1e-12,
                 "t_abs": 1e-12, "normal_deg": 1e-9}}  # fmt: skip
    hole = np.zeros_like(ref.hit)
    hole[26:30, 4:12] = True
    hole &= ref.hit
    cand.hit = ref.hit & ~hole
    cand.shape_id = np.where(cand.hit, ref.shape_id, -1)
    cand.t = np.where(cand.hit, ref.t * (1 + 1e-6), np.inf)
    cand.position = np.where(cand.hit[..., None], ref.position, 0.0)
    cand.normal = np.where(cand.hit[..., None], ref.normal, 0.0)
    cand.color = ref.color.copy()
    cand.color[10:18, 10:18] += 0.2
    geom = check_geometry(scene, rules, ref, cand)
    shading = check_shading(scene, ref, cand, geom)
    assert geom.verdict == "fail" and shading.verdict == "fail"
    geom.reason += " " + PAYLOAD
    rule_mask = np.zeros_like(ref.hit)
    rule_mask[:8] = True
    failing = BackendCheck(
        backend="synthetic", verdict="fail", reason=f"geometry: {geom.reason}",
        checks={"geometry": geom, "shading": shading}, rules={"clamp": int(rule_mask.sum()), "two_sided": 0},
        rule_masks={"clamp": rule_mask, "two_sided": np.zeros_like(rule_mask)},
        rules_followed={"clamp": True, "note": PAYLOAD}, seconds=0.5, result=cand, reference=ref,
    )  # fmt: skip
    broken = BackendCheck(
        backend="mitsuba", verdict="error", reason="render crashed: " + PAYLOAD,
        result=RenderResult.failed("mitsuba", SIZE, SIZE, "error", PAYLOAD, version="3.9.1"),
    )  # fmt: skip
    return SceneCheck(
        scene="evil" + PAYLOAD, file="scenes/" + PAYLOAD + ".toml", verdict="error", description=PAYLOAD,
        reason=PAYLOAD, backends={"synthetic": failing, "mitsuba": broken}, reference=ref,
    )  # fmt: skip


SWEEP = {
    "scene": "exercise" + PAYLOAD,
    "size": [16, 16],
    "repeats": 2,
    "rows": [
        {"backend": "reference", "knob": "spp", "value": 4, "cost": 4, "status": "ok", "seconds_median": 0.01,
         "metric": "rmse", "error": {"rmse": 0.02}, "pareto": True, "reason": ""},
        {"backend": "povray", "knob": None, "value": None, "status": "skip", "reason": PAYLOAD},
        {"backend": "embree"},  # keys missing: still a row
        "not a row",
    ],
    "slopes": {"reference/spp": {"metric": "rmse", "slope_cost": -0.5, "theory": PAYLOAD}, "bad": None},
    "pareto": {"reference/spp": [4]},
    "answer_lines": ["exercise 16x16: error < 1/255 costs 0.01 s with the reference at 4 spp " + PAYLOAD],
}  # fmt: skip


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    real = check_scene(ROOT / "scenes" / "exercise.toml", ["reference", "embree"], (SIZE, SIZE))
    scenes = [real, synthetic_scene(real)]
    result = CheckResult(verdict=worst([s.verdict for s in scenes]), scenes=scenes)
    sweep_dir = tmp_path_factory.mktemp("sweep")
    write_image(sweep_dir / "sweep.png", np.full((20, 30, 3), 200, np.uint8))
    write_image(sweep_dir / "sweep-embree.png", np.full((20, 30, 3), 100, np.uint8))
    write_image(sweep_dir / "sweep-<x>.png", np.zeros((4, 4, 3), np.uint8))  # not a name the sweep writes
    calls = []
    out = tmp_path_factory.mktemp("report") / "report"
    (out / "assets").mkdir(parents=True)
    write_image(out / "assets" / "stale.png", np.zeros((2, 2, 3), np.uint8))
    index = report.write_report(
        result, out, command="minirt report scenes/exercise.toml --size 32x32", sweep=SWEEP, sweep_dir=sweep_dir,
        progress=lambda *a: calls.append(a), date=DATE,
    )  # fmt: skip
    return SimpleNamespace(result=result, out=out, index=index, html=index.read_text(), calls=calls,
                           sweep_dir=sweep_dir)  # fmt: skip


def test_files_and_json(built):
    assert built.index == built.out / "index.html"
    data = json.loads((built.out / "report.json").read_text())
    assert data["verdict"] == "error"
    assert [s["description"] for s in data["scenes"]] == [built.result.scenes[0].description, PAYLOAD]
    assert data["report"]["command"] == "minirt report scenes/exercise.toml --size 32x32"
    assert data["report"]["date"] == DATE
    assert data["report"]["machine"]["cpu_count"] >= 1
    assert data["sweep"]["scene"] == SWEEP["scene"]
    names = sorted(p.name for p in (built.out / "assets").iterdir())
    assert "stale.png" not in names  # a previous report's leftovers are pruned
    assert "sweep.png" in names and "sweep-embree.png" in names and "sweep-<x>.png" not in names
    for n in names:
        assert re.fullmatch(r"(s\d\d-[a-z0-9_-]+|sweep(-[a-z0-9_]+)?)\.png", n), n
    srcs = re.findall(r'<img[^>]* src="([^"]+)"', built.html)
    assert len(srcs) > 15
    for s in srcs:
        assert s.startswith("assets/") and (built.out / s).is_file(), s


def test_content(built):
    html = built.html
    # Failures and errors first: the synthetic scene (error) before exercise (pass).
    assert html.index('id="scene-1"') < html.index('id="scene-0"')
    for text in ("minirt report scenes/exercise.toml --size 32x32", DATE, "trimesh", "embreex", "ERROR", "FAIL",
                 "mask_mismatch_outside_band", "color8_levels", "hit-mask mismatches", "Accuracy sweep",
                 "t: relative error", "colour: 8-bit difference", "clamp", "make goldens"):  # fmt: skip
        assert text in html, text
    assert 'class="hot"' in html  # a defect count is highlighted
    assert "POV-Ray &lt;b&gt;9&lt;/b&gt;" in html


def test_scene_text_is_escaped(built):
    html = built.html
    assert PAYLOAD not in html
    assert "<img src=x" not in html
    assert html.count(ESCAPED) >= 5  # name, file, description, reason, backend reason, sweep...
    assert len(re.findall(r"<script\b", html, re.I)) == 1  # the page's own, and it is allowed by hash
    assert re.search(r"script-src 'sha256-[A-Za-z0-9+/=]+';", html)  # no 'unsafe-inline' for scripts
    assert not re.search(r"(https?:)?//[a-z0-9.-]+\.[a-z]{2,}/", html.replace("file://", ""))  # no remote URL


def test_progress(built):
    done = [c[0] for c in built.calls]
    total = built.calls[-1][1]
    assert done == sorted(done) and built.calls[-1][:2] == (total, total)
    assert all(isinstance(c[2], str) for c in built.calls)


def test_assets_are_reproducible(built, tmp_path):
    index = report.write_report(built.result, tmp_path / "again", command="x", sweep=SWEEP,
                                sweep_dir=built.sweep_dir, date="another date")  # fmt: skip
    a = {p.name: p.read_bytes() for p in (built.out / "assets").iterdir()}
    b = {p.name: p.read_bytes() for p in (index.parent / "assets").iterdir()}
    assert a == b  # the date and the command are in the page only


def test_sweep_answer_opens_the_sweep_section(built):
    html = built.html
    section = html[html.index('<section class="sweep"') :]
    assert section.index('<ul class="answer">') < section.index("<table")  # the answer before any table
    assert "error &lt; 1/255 costs 0.01 s with the reference at 4 spp " + ESCAPED in section


def test_maps_mark_the_pixels_the_check_does_not_judge(built):
    """The real exercise-vs-Embree geometry check leaves the silhouette band unjudged: its t map says so
    (pixels hatched, their count and the max over judged pixels in the caption), and the hatched pixels
    are drawn grey, the judged ones in the colour map."""
    real = built.result.scenes[0].backends["embree"]
    geom = real.checks["geometry"]
    ex = geom.images["not_judged"]
    assert ex.any() and not (ex & ~geom.images["band"]).any()
    rel = geom.images["depth_rel_err"]
    html = built.html[built.html.index('id="scene-0-embree"') :]  # the real scene's Embree section
    caption = re.search(r"geometry</span> · max over judged pixels <span class=\"mono\">([^<]+)</span>\s*<br>"
                        r"<span class=\"sw hatch\"></span><span class=\"muted small\">hatched: (\d+) pixels? the "
                        r"check does not judge \(the silhouette band\); max over all pixels <span class=\"mono\">"
                        r"([^<]+)</span>", html)  # fmt: skip
    assert caption, "no caption with the excluded pixels"
    assert int(caption.group(2)) == int(ex.sum())
    assert float(caption.group(1)) == pytest.approx(float(rel[~ex].max()), rel=1e-3)
    assert float(caption.group(3)) == pytest.approx(float(rel.max()), rel=1e-3)
    # the map itself: grey where not judged
    img = read_image_u8(built.out / "assets" / "s00-embree-depth_rel_err.png")[..., :3].astype(int)
    grey = (np.abs(img - np.array([0x9A, 0x9A, 0x9A])).max(-1) <= 2).sum()
    assert grey > ex.sum()  # each unjudged pixel is several grey display pixels (between the hatch lines)


def test_heatmap_scale_is_that_of_the_judged_pixels():
    data = np.zeros((8, 8))
    data[2:6, 2:6] = 0.01
    data[0, 0] = 100.0  # an unjudged edge pixel
    ex = np.zeros((8, 8), bool)
    ex[0, 0] = True
    fig = figures.heatmap(data, "t", "relative", "viridis", None, ex)
    (im,) = fig.axes[0].get_images()
    assert im.get_clim() == (0.0, 0.01)
    assert figures.heatmap(data, "t", "relative", "viridis").axes[0].get_images()[0].get_clim() == (0.0, 100.0)


def test_sweep_view_tolerates_missing_keys(tmp_path):
    assets = Assets(tmp_path)
    assert report._sweep_view(None, None, assets) is None
    assert report._sweep_view(None, tmp_path, assets) is None  # no sweep.json there
    v = report._sweep_view({}, None, assets)
    assert v["rows"] == [] and v["slopes"] == [] and v["plots"] == []
    v = report._sweep_view({"rows": None, "slopes": [1], "pareto": "x", "size": 7}, tmp_path / "nope", assets)
    assert v["rows"] == [] and v["size"] == "7"
    (tmp_path / "sweep.json").write_text(json.dumps(SWEEP))
    assert len(report._sweep_view(None, tmp_path, assets)["rows"]) == 3


# ---------------------------------------------------------------------------------------------
# In a real browser


def test_in_a_browser(built, tmp_path):
    url = built.index.resolve().as_uri()
    # 1. The DOM after the load event: the page's own script writes its self-check on <body>.
    dom, attrs = loaded_page(tmp_path, url, "data-verdict")
    assert attrs.get("data-ready") == "1", attrs
    assert_all_images_loaded(attrs, built.html)
    assert attrs["data-errors"] == "0" and attrs["data-alerts"] == "0" and attrs["data-csp-violations"] == "0", attrs
    assert len(re.findall(r"<script\b", dom.stdout, re.I)) == 1  # nothing injected
    assert ESCAPED in dom.stdout  # shown as text
    assert not console(dom), console(dom)  # errors and CSP refusals
    # 2. A screenshot: not blank.
    px = screenshot(tmp_path, url, 1280, 2000)
    assert px.shape[:2] == (2000, 1280)
    colours = distinct_colours(px)
    white = (px > 245).all(-1).mean()
    assert colours > 500 and white < 0.5 and px.std() > 10, (colours, white, px.std())


def test_committed_sample_is_complete():
    """reports/sample (refreshed by `make sample`): every image the page names exists, names URL-safe."""
    sample = Path(__file__).resolve().parents[2] / "reports" / "sample"
    html = (sample / "index.html").read_text()
    srcs = re.findall(r'<img[^>]* src="([^"]+)"', html)
    assert len(srcs) > 50
    for s in srcs:
        assert re.fullmatch(r"assets/[A-Za-z0-9_.-]+", s) and (sample / s).is_file(), s
    used = {s.removeprefix("assets/") for s in srcs}
    assert {p.name for p in (sample / "assets").iterdir()} <= used | {"sweep.png"}  # nothing stale
    data = json.loads((sample / "report.json").read_text())
    assert data["verdict"] == "pass" and all(s["verdict"] == "pass" for s in data["scenes"])


def test_an_inconclusive_check_is_shown_as_such(tmp_path):
    """A check that could not fail (here: an infinite t tolerance) is a WARN the page labels INCONCLUSIVE, in the
    matrix, on the backend and on the check, and report.json says so."""
    real = check_scene(ROOT / "scenes" / "exercise.toml", ["reference"], (16, 16))
    scene = load_scene(ROOT / "scenes" / "exercise.toml").with_overrides(width=16, height=16)
    ref = real.reference
    cand = copy.deepcopy(ref)
    cand.backend = "synthetic"
    cand.meta = {**cand.meta, "precision": {"band_eps": 1e-9, "t_rel": 1e-12, "t_abs": np.inf, "normal_deg": 1e-9}}
    geom = check_geometry(scene, resolve(scene), ref, cand)
    assert geom.inconclusive
    b = BackendCheck(backend="synthetic", verdict="warn", reason=geom.reason, checks={"geometry": geom},
                     result=cand, reference=ref)  # fmt: skip
    sc = SceneCheck(scene="vague", file="vague.toml", verdict="warn", backends={"synthetic": b}, reference=ref)
    index = report.write_report(CheckResult(verdict="warn", scenes=[sc]), tmp_path / "r", command="x", date=DATE)
    html = index.read_text()
    assert html.count(">INCONCLUSIVE<") == 4  # matrix cell, tile, backend summary, geometry check
    assert "inconclusive: this oracle cannot judge this scene (the t tolerance" in html
    data = json.loads((tmp_path / "r" / "report.json").read_text())
    assert data["scenes"][0]["backends"]["synthetic"]["inconclusive"] is True
