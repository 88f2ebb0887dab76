"""The Mitsuba 3 oracle against the reference tracer (small images: 64 x 64 on every scene).

Tolerances come from oracles/mitsuba/ (precision analysis next to the constants, in accuracy.py):
- hit masks may differ only inside the silhouette band, margin < BAND_K * band_eps (float32
  discriminant; eps = u32 max |f|^2 / r^2 over the balls, K = 16);
- t: |dt| <= T_REL t + 16 u32 (|f| + r) + 4 u32 |f|^2 / (r sqrt(2 m)) on balls (m the silhouette
  margin), T_REL t + the rectangle's absolute bound (meta.planes) on planes;
- normals: <= 16 u32 (|c| + r + |o|) / r radians on balls (a float32 point normalised), ~0 on planes;
- the diffuse term corrected by pi r^2 equals the reference's n.s dc lc up to the cosine's error
  (normal and position errors) on every pixel both call lit; a lit/shadowed disagreement only where
  the shadow ray is inside the band.
On failure a test writes its evidence (both masks, the mismatch image) to tests/_evidence/mitsuba/.
"""

from __future__ import annotations

import math
import os
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from minirt.model import camera
from minirt.model.rules import resolve
from minirt.model.scene import Ball, load_scene, parse_scene
from minirt.oracles import mitsuba as om
from minirt.oracles.mitsuba import exporter, rays, variants
from minirt.oracles.mitsuba import oracle as mitsuba_oracle
from minirt.reference import band, tracer

ROOT = Path(__file__).resolve().parents[2]
SCENES = sorted((ROOT / "scenes").glob("*.toml"))
SNAPSHOTS = Path(__file__).resolve().parents[1] / "snapshots" / "mitsuba"
EVIDENCE = Path(__file__).resolve().parents[1] / "_evidence" / "mitsuba"
SIZE = 64
U32 = om.U32


@pytest.fixture(scope="module")
def oracle():
    o = om.MitsubaOracle()
    ok, why = o.available()
    assert ok, f"Mitsuba must be usable here (make test installs it): {why}"
    return o


_cache: dict[str, tuple] = {}


def _pair(oracle, path: Path):
    """(scene, rules, mitsuba result, reference result), rendered once per scene."""
    if path.stem not in _cache:
        scene = load_scene(path).with_overrides(width=SIZE, height=SIZE, samples=1)  # ray-for-ray: one ray per pixel
        rules = oracle.adapt(resolve(scene))
        res = oracle.render(scene, rules)
        assert res.ok, res.reason
        _cache[path.stem] = (scene, rules, res, tracer.render(scene, rules))
    return _cache[path.stem]


def _evidence(name: str, **images: np.ndarray) -> str:
    from minirt.io.images import write_image

    EVIDENCE.mkdir(parents=True, exist_ok=True)
    for k, img in images.items():
        write_image(EVIDENCE / f"{name}_{k}.png", (np.asarray(img, dtype=np.float64) * 255).astype(np.uint8))
    return f"evidence in {EVIDENCE}"


def _angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle between vectors (radians), stable near 0 (arccos of a dot product is not)."""
    a = a / np.maximum(np.linalg.norm(a, axis=-1, keepdims=True), 1e-300)
    b = b / np.maximum(np.linalg.norm(b, axis=-1, keepdims=True), 1e-300)
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def test_available_and_version(oracle):
    assert oracle.version().startswith("mitsuba 3.9.1 (")
    assert variants._state["variant"] in om.VARIANTS


@pytest.mark.parametrize("path", SCENES, ids=lambda p: p.stem)
def test_geometry_matches_reference(oracle, path):
    scene, rules, res, ref = _pair(oracle, path)
    o, d = camera.primary_rays(scene, rules)
    margin = band.margins(scene, o, d)["margin"].reshape(SIZE, SIZE)
    eps = om.band_eps(scene, o)
    in_band = margin < om.BAND_K * eps
    mismatch = res.hit != ref.hit
    bad = mismatch & ~in_band
    assert not bad.any(), f"{bad.sum()} hit-mask mismatches outside the band; " + _evidence(
        path.stem, mitsuba=res.hit, reference=ref.hit, mismatch=bad
    )
    both = res.hit & ref.hit
    wrong_id = both & (res.shape_id != ref.shape_id) & ~in_band
    assert not wrong_id.any(), f"{wrong_id.sum()} shape-id mismatches outside the band"
    same = both & (res.shape_id == ref.shape_id)

    # t tolerance per pixel (see the module docstring)
    tol = om.T_REL * np.where(same, ref.t, 0.0)
    olen = float(np.max(np.linalg.norm(o, axis=1)))
    for k, s in enumerate(scene.shapes):
        on = same & (ref.shape_id == k)
        if isinstance(s, Ball):
            f = olen + float(np.linalg.norm(s.center))
            sil = band.margins(scene, o, d)["silhouette"].reshape(SIZE, SIZE)
            extra = 16 * U32 * (f + s.radius) + 4 * U32 * f * f / (s.radius * np.sqrt(2 * np.maximum(sil, 1e-30)))
        else:
            extra = res.meta["planes"][f"shape{k}"]["abs_error"]
        tol = np.where(on, tol + extra, tol)
    with np.errstate(invalid="ignore"):
        dt = np.where(same, np.abs(res.t - ref.t), 0.0)
    assert np.all(dt <= tol), f"t off by {dt.max():.3g} (tolerance there {tol[np.argmax(dt - tol)]:.3g})"

    ang = np.where(same, _angle(res.normal, ref.normal), 0.0)
    ntol = np.zeros_like(ang)
    for k, s in enumerate(scene.shapes):
        if isinstance(s, Ball):
            ntol[same & (ref.shape_id == k)] = 16 * U32 * (float(np.linalg.norm(s.center)) + s.radius + olen) / s.radius
        else:
            ntol[same & (ref.shape_id == k)] = 16 * U32
    assert np.all(ang <= ntol), f"normal off by {np.degrees(ang.max()):.3g} deg"
    assert np.degrees(ntol.max()) <= res.meta["precision"]["normal_deg"]


@pytest.mark.parametrize("path", SCENES, ids=lambda p: p.stem)
def test_diffuse_correction_reproduces_reference(oracle, path):
    scene, _rules, res, ref = _pair(oracle, path)
    same = res.hit & ref.hit & (res.shape_id == ref.shape_id)
    mine, theirs = res.aux["diffuse_exercise"], ref.terms["diffuse"]
    np.testing.assert_allclose(mine, res.terms["diffuse"] * res.aux["diffuse_to_exercise"][..., None])
    lit_m, lit_r = mine.max(axis=-1) > 0, theirs.max(axis=-1) > 0
    # lit/shadowed disagreements: only where the shadow ray grazes a silhouette (band on shadow rays)
    flip = same & (lit_m != lit_r)
    if flip.any():
        p = ref.position[flip]
        s = np.asarray(scene.light.position) - p
        s /= np.linalg.norm(s, axis=1, keepdims=True)
        m = band.margins(scene, p, s)["margin"]
        # the shadow ray starts at Mitsuba's hit point, whose absolute error (the rectangles' bound,
        # meta.planes) moves the ray relative to a ball of radius r by error / r
        pos_err = max([v["abs_error"] for v in res.meta["planes"].values()] + [0.0])
        r_min = min([s_.radius for s_ in scene.shapes if isinstance(s_, Ball)] + [math.inf])
        eps = om.band_eps(scene, p) + pos_err / r_min
        assert np.all(m < om.BAND_K * eps), "a shadow disagreement outside the band"
    both = same & lit_m & lit_r
    scale = np.zeros(3)
    for s_ in scene.shapes:
        scale = np.maximum(scale, np.asarray(s_.material.diffuse) * np.asarray(scene.light.color))
    # the cosine n.s carries the normal's error and the hit point's error over the light distance
    err = np.abs(mine - theirs)[both]
    allowed = 1e-4 * scale + 1e-4 * np.abs(theirs[both])
    assert np.all(err <= allowed), f"diffuse off by {err.max():.3g}"
    assert both.sum() > 0.05 * SIZE * SIZE, "too few lit pixels to test anything"


def test_passes_follow_the_scene(oracle):
    _scene, _, res, _ = _pair(oracle, ROOT / "scenes" / "matte.toml")
    assert not any("conductor" in p or "reflection" in p for p in res.meta["passes"])
    assert res.meta["unsupported_terms"] == ["ambient", "background"]
    _, _, res, _ = _pair(oracle, ROOT / "scenes" / "three_balls.toml")
    assert "conductor.sample(level 0)" in res.meta["passes"]
    assert res.meta["emitter"]["intensity"] == [1.0, 1.0, 1.0]
    for key in ("setup", "render"):
        assert res.meta["timings"][key] >= 0
    assert set(res.meta["precision"]) >= {"t_rel", "normal_deg", "why"}


def test_every_plane_rectangle_covers_its_rays(oracle):
    """Growing the rectangles converged: a re-check finds no plane point a traced ray missed."""
    for path in SCENES:
        _, _, res, _ = _pair(oracle, path)
        assert res.meta["plane_resizes"] < rays._MAX_RESIZE, path.stem


@pytest.mark.parametrize("name", ["exercise", "rules"])
def test_sensor_lands_on_the_same_rays(oracle, name):
    scene, rules, rays, _ = _pair(oracle, ROOT / "scenes" / f"{name}.toml")
    sens = oracle.render(scene, rules, {"mode": "sensor"})
    assert sens.ok, sens.reason
    assert np.array_equal(sens.hit, rays.hit)
    assert np.array_equal(sens.shape_id, rays.shape_id)
    both = sens.hit & rays.hit
    # the sensor builds its rays in float32 from the pixel position: a few ulps of the direction
    assert np.all(np.abs(sens.t[both] - rays.t[both]) <= 64 * U32 * (1 + rays.t[both]))
    # the direct integrator's colour is the custom route's local term (no reflection followed)
    np.testing.assert_allclose(sens.color, rays.terms["diffuse"], rtol=1e-3, atol=1e-6)


def test_sensor_spp_gives_variance_and_non_square_skips(oracle):
    scene = load_scene(ROOT / "scenes" / "exercise.toml").with_overrides(width=16, height=16)
    rules = oracle.adapt(resolve(scene))
    res = oracle.render(scene, rules, {"mode": "sensor", "spp": 4, "seed": 3})
    assert res.ok, res.reason
    assert res.aux["variance"].shape == (16, 16, 3) and np.all(res.aux["variance"] >= 0)
    assert res.aux["variance"].max() > 0  # edges of the ball get mixed samples
    again = oracle.render(scene, rules, {"mode": "sensor", "spp": 4, "seed": 3})
    assert np.array_equal(res.color, again.color)  # repeatable for a fixed seed
    wide = scene.with_overrides(width=16, height=8)
    res = oracle.render(wide, rules, {"mode": "sensor"})
    assert res.status == "skip" and "square" in res.reason


# ---- XML ------------------------------------------------------------------------------------


def test_xml_snapshot(oracle):
    scene = load_scene(ROOT / "scenes" / "exercise.toml").with_overrides(width=64, height=64)
    xml = om.scene_to_xml(scene, oracle.adapt(resolve(scene)))
    snap = SNAPSHOTS / "exercise.xml"
    if os.environ.get("MINIRT_UPDATE_SNAPSHOTS") == "1" or not snap.exists():
        snap.parent.mkdir(parents=True, exist_ok=True)
        snap.write_text(xml, encoding="utf-8")
    expected = snap.read_text(encoding="utf-8")
    assert xml == expected, f"XML changed; update with MINIRT_UPDATE_SNAPSHOTS=1 pytest {__file__}"


NASTY = 'x"\'<!-- --> ]]> <script>alert(1)</script> &amp; #include "/etc/passwd" -\n--'


def test_untrusted_names_never_reach_the_xml_unescaped(oracle, tmp_path):
    name = NASTY.replace("\\", "").replace("\n", " ")
    text = (ROOT / "scenes" / "exercise.toml").read_text()
    text = text.replace('name = "exercise"', f"name = {_toml_str(name)}")
    text = text.replace('description = "', f"description = {_toml_str(name)[:-1]} ")
    text = text.replace("materials.red]", f"materials.{_toml_str(name)}]").replace('"red"', _toml_str(name))
    scene = parse_scene(text, "nasty.toml").with_overrides(width=16, height=16)
    rules = oracle.adapt(resolve(scene))
    xml = om.scene_to_xml(scene, rules)
    root = ET.fromstring(xml.encode())  # well-formed
    assert root.tag == "scene"
    body = xml.split("\n", 1)[1]
    for bad in ("<script", "]]>", "#include", 'passwd"', "alert(1)</"):
        assert bad not in body.split("-->", 1)[1], bad  # nothing after the header comment
    comments = re.findall(r"<!--(.*?)-->", xml, flags=re.S)
    assert comments and all("--" not in c and not c.endswith("-") for c in comments)
    assert "<script" not in xml and "&lt;script&gt;" in comments[0]  # the name only escaped, in a comment
    (path,) = oracle.export(scene, rules, tmp_path)
    mi = variants._state["mi"]
    ms = mi.load_file(str(path))
    img = np.asarray(mi.render(ms, spp=1))
    assert img.shape[:2] == (16, 16) and np.isfinite(img).all() and img.max() > 0


def _toml_str(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


# ---- failures -------------------------------------------------------------------------------


def test_import_failure_is_a_skip(monkeypatch):
    def boom():
        raise ImportError("No module named 'mitsuba'")

    monkeypatch.setattr(mitsuba_oracle, "load_mitsuba", boom)  # where the oracle finds it
    o = om.MitsubaOracle()
    ok, why = o.available()
    assert not ok and "mitsuba" in why
    scene = load_scene(ROOT / "scenes" / "matte.toml").with_overrides(width=8, height=8)
    res = o.render(scene, o.adapt(resolve(scene)))
    assert res.status == "skip" and "No module named" in res.reason and "\n" not in res.reason


def test_mitsuba_exception_is_an_error(oracle, monkeypatch):
    mi = variants._state["mi"]

    def broken(*a, **k):
        raise RuntimeError("simulated parser failure\nsecond line")

    monkeypatch.setattr(mi, "load_string", broken)
    scene = load_scene(ROOT / "scenes" / "matte.toml").with_overrides(width=8, height=8)
    res = oracle.render(scene, oracle.adapt(resolve(scene)))
    assert res.status == "error" and "simulated parser failure" in res.reason and "\n" not in res.reason


def test_supported_rules_are_declared(oracle):
    r = oracle.adapt(resolve(load_scene(ROOT / "scenes" / "exercise.toml")))
    assert (r.near_root_only, r.shadow_range, r.two_sided, r.clamp, r.offset) == (
        False, "to-light", True, True, "error-bound",
    )  # fmt: skip
    assert math.isfinite(om.T_REL)


def test_scalar_fallback_variant_renders(tmp_path):
    """With llvm ruled out, scalar_rgb is used (in a subprocess: the variant is process-global)."""
    import subprocess
    import sys

    code = (
        "import numpy as np, minirt.oracles.mitsuba as om, minirt.oracles.mitsuba.variants as mv\n"
        "mv.VARIANTS = ('scalar_rgb',)\n"
        "from minirt.model.scene import load_scene\nfrom minirt.model.rules import resolve\n"
        "from minirt.reference import tracer\n"
        "o = om.MitsubaOracle()\n"
        "s = load_scene('scenes/exercise.toml').with_overrides(width=8, height=8)\n"
        "r = o.adapt(resolve(s)); res = o.render(s, r); ref = tracer.render(s, r)\n"
        "assert res.ok, res.reason\nassert o.version().endswith('(scalar_rgb)')\n"
        "assert np.array_equal(res.hit, ref.hit)\n"
        "assert np.abs(res.aux['diffuse_exercise'] - ref.terms['diffuse']).max() < 1e-5\n"
        "print('ok')\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0 and "ok" in out.stdout, out.stderr[-2000:]


@pytest.mark.parametrize("name", ["exercise", "shadows"])
def test_export_renders_visibly_in_mitsuba(oracle, name, tmp_path):
    """Mitsuba's own render of the exported XML resembles the exercise's image: with the light's intensity
    scaled by pi d^2 (the viewing distance) its mean brightness is within 0.3-3x of the reference's
    (unscaled, the exercise scene's mean is ~300x too dark). Only the export is scaled."""
    scene = load_scene(ROOT / "scenes" / f"{name}.toml").with_overrides(width=16, height=16)
    rules = oracle.adapt(resolve(scene))
    (path,) = oracle.export(scene, rules, tmp_path)
    xml = path.read_text()
    d = om.viewing_distance(scene, rules)
    factor = math.pi * d**2
    assert f"times pi d^2 = {factor!r}" in xml and f"d = {d!r}" in xml  # the file says how it was scaled
    assert f'<rgb name="intensity" value="{exporter._rgb(tuple(c * factor for c in scene.light.color))}"/>' in xml
    # the oracle's own scene (render, check) keeps the exercise's intensity
    assert f'<rgb name="intensity" value="{exporter._rgb(scene.light.color)}"/>' in om.scene_to_xml(scene, rules)
    mi = variants._state["mi"]
    img = np.asarray(mi.render(mi.load_file(str(path)), spp=4))
    ref = tracer.render(scene, resolve(scene)).color
    ratio = float(img.mean() / ref.mean())
    assert 0.3 < ratio < 3.0, ratio
    assert img.max() > 0.2  # visible, not the ~1e-3 of an unscaled light


def test_a_second_render_compiles_nothing(oracle):
    """The rays handed to Mitsuba sit at 64-byte boundaries (minirt.jit.arrays), so a kernel's code does not
    depend on where NumPy put them: rendering a scene again in the same process is all kernel-cache hits
    (before: 87 of three_balls' 282 kernels compiled again, 1.8 s)."""
    import drjit as dr

    scene = load_scene(ROOT / "scenes" / "three_balls.toml").with_overrides(width=40, height=24, samples=1)
    rules = oracle.adapt(resolve(scene))
    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        assert oracle.render(scene, rules).ok
        dr.kernel_history()
        assert oracle.render(scene, rules).ok
        kernels = [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]
    assert len(kernels) > 10  # the render ran its kernels ...
    assert [k["hash"] for k in kernels if not k["cache_hit"]] == []  # ... every one already compiled
