"""Outputs: pruning changes nothing, files are bit-identical run to run, buffers and sidecar complete."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from support.inproc import minirt

from minirt.io.images import read_image, read_image_u8
from minirt.model.result import TERMS
from minirt.model.rules import PROFILES, TRACE_RULES, flipped, resolve
from minirt.model.scene import load_scene
from minirt.reference.probe import probe
from minirt.reference.tracer import Tracer


def _same(a, b):
    for f in ("hit", "shape_id", "t", "position", "normal", "color"):
        x, y = getattr(a, f), getattr(b, f)
        assert x.dtype == y.dtype and x.tobytes() == y.tobytes(), f
    for k in TERMS:
        assert a.terms[k].tobytes() == b.terms[k].tobytes(), k


@pytest.mark.parametrize("profile", list(PROFILES))
def test_pruning_is_bit_identical(scene_path, profile):
    scene = load_scene(scene_path).with_overrides(width=40, height=40)
    for rules in [PROFILES[profile], *(flipped(PROFILES[profile], r) for r in TRACE_RULES)]:
        _same(Tracer(scene, rules, prune=True).render(), Tracer(scene, rules, prune=False).render())


def test_pruning_skips_work():
    """The matte scene has no specular and no reflection: neither is simulated, nor traced."""
    scene = load_scene("scenes/matte.toml")
    r = Tracer(scene, resolve(scene)).render()
    assert set(r.meta["effects"]["skipped"]) == {"specular", "reflection"}
    assert r.meta["effects"]["reflection_depth"] == 0
    full = Tracer(scene, resolve(scene), prune=False)
    assert full.effects.reflection and full.effects.reflection_depth == 3


def _children(*cmds: list[str], timeout: int) -> None:
    """Each command in a child process of its own, all at once (they are independent runs: the files
    two processes write are compared), each required to succeed."""
    procs = [subprocess.Popen(c, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True) for c in cmds]
    for c, p in zip(cmds, procs, strict=True):
        _, err = p.communicate(timeout=timeout)
        assert p.returncode == 0, (c, err[-2000:])


def test_files_are_bit_identical(tmp_path):
    def render(out, *extra):
        return [sys.executable, "-m", "minirt", "render", "scenes/exercise.toml", "--width", "32", "--height", "24",
                "--out", str(out), *extra]  # fmt: skip

    _children(render(tmp_path / "a"), render(tmp_path / "b"), render(tmp_path / "c", "--timings"), timeout=120)
    for suffix in ("png", "exr", "json"):
        name = f"exercise.reference.{suffix}"
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name
    meta = json.loads((tmp_path / "a" / "exercise.reference.json").read_text())
    assert "timings" not in meta and meta["scene_sha256"] and meta["effects"]["simulated"]
    # --timings records them (asked for explicitly: the sidecar then measures the run)
    timed = json.loads((tmp_path / "c" / "exercise.reference.json").read_text())
    assert timed["timings"]["wall"] > 0 and timed["timings"]["total"] > 0
    assert {k: v for k, v in timed.items() if k != "timings"} == meta


def test_exr_holds_every_buffer(tmp_path):
    from minirt.io.images import write_result

    scene = load_scene("scenes/three_balls.toml").with_overrides(width=16, height=12)
    r = Tracer(scene, resolve(scene)).render()
    paths = write_result(r, tmp_path, "x")
    data, names = read_image(paths["exr"])
    assert data.shape == (12, 16, len(names))
    expected = ["R", "G", "B", "hit", "id", "t", "P.X", "P.Y", "P.Z", "N.X", "N.Y", "N.Z"]
    expected += [f"{t}.{c}" for t in TERMS for c in "RGB"]
    assert sorted(names) == sorted(expected)  # OpenEXR stores channels sorted by name
    ch = {n: data[..., i] for i, n in enumerate(names)}
    # the harness's diagnostics (render(diagnostics=True)) add two aux channels
    rd = Tracer(scene, resolve(scene)).render(diagnostics=True)
    assert np.array_equal(rd.color, r.color) and set(rd.aux) == {"ray_tree", "shadow_margin"}
    paths = write_result(rd, tmp_path, "d")
    data_d, names_d = read_image(paths["exr"])
    assert sorted(names_d) == sorted([*expected, "aux.ray_tree", "aux.shadow_margin"])
    tree = data_d[..., names_d.index("aux.ray_tree")]
    assert tree.max() < 2**24 and len(np.unique(tree)) > 4  # shapes x lit x reflected: several trees
    paths = write_result(r, tmp_path, "x")  # the plain render's files, checked below
    assert np.array_equal(ch["id"], r.shape_id.astype(np.float32))
    assert np.allclose(ch["t"], np.where(r.hit, r.t, 0), rtol=1e-7)
    # Every channel is its float64 buffer rounded once to float32, exactly (exr_channels converts each
    # buffer straight into its channel).
    planes = {"hit": r.hit, "id": r.shape_id, "t": np.where(r.hit, r.t, 0.0)}
    for prefix, a, comps in [("", r.color, "RGB"), ("P.", r.position, "XYZ"), ("N.", r.normal, "XYZ")] + [
        (f"{t}.", r.terms[t], "RGB") for t in TERMS
    ]:
        planes |= {prefix + c: a[..., i] for i, c in enumerate(comps)}
    assert set(planes) == set(names)
    for name, plane in planes.items():
        assert np.array_equal(ch[name], np.asarray(plane, np.float64).astype(np.float32)), name
    total = sum(np.stack([ch[f"{t}.{c}"] for c in "RGB"], -1) for t in TERMS)
    assert np.allclose(total, r.color, atol=1e-6), "the terms add up to the colour"
    png = read_image_u8(paths["png"])
    assert np.array_equal(png, np.floor(np.clip(r.color, 0, 1) * 255 + 0.5).astype(np.uint8))
    meta = json.loads(paths["json"].read_text())
    assert meta["scene_sha256"] == scene.digest and meta["settings"]["precision"] == "f64"
    assert {"simulated", "skipped"} <= set(meta["effects"]) and "drjit" in meta["version"]


def test_samples_average_stratified_rays():
    scene = load_scene("scenes/exercise.toml").with_overrides(width=24, height=24, samples=4)
    r = Tracer(scene, resolve(scene)).render()
    one = Tracer(scene.with_overrides(samples=1), resolve(scene)).render()
    assert np.array_equal(r.hit, one.hit), "geometry buffers always describe the one-ray-per-pixel ray"
    diff = np.abs(r.color - one.color).max(axis=-1)
    # Inside a shape, the pixel average differs from its corner sample by the shading gradient over
    # one pixel (small); across a silhouette it differs by a whole step between two shapes.
    assert np.median(diff) < 0.02 and diff.max() > 0.2
    again = Tracer(scene, resolve(scene)).render()
    assert r.color.tobytes() == again.color.tobytes(), "the sample pattern is seeded"


def test_probe_matches_render():
    scene = load_scene("scenes/three_balls.toml").with_overrides(width=32, height=32)
    rules = resolve(scene)
    img = Tracer(scene, rules).render()
    for x, y in [(5, 30), (12, 20), (20, 18), (1, 1)]:
        p = probe(scene, rules, x, y)
        assert set(p) >= {"ray", "hit", "terms", "color", "color8"}
        assert np.allclose(p["color"], img.color[y, x], rtol=0, atol=1e-12)
        assert p["color8"] == img.color8()[y, x].tolist()
        if img.hit[y, x]:
            assert p["hit"]["id"] == img.shape_id[y, x] and p["hit"]["t"] == img.t[y, x]
        else:
            assert p["hit"] is None


def test_probe_json_cli():
    p = minirt("probe", "scenes/exercise.toml", "128", "128", "--json")  # in this process (tests/support/inproc.py)
    assert p.returncode == 0, p.stderr
    d = json.loads(p.stdout)
    assert d["hit"]["id"] == 0 and d["hit"]["normal"][2] < 0
    assert d["shadow"]["lit"] is True and len(d["levels"]) >= 2


@pytest.mark.parametrize("rule", [{}, {"pixel_sample": "center"}, {"ray_origin": "camera"}])
@pytest.mark.parametrize("precision", ["f64", "f32"])
def test_tracer_rays_are_the_oracles_rays(rule, precision):
    """The tracer builds primary rays in Dr.Jit; oracles get camera.primary_rays: same bits."""
    from minirt.model import camera

    scene = load_scene("scenes/exercise.toml").with_overrides(width=37, height=23)
    rules = resolve(scene, overrides=rule)
    tr = Tracer(scene, rules, precision=precision)
    o, d = tr.primary_rays()
    o_np, d_np = camera.primary_rays(scene, rules)
    dt = np.float64 if precision == "f64" else np.float32
    if precision == "f64":
        assert tr.to_numpy3(o).tobytes() == o_np.tobytes()
        assert tr.to_numpy3(d).tobytes() == d_np.tobytes()
    else:  # float32 rays: the same rays rounded once (the tracer computes them in float32)
        assert np.allclose(tr.to_numpy3(d), d_np.astype(dt), rtol=0, atol=4e-7)


@pytest.mark.parametrize("rule", [{}, {"ray_origin": "camera"}])
@pytest.mark.parametrize("precision", ["f64", "f32"])
def test_sample_rays_are_camera_rays_through(rule, precision):
    """samples > 1: the tracer builds each sample's rays in Dr.Jit (float64, then its precision);
    camera.rays_through, which Mitsuba's and the harness's samples use, gives the same bits."""
    from minirt.model import camera

    scene = load_scene("scenes/exercise.toml").with_overrides(width=37, height=23, samples=9)
    rules = resolve(scene, overrides=rule)
    tr = Tracer(scene, rules, precision=precision)
    dt = np.float64 if precision == "f64" else np.float32
    for s in (0, 4, 8):
        u, v = camera.sample_offsets(9, s, 37 * 23)
        o, d = tr.sample_rays(u, v)
        o_np, d_np = camera.rays_through(scene, rules, u, v)
        assert tr.to_numpy3(o).astype(dt).tobytes() == o_np.astype(dt).tobytes()
        assert tr.to_numpy3(d).astype(dt).tobytes() == d_np.astype(dt).tobytes()


def test_every_backend_writes_identical_files_twice(tmp_path):
    """`render -b all` twice: every file (each backend's PNG, EXR, JSON and the contact sheet) byte-equal."""

    def render(out):
        return [sys.executable, "-m", "minirt", "render", "scenes/three_balls.toml", "-b", "all",
                "--width", "24", "--height", "16", "--out", str(out)]  # fmt: skip

    _children(render(tmp_path / "a"), render(tmp_path / "b"), timeout=300)
    names = sorted(p.name for p in (tmp_path / "a").iterdir())
    assert names == sorted(p.name for p in (tmp_path / "b").iterdir())
    assert "three_balls.contact.png" in names, names
    for backend in ("reference", "mitsuba", "povray", "embree"):  # Embree is geometry only: EXR, no PNG
        assert {f"three_balls.{backend}.exr", f"three_balls.{backend}.json"} <= set(names), (backend, names)
    for name in names:
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name


@pytest.mark.parametrize(
    "changes",
    [{}, {"ray_origin": "camera", "pixel_sample": "center", "pixel_shift": (1.0, -0.5)}],
    ids=["given", "moved"],
)
def test_rays_of_some_pixels_are_the_whole_images_bits(changes):
    """camera.primary_rays(..., pixels): the diagnosis asks for a few pixels' rays; each must be the same
    float64 bits as that pixel's ray in the whole image (a non-square image, first/last pixels, row ends)."""
    from dataclasses import replace

    from minirt.model import camera
    from minirt.model import rules as R

    sc = load_scene("scenes/rules.toml").with_overrides(width=37, height=23)
    rules = replace(R.resolve(sc), **changes)
    o, d = camera.primary_rays(sc, rules)
    idx = np.array([0, 5, 36, 37, 500, 850])
    o2, d2 = camera.primary_rays(sc, rules, idx)
    assert o2.shape == (6, 3) and d2.shape == (6, 3)
    assert (o[idx].view(np.uint64) == o2.view(np.uint64)).all()
    assert (d[idx].view(np.uint64) == d2.view(np.uint64)).all()


def test_both_layouts_hold_the_same_bits_and_files(tmp_path, monkeypatch):
    """A straight-line first level hands its buffers over as the kernel's own outputs (``Planes``, stacked
    only when read); a looped one as 4-packets. Same buffers, same files -- and writing the EXR and the PNG
    does not stack the planes."""
    from minirt.io import images
    from minirt.model.result import Planes
    from minirt.reference import integrator

    scene = load_scene("scenes/three_balls.toml").with_overrides(width=48, height=40)
    rules = resolve(scene)
    got = {}
    for form, below in (("looped", 1 << 62), ("straight", 0)):
        monkeypatch.setattr(integrator, "LOOP_FIRST_LEVEL_BELOW", below)
        r = Tracer(scene, rules).render()
        held = [r.held(k) for k in ("color", "position", "normal", *TERMS)]
        assert all(isinstance(v, Planes) == (form == "straight") for v in held), form
        paths = images.write_result(r, tmp_path / form, "x")
        if form == "straight":  # the files are written from the components
            assert all(isinstance(r.held(k), Planes) for k in ("color", "position", "normal", *TERMS))
        got[form] = (r, {k: p.read_bytes() for k, p in paths.items()})
    (a, fa), (b, fb) = got["looped"], got["straight"]
    _same(a, b)
    assert fa == fb
    assert b.color.shape == (40, 48, 3) and b.color.flags.c_contiguous
    assert not isinstance(b.held("color"), Planes)  # stacked once read, and kept
