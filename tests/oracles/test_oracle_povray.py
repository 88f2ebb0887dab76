"""The POV-Ray oracle against the reference tracer, on every scene at 48x48, plus its exporter and failures.

Comparisons are made under ``oracle.adapt(rules)``, so the reference follows the same model rules.

- Hit mask: may differ only inside the silhouette band, margin < K·eps with K·eps =
  ``povray.band_threshold(scene, rules)`` (float bounding boxes 2^-24 (|C| + r)/r, the textbook
  discriminant 2^-53 |f|^2/r^2, planes missed below |n·d| = 1e-10, the mesh camera's single-precision
  rays; K = 8) -- a few 1e-6 for these scenes -- or a candidate hit within its start band (POV-Ray
  ignores hits within 1e-4 of a ray's origin).
- Shape ids: equal on every pixel both call a hit, outside the band.
- t, position, normal: within the encoding precision in ``meta["precision"]`` (derived in
  povray.precision: 2.4e-7 of each per-shape range) plus 1e-9 relative for POV-Ray's own rounding.
- Colour: POV-Ray's 8-bit PNG within 1 level of the reference's 8-bit image outside the band (measured:
  all pixels equal); the half-float EXR within 2^-11 relative of the reference colour.

Set MINIRT_UPDATE_SNAPSHOTS=1 to rewrite tests/snapshots/povray/ after an intended exporter change.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from support.scenes import ball, material, plane, scene_text

from minirt.harness import backends
from minirt.io.images import read_image_u8
from minirt.model import camera
from minirt.model import rules as R
from minirt.model.scene import Scene, load_scene, parse_scene
from minirt.oracles import povray
from minirt.oracles.povray import PovrayOracle
from minirt.oracles.povray import oracle as povray_oracle
from minirt.reference import band, tracer

ROOT = Path(__file__).resolve().parents[2]
SNAPSHOTS = Path(__file__).resolve().parents[1] / "snapshots" / "povray"
SIZE = 48
ORACLE = PovrayOracle()

# (case id, scene file stem, rule overrides): every scene with its own profile, plus the rule values the
# exporter handles differently (background on-miss, pixel centres, camera-origin rays).
CASES = [(p.stem, p.stem, {}) for p in sorted((ROOT / "scenes").glob("*.toml"))] + [
    ("exercise-conventional", "exercise", {"profile": "conventional"}),
    ("three_balls-center", "three_balls", {"pixel_sample": "center"}),
    ("near-ball-camera", None, {"ray_origin": "camera"}),
    ("rules-camera", "rules", {"ray_origin": "camera"}),  # "rules" itself needs the mesh camera
    ("near-ball", None, {}),  # a ball between camera and image plane: the mesh camera
]

NEAR_BALL = scene_text(
    ball((0.1, 0.0, -0.6), 0.15),
    ball((0.0, 0.0, 4.0), 1.0),
    plane((0.0, 1.0, 0.0), -1.0),
    light=(3.0, 4.0, -3.0),
    render={"background": (0.1, 0.1, 0.2), "max_depth": 2},
    materials={"m": material((0.5, 0.6, 0.7), ambient=(0.1, 0.05, 0.0), specular=0.4, reflection=0.3)},
)


def _scene(stem: str | None) -> Scene:
    sc = load_scene(ROOT / "scenes" / f"{stem}.toml") if stem else parse_scene(NEAR_BALL, "near_ball.toml")
    return sc.with_overrides(width=SIZE, height=SIZE, samples=1)


def _rules(sc: Scene, overrides: dict) -> R.Rules:
    ov = dict(overrides)
    profile = ov.pop("profile", None)
    return ORACLE.adapt(R.resolve(sc, profile, ov))


@pytest.fixture(scope="module")
def renders():
    cache: dict[str, dict] = {}

    def get(case: str) -> dict:
        if case not in cache:
            _, stem, ov = next(c for c in CASES if c[0] == case)
            sc = _scene(stem)
            rules = _rules(sc, ov)
            res = ORACLE.render(sc, rules)
            assert res.ok, f"{case}: POV-Ray {res.status}: {res.reason}"  # say why, not a KeyError below
            ref = tracer.render(sc, rules)
            o, d = camera.primary_rays(sc, rules)
            with np.errstate(invalid="ignore"):
                m = band.margins(sc, o, d)
            p = res.meta["precision"]
            starts = band.start_band(sc, o, d, p["min_distance"], p["start_err"], p["start_err"])
            outside = (m["margin"] >= povray.band_threshold(sc, rules)) & ~starts
            cache[case] = {"scene": sc, "rules": rules, "res": res, "ref": ref, "outside": outside.reshape(SIZE, SIZE)}
        return cache[case]

    return get


CASE_IDS = [c[0] for c in CASES]


def test_available_and_version():
    ok, why = ORACLE.available()
    assert ok, why  # a fresh machine must have povray installed (make test installs it)
    assert re.fullmatch(r"POV-Ray 3\.7\.\d+\.\d+", ORACLE.version())
    assert backends.get("povray").name == "povray"


@pytest.mark.parametrize("case", CASE_IDS)
def test_render_ok_with_two_invocations(renders, case):
    r = renders(case)
    res = r["res"]
    assert res.ok, res.reason
    assert len(res.meta["commands"]) == 2  # one EXR animation (colour + buffers) and the 8-bit PNG
    assert all(c.startswith("povray -D -A") for c in res.meta["commands"])
    tm = res.meta["timings"]
    # The two passes run side by side: setup is the sum of each process's own, the total the wall time,
    # at least the longer pass's.
    passes = tm["passes"].values()
    assert tm["setup"] > 0 and tm["setup"] == pytest.approx(sum(p["setup"] for p in passes))
    assert tm["total"] >= max(p["wall"] for p in passes)
    assert res.meta["hit_consistency"] == 0  # alpha of every frame and the id channel agree


@pytest.mark.parametrize("case", CASE_IDS)
def test_hit_mask_and_ids(renders, case):
    r = renders(case)
    res, ref, outside = r["res"], r["ref"], r["outside"]
    diff = res.hit != ref.hit
    assert not (diff & outside).any(), f"{int((diff & outside).sum())} hit mismatches outside the band"
    both = res.hit & ref.hit & outside
    assert np.array_equal(res.shape_id[both], ref.shape_id[both])


@pytest.mark.parametrize("case", CASE_IDS)
def test_geometry_within_encoding_precision(renders, case):
    r = renders(case)
    res, ref, outside = r["res"], r["ref"], r["outside"]
    prec = res.meta["precision"]
    ok = res.hit & ref.hit & (res.shape_id == ref.shape_id) & outside
    assert ok.sum() > 0
    scale = np.maximum(1.0, np.abs(ref.t[ok]))
    assert np.all(np.abs(res.t[ok] - ref.t[ok]) <= prec["t_abs"] + 1e-9 * scale)
    dp = np.abs(res.position[ok] - ref.position[ok]).max(axis=-1)
    assert np.all(dp <= prec["position_abs"] + 1e-9 * scale)
    dn = np.abs(res.normal[ok] - ref.normal[ok]).max(axis=-1)
    assert np.all(dn <= prec["normal_abs"] + 1e-9)
    # self-check of the decoding: every decoded point lies on its surface
    assert max(res.meta["surface_residual"].values()) <= 2 * prec["position_abs"] + 1e-9 * scale.max()


@pytest.mark.parametrize("case", CASE_IDS)
def test_color(renders, case):
    r = renders(case)
    res, ref, outside = r["res"], r["ref"], r["outside"]
    pov8 = res.image8.astype(int)
    ref8 = ref.color8().astype(int)
    d8 = np.abs(pov8 - ref8).max(axis=-1)
    differ = int((d8[outside] > 0).sum())
    print(f"{case}: 8-bit pixels differing outside the band: {differ} of {int(outside.sum())}")
    assert d8[outside].max() <= 1, f"{int((d8[outside] > 1).sum())} pixels differ by more than 1 level"
    # half float: relative rounding 2^-12, POV-Ray's single-precision colour arithmetic well below
    tol = 2.0**-11 * np.abs(ref.color) + 1e-6
    assert np.all((np.abs(res.color - ref.color) <= tol)[outside])


def test_only_needed_features_are_emitted():
    matte = _scene("matte")
    text = povray.scene_to_pov(matte, _rules(matte, {}))
    assert "phong" not in text and "reflection" not in text and "#switch" not in text
    shadows = _scene("shadows")  # max_depth 0: no reflection
    assert "reflection" not in povray.scene_to_pov(shadows, _rules(shadows, {}))
    cs = _scene("colored_specular")
    assert povray.needs_per_channel(cs, _rules(cs, {}))
    assert not povray.needs_per_channel(_scene("exercise"), _rules(_scene("exercise"), {}))
    ex = _scene("exercise")
    assert "background" not in povray.scene_to_pov(ex, _rules(ex, {}))  # on-hit: folded into ambient
    assert "background {" in povray.scene_to_pov(ex, _rules(ex, {"profile": "conventional"}))


def _snapshot(name: str, text: str) -> None:
    path = SNAPSHOTS / name
    if os.environ.get("MINIRT_UPDATE_SNAPSHOTS"):
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    assert path.exists(), f"missing snapshot {path}: run MINIRT_UPDATE_SNAPSHOTS=1 pytest {__file__}"
    assert text == path.read_text(), f"{name} changed; if intended: MINIRT_UPDATE_SNAPSHOTS=1 pytest {__file__}"


@pytest.mark.parametrize("stem", ["exercise", "colored_specular"])
def test_exporter_snapshot(stem):
    sc = _scene(stem)
    _snapshot(f"{stem}.pov", povray.scene_to_pov(sc, _rules(sc, {})))


def test_exporter_snapshot_geometry_frames():
    sc = _scene("exercise")
    ranges = [{"x": (-1.0, 1.0), "y": (-2.0, 0.5), "z": (3.0, 5.0), "t": (0.5, 4.0)}, None]
    frames = povray.color_frames(sc, _rules(sc, {})) + povray.geometry_frames()
    _snapshot("exercise_geometry.pov", povray.scene_to_pov(sc, _rules(sc, {}), frames, ranges))


HOSTILE = r'''
[scene]
name = "evil\" #fopen F \"/etc/passwd\" read #declare X = 1; // /* */"
description = """line one
#write (F, "pwned") */ /* // #include "colors.inc"
#declare Y = 2;"""

[camera]
distance = 2.0
width = 48
height = 48

[light]
position = [10.0, 10.0, -1.0]

[materials."red\"} #fopen G \"x\" write //"]
ambient = [0.1, 0.0, 0.0]
diffuse = [0.7, 0.1, 0.1]
specular = [0.5, 0.5, 0.5]
reflection = [1e-7, 1e-7, 1e-7]

[materials."#declare\n/*"]
ambient = [0.05, 0.05, 0.05]
diffuse = [0.5, 0.5, 0.5]

[[shapes]]
type = "ball"
center = [0.0, 0.0, 4.0]
radius = 0.5
material = "red\"} #fopen G \"x\" write //"

[[shapes]]
type = "plane"
normal = [0.0, 3.0, 0.0]
distance = -3.0
material = "#declare\n/*"
'''

# Every word the exporter may write (the 'e' of exponents included): anything else came from the scene.
KEYWORDS = {
    "version", "global_settings", "assumed_gamma", "ambient_light", "max_trace_level", "adc_bailout", "camera",
    "perspective", "location", "right", "up", "direction", "switch", "frame_number", "case", "break", "end",
    "light_source", "color", "rgb", "background", "sphere", "plane", "pigment", "finish", "ambient", "diffuse",
    "phong", "phong_size", "reflection", "average", "pigment_map", "function", "color_map", "floor", "sqrt",
    "x", "y", "z", "e",
    "declare", povray.MESH_NAME, "mesh2", "vertex_vectors", "face_indices", "mesh_camera", "mesh",  # mesh camera
}  # fmt: skip
# A ball between camera and image plane: the same hostile names through the mesh-camera exporter.
HOSTILE_NEAR = HOSTILE + "\n" + ball((0.0, 0.0, -0.5), 0.05, "#declare\n/*")


@pytest.mark.parametrize("text", [HOSTILE, HOSTILE_NEAR], ids=["pinhole", "mesh-camera"])
def test_hostile_names_never_reach_the_pov_file(tmp_path, text):
    sc = parse_scene(text, "hostile.toml")
    rules = _rules(sc, {})
    assert povray.uses_mesh_camera(sc, rules) == (text is HOSTILE_NEAR)
    frames = povray.color_frames(sc, rules) + povray.geometry_frames()
    text = povray.scene_to_pov(sc, rules, frames)
    # the one declaration the exporter makes itself (the mesh camera's mesh), then nothing else may match
    text, count = re.subn(rf"#declare {povray.MESH_NAME}0 = mesh2", "", text)
    assert count == int(povray.uses_mesh_camera(sc, rules))
    for bad in ['"', "//", "/*", "*/", "#declare", "#fopen", "#write", "#include", "evil", "red", "passwd", "pwned"]:
        assert bad not in text, bad
    words = set(re.findall(r"[A-Za-z_]+", text))
    assert words <= KEYWORDS, words - KEYWORDS
    assert set(re.findall(r"#\w+", text)) <= {"#version", "#switch", "#case", "#break", "#end"}
    files = povray.export(sc, rules, tmp_path)
    for f in files:
        if f.suffix == ".pov":
            assert f.read_text() == povray.scene_to_pov(sc, rules)
    res = ORACLE.render(sc, rules)
    assert res.ok, res.reason
    assert res.hit.any()


def test_export_writes_a_runnable_command(tmp_path):
    sc = _scene("exercise")
    rules = _rules(sc, {})
    files = povray.export(sc, rules, tmp_path)
    assert {f.name for f in files} == {"scene.pov", "render.sh", "README.txt"}
    cmd = shlex.join(povray.command(sc, 1, 1, 1, "png8"))
    assert cmd in (tmp_path / "render.sh").read_text() and cmd in (tmp_path / "README.txt").read_text()
    subprocess.run(["sh", str(tmp_path / "render.sh")], check=True, capture_output=True, timeout=120)
    png = read_image_u8(tmp_path / "out.png")
    ref = tracer.render(sc, rules).color8()
    assert np.abs(png[..., :3].astype(int) - ref.astype(int)).max() <= 1


def test_broken_scene_reports_povray_parse_error(monkeypatch):
    garbage = "#version 3.7;\nsphere { <0, 0, 4>, 0.5 pigmnt { rgb 1 } }\n"
    monkeypatch.setattr(povray_oracle, "scene_to_pov", lambda *a, **k: garbage)  # where the render finds it
    sc = _scene("exercise")
    res = ORACLE.render(sc, _rules(sc, {}))
    assert res.status == "error"
    assert "line 2" in res.reason and "Parse Error" in res.reason and "pigmnt" in res.reason
    assert "\n" not in res.reason


def test_timeout_is_an_error_not_a_hang():
    sc = _scene("matte")
    res = ORACLE.render(sc, _rules(sc, {}), {"timeout": 0.05})
    assert res.status == "error" and "timed out" in res.reason


def test_missing_povray_is_a_skip(monkeypatch):
    monkeypatch.setenv("PATH", str(Path("/nonexistent-minirt")))
    ok, why = ORACLE.available()
    assert not ok and why == "povray not found on PATH; install: sudo apt-get install povray"
    sc = _scene("exercise")
    res = ORACLE.render(sc, _rules(sc, {}))
    assert res.status == "skip" and res.reason == why


def test_missing_povray_via_which(monkeypatch):
    monkeypatch.setattr(shutil, "which", lambda name: None)
    sc = _scene("matte")
    res = ORACLE.render(sc, _rules(sc, {}))
    assert res.status == "skip" and "povray not found" in res.reason


def test_mesh_camera_only_when_something_is_between_camera_and_image_plane(renders):
    """The pinhole camera unless a shape reaches between it and z = 0; then a mesh camera (H + 1 rows,
    the first dropped), whose rays start on the image plane: the near ball is not seen from behind."""
    sc = _scene(None)
    rules = _rules(sc, {})
    assert rules.ray_origin == "image-plane"
    assert povray.between_camera_and_image_plane(sc) == [0] and povray.uses_mesh_camera(sc, rules)
    assert not povray.uses_mesh_camera(sc, replace(rules, ray_origin="camera"))
    text = povray.scene_to_pov(sc, rules)
    assert f"face_indices {{ {SIZE * SIZE}," in text and "mesh_camera" in text
    res = renders("near-ball")["res"]
    assert res.meta["settings"]["camera"] == "mesh_camera" and res.meta["precision"]["mesh_camera"]
    assert all(f"+H{SIZE + 1}" in c for c in res.meta["commands"])
    assert renders("exercise")["res"].meta["settings"]["camera"] == "perspective"
    # the camera-origin render sees the near ball, the image-plane one does not: they really differ
    assert (res.shape_id == 0).sum() < (renders("near-ball-camera")["res"].shape_id == 0).sum()
    # antialiasing maps sub-pixel samples to one triangle: refused with the reason
    aa = ORACLE.render(sc, rules, {"antialias": 2})
    assert aa.status == "skip" and "needs a mesh camera" in aa.reason
    # a plane crossing the pyramid, and a ball wholly outside it
    assert povray.between_camera_and_image_plane(_scene("shadows")) == []
    plane = parse_scene(
        NEAR_BALL.replace("distance = -1.0", "distance = -0.1").replace("[0.0, 1.0, 0.0]", "[0.0, 0.0, 1.0]")
    )
    assert 2 in povray.between_camera_and_image_plane(plane)


def test_supported_rules_and_adapt():
    ex = R.PROFILES["exercise"]
    adapted = ORACLE.adapt(ex)
    assert adapted == replace(
        R.PROFILES["conventional"], background="on-hit", offset="error-bound", ray_origin="image-plane"
    )
    assert set(ORACLE.cannot_follow(ex)) == {"near_root_only", "shadow_range", "two_sided", "clamp", "offset"}
    assert ORACLE.cannot_follow(R.PROFILES["conventional"]) == []


@pytest.mark.parametrize("stem", ["soft", "rules"])
def test_the_exercises_own_samples(stem):
    """Option samples = n: POV-Ray shoots the reference's n stratified rays per pixel (one camera mesh
    each) and averages them, so its colour matches the reference's n-sample render pixel by pixel:
    8-bit within one level, and one level only on a rounding tie, except where a sample's ray lies in
    the band (taken over every sample)."""
    sc = _scene(stem).with_overrides(width=32, height=32, samples=9)
    rules = _rules(sc, {})
    res = ORACLE.render(sc, rules, {"samples": 9})
    assert res.ok, res.reason
    assert res.meta["settings"]["samples_rendered"] == 9 and res.meta["settings"]["camera"] == "mesh_camera"
    assert len(res.meta["commands"]) == 2 and not res.hit.any()  # colour only: no geometry frames
    ref = tracer.render(sc, rules)
    p = res.meta["precision"]
    inband = band.sample_band(sc, rules, 9, p["band_threshold"], p["min_distance"], p["start_err"])
    d = np.abs(res.image8.astype(int) - ref.color8().astype(int))
    assert d[~inband].max() <= 1
    x = np.clip(ref.color, 0, 1) * 255 + 0.5
    tie = np.abs(x - np.rint(x)) <= 2.0**-20 * x
    assert not ((d == 1) & ~tie)[~inband].any()
    # and it is not the one-ray image: supersampling changed the silhouettes
    one = ORACLE.render(sc.with_overrides(samples=1), rules)
    assert (np.abs(one.image8.astype(int) - res.image8.astype(int)).max(axis=-1) > 8).sum() > 10


def test_samples_option_is_checked():
    sc = _scene("exercise").with_overrides(width=32, height=32)
    rules = _rules(sc, {})
    both = ORACLE.render(sc, rules, {"samples": 4, "antialias": 2})
    assert both.status == "error" and "exclude each other" in both.reason
    assert ORACLE.render(sc, rules, {"samples": 0}).status == "error"
    huge = ORACLE.render(sc, rules, {"samples": povray.MAX_MESH_RAYS // (32 * 32) + 1})
    assert huge.status == "skip" and "mesh-camera rays" in huge.reason


def _hidden_then_shown(hidden: int) -> Scene:
    """``hidden`` tiny balls far behind the camera, then five visible ones (the last ids)."""
    behind = "".join(ball((0.01 * k, 0.0, -50.0), 0.001) for k in range(hidden))
    shown = "".join(
        ball((x, y, 4.0), 0.6) for x, y in ((-1.0, -0.6), (0.0, -0.6), (1.0, -0.6), (-0.5, 0.6), (0.5, 0.6))
    )
    m = {"m": material((0.6, 0.5, 0.4))}
    return parse_scene(scene_text(behind, shown, size=24, light=(3.0, 4.0, -3.0), materials=m))


def test_ids_of_more_shapes_than_one_half_float_channel_holds():
    """Shape ids are k + 1 = 2048 hi + lo, each part / 2048 in a half-float channel of its own; the hi frame
    is rendered only from ID_SCALE - 1 shapes on. A scene of 2,100 shapes whose visible balls are the last
    ones (ids 2,095 ... 2,099; the others far behind the camera): one channel would read (k + 1) / 2048 > 1,
    clamped by the colour map, and every visible id came back as 2,047."""
    assert len(povray.geometry_frames(_hidden_then_shown(2040))) == 3  # 2,045 shapes: ids fit one channel
    sc = _hidden_then_shown(2095)
    assert len(povray.geometry_frames(sc)) == 4
    rules = ORACLE.adapt(R.resolve(sc))
    res = ORACLE.render(sc, rules)
    assert res.ok, res.reason
    ref = tracer.render(sc, rules)
    both = res.hit & ref.hit
    assert both.sum() > 100 and set(np.unique(ref.shape_id[both])) == set(range(2095, 2100))
    assert (res.shape_id[both] == ref.shape_id[both]).mean() > 0.99  # the silhouettes may differ
    assert res.meta["hit_consistency"] == 0
