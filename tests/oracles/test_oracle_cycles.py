"""The Cycles oracle (Blender 5.0.1 as a Python module, in a child process) against the reference tracer.

What "agree" means here (oracles/cycles/precision.py derives every bound):
- geometry, per pixel, through the harness's own check with Cycles' tolerance: hit masks and shape ids
  agree outside each shape's band (the float32 intersector and the camera ray's displacement), t within
  t_rel t + the quads' abs_error + (abs_error + origin_err + dir_err t)/cos, normals within the float32
  floor plus the hit point's displacement over r -- and the check judges the scene (not inconclusive);
- shading: Cycles' diffuse term times pi r^2 is the exercise's n.s dc lc within the harness's diffuse_rel;
- Cycles' camera rays go through the rules' points (corner, centre, shift, non-square pixels): the ray
  implied by each hit point is within dir_err plus the hit point's own rounding of the reference's;
- a render is the same bytes twice; a forced disagreement FAILs; a missing Blender is a SKIP and a
  crashing one an ERROR while the others finish.
Small images (24 to 48 pixels a side): Blender's start-up (~1-2 s a render) dominates.
"""

from __future__ import annotations

import json
import math
import subprocess
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from minirt.harness.backends import get
from minirt.harness.results import CheckResult, SceneCheck, worst
from minirt.harness.run import check_scene
from minirt.model import camera
from minirt.model.rules import resolve
from minirt.model.scene import Ball, load_scene, parse_scene
from minirt.oracles.cycles import CyclesOracle, run
from minirt.oracles.cycles import precision as pr
from minirt.oracles.cycles import scene as cs
from minirt.reference import tracer

ROOT = Path(__file__).resolve().parents[2]
SCENES = sorted((ROOT / "scenes").glob("*.toml"))
SIZE = 48

pytestmark = pytest.mark.skipif(
    not CyclesOracle().available()[0],
    reason=f"Blender's Python is not installed here ({CyclesOracle().available()[1]})",
)


@pytest.fixture(scope="module")
def oracle():
    return get("cycles")


def _scene(name: str, w: int = SIZE, h: int | None = None):
    return load_scene(ROOT / "scenes" / f"{name}.toml").with_overrides(width=w, height=h or w, samples=1)


_checked: dict[str, SceneCheck] = {}


def _check(path: Path) -> SceneCheck:
    if path.stem not in _checked:
        _checked[path.stem] = check_scene(path, ["cycles"], (SIZE, SIZE))
    return _checked[path.stem]


def test_available_and_version(oracle):
    assert oracle.available() == (True, "Blender 5.0.1 (Cycles, CPU)")
    assert oracle.name == "cycles" and oracle.export_as == "blender" and oracle.concurrent


@pytest.mark.parametrize("path", SCENES, ids=lambda p: p.stem)
def test_buffers_match_the_reference_within_the_band(path):
    b = _check(path).backends["cycles"]
    geom = b.checks["geometry"]
    assert geom.verdict == "pass" and not geom.inconclusive, geom.reason
    f = geom.figures
    assert f["mask_mismatch_outside_band"] == 0 and f["id_mismatch"] == 0 and f["depth_violations"] == 0
    assert f["normal_violations"] == 0
    # judged on (nearly) every hit pixel: Cycles' band is narrow on the bundled scenes
    assert f["band_pixels"] < 0.05 * f["pixels"], f["band_pixels"]
    assert f["depth_rel_err_max"] < 1e-5  # float32: a few u32 of t


@pytest.mark.parametrize("path", SCENES, ids=lambda p: p.stem)
def test_diffuse_term_is_the_exercises(path):
    b = _check(path).backends["cycles"]
    shading = b.checks["shading"]
    assert shading.verdict == "pass", shading.reason
    assert shading.figures["lit_mismatch"] == 0
    assert shading.figures["diffuse_rel_err_max"] < 1e-4
    assert b.verdict == "pass", b.reason


def _implied_rays(oracle, scene, rules):
    res = oracle.render(scene, rules)
    assert res.ok, res.reason
    _o, d = camera.primary_rays(scene, rules)
    cam = np.asarray(scene.camera.position)
    hit = res.hit.reshape(-1)
    p = res.position.reshape(-1, 3)[hit]
    implied = (p - cam) / np.linalg.norm(p - cam, axis=1, keepdims=True)
    return res, implied, d[hit], np.linalg.norm(p - cam, axis=1)


@pytest.mark.parametrize(
    "rule, size",
    [({}, (32, 32)), ({"pixel_sample": "center"}, (32, 32)), ({"pixel_shift": (0.5, -1.0)}, (32, 32)),
     ({"ray_origin": "camera"}, (32, 32)), ({}, (40, 24)), ({}, (24, 40)),
     ({}, (3, 2)), ({"pixel_sample": "center"}, (40, 3))],
)  # fmt: skip
def test_camera_rays_go_through_the_rules_points(oracle, rule, size):
    """The direction from the camera to each of Cycles' hit points is the reference's ray: within dir_err
    plus the hit point's float32 rounding (8 u32 |P| over its distance from the camera). Without the
    filter-centre bias (1/2044 pixel) the rays would be off by 1e-5 radians here; by a pixel's half without
    the corner shift."""
    scene = _scene("shadows", *size)
    rules = replace(oracle.adapt(resolve(scene)), **rule)
    _res, implied, d, dist = _implied_rays(oracle, scene, rules)
    ang = np.linalg.norm(np.cross(implied, d), axis=1)
    allowed = pr.DIR_ERR + 8 * pr.U32 * (dist + 3.0) / dist
    assert np.all(ang <= allowed), f"{ang.max():.3g} rad (allowed {allowed.min():.3g})"
    pixel = 1.0 / (scene.camera.distance * max(size))
    assert ang.max() < 1e-3 * pixel  # a thousandth of a pixel's angle at most


def test_same_bytes_twice(oracle):
    scene = _scene("three_balls", 40, 24)
    rules = oracle.adapt(resolve(scene))
    a, b = oracle.render(scene, rules), oracle.render(scene, rules)
    for key in ("hit", "shape_id", "t", "position", "normal", "color", "image8"):
        assert np.array_equal(getattr(a, key), getattr(b, key)), key
    for key in a.aux:
        assert np.array_equal(a.aux[key], b.aux[key]), key


def test_a_ball_is_invisible_from_inside(oracle):
    """Cycles culls a point's back face (near_root_only true): the rules scene's ball crossing the image
    plane hides nothing from the rays starting inside it, as the reference under near_root_only true."""
    scene = _scene("rules", 32)
    assert oracle.adapt(resolve(scene)).near_root_only is True
    rules = oracle.adapt(resolve(scene))
    res, ref = oracle.render(scene, rules), tracer.render(scene, rules)
    o, _ = camera.primary_rays(scene, rules)
    ball = scene.shapes[3]
    assert isinstance(ball, Ball) and ball.center[2] - ball.radius < 0 < ball.center[2] + ball.radius
    inside = (np.linalg.norm(o - np.asarray(ball.center), axis=1) < ball.radius).reshape(32, 32)
    assert inside.any()
    assert not np.any(res.shape_id[inside] == 3) and np.array_equal(res.shape_id[inside], ref.shape_id[inside])
    under_false = tracer.render(scene, replace(rules, near_root_only=False))
    assert np.any(under_false.shape_id[inside] == 3)  # the rule matters on those rays


def test_samples_are_seeded_and_the_statistical_route_has_a_variance(oracle):
    scene = _scene("exercise", 24)
    rules = oracle.adapt(resolve(scene))
    a, b = oracle.render(scene, rules, {"spp": 8, "seed": 3}), oracle.render(scene, rules, {"spp": 8, "seed": 3})
    assert a.ok and np.array_equal(a.color, b.color)
    assert not np.array_equal(a.color, oracle.render(scene, rules, {"spp": 8, "seed": 4}).color)
    s = oracle.render(scene, rules, {"mode": "sensor", "spp": 4})
    assert s.ok, s.reason
    assert s.aux["variance"].shape == (24, 24, 3) and s.aux["variance"].max() > 0  # the ball's edge pixels
    cov = s.aux["coverage"]
    assert set(np.unique(cov)) <= {0.0, 0.25, 0.5, 0.75, 1.0} and 0 < cov.mean() < 1
    assert "reflection" in s.meta["unsupported_terms"]  # direct light only on that route
    assert oracle.render(scene, rules, {"spp": 0}).status == "error"


def test_a_forced_disagreement_fails():
    """The same scene with a ball 2 % larger than the reference's: the check FAILs on geometry."""
    path = ROOT / "scenes" / "exercise.toml"
    scene = _scene("exercise", 32)
    rules = get("cycles").adapt(resolve(scene))
    ball = scene.shapes[0]
    assert isinstance(ball, Ball)
    bigger = replace(scene, shapes=(replace(ball, radius=ball.radius * 1.02), *scene.shapes[1:]))
    res = get("cycles").render(bigger, rules)
    assert res.ok, res.reason
    res.meta["precision"]["radius"][0] = ball.radius  # the tolerance of the scene it is compared with
    sc = check_scene(path, ["cycles"], (32, 32), rendered={"cycles": res})
    b = sc.backends["cycles"]
    assert b.verdict == "fail" and "geometry" in b.reason, b.reason
    f = b.checks["geometry"].figures
    assert f["mask_mismatch_outside_band"] > 0 and f["depth_violations"] > 50  # its rim, and its whole face in t


def test_export_is_a_blend_file_a_student_can_render(oracle, tmp_path):
    """SCENE.blend: materials named as in the scene file, the world the background colour, Cycles as the
    oracle renders; Blender's own render of it is about as bright as the exercise's image (its light scaled
    by pi d^2 for viewing, as Mitsuba's export)."""
    scene = _scene("exercise", 16)
    rules = oracle.adapt(resolve(scene))
    (path,) = oracle.export(scene, rules, tmp_path)
    assert path.name == "exercise.blend" and path.stat().st_size > 10_000
    code = (
        "import bpy, json, sys\n"
        "bpy.ops.wm.open_mainfile(filepath=sys.argv[1])\n"
        "sc = bpy.context.scene\n"
        "sc.render.filepath = sys.argv[2]\n"
        "bpy.ops.render.render(write_still=True)\n"
        "bg = sc.world.node_tree.nodes['Background'].inputs['Color'].default_value\n"
        "print('minirt-cycles ' + json.dumps({'engine': sc.render.engine, 'samples': sc.cycles.samples,"
        " 'materials': sorted(m.name for m in bpy.data.materials), 'world': list(bg)[:3],"
        " 'size': [sc.render.resolution_x, sc.render.resolution_y]}))\n"
    )
    out = tmp_path / "render.exr"
    p = subprocess.run([str(run.blender_python()), "-c", code, str(path), str(out)], capture_output=True,
                       text=True, timeout=300)  # fmt: skip
    said = run._said(p.stdout)
    assert p.returncode == 0 and said, p.stderr[-2000:]
    assert said["engine"] == "CYCLES" and said["samples"] == 1 and said["size"] == [16, 16]
    assert said["materials"] == ["floor", "red"]
    np.testing.assert_allclose(said["world"], scene.background, rtol=1e-6)
    img = run.read_exr(out, 16, 16)
    rgb = np.stack([img[f"Combined.{c}"] for c in "RGB"], axis=-1)
    ratio = float(rgb.mean() / tracer.render(scene, resolve(scene)).color.mean())
    assert 0.3 < ratio < 3.0, ratio


NASTY = 'x"\'<!-- --> ]]> <script>alert(1)</script> &amp; #include "/etc/passwd" -\n--'


def test_untrusted_names_stay_names(oracle, tmp_path):
    """A scene and material named with quotes, markup and paths: the job carries them as JSON strings,
    Blender as datablock names, and the export's file name is a safe stem inside --out."""
    name = NASTY.replace("\n", " ")
    quoted = '"' + name.replace("\\", "\\\\").replace('"', '\\"') + '"'
    text = (ROOT / "scenes" / "exercise.toml").read_text()
    text = text.replace('name = "exercise"', f"name = {quoted}")
    text = text.replace("materials.red]", f"materials.{quoted}]").replace('"red"', quoted)
    scene = parse_scene(text, "nasty.toml").with_overrides(width=8, height=8)
    rules = oracle.adapt(resolve(scene))
    res = oracle.render(scene, rules)
    assert res.ok, res.reason
    (path,) = oracle.export(scene, rules, tmp_path / "out")
    assert path.parent == tmp_path / "out" and path.suffix == ".blend" and "/" not in path.stem
    assert cs.materials_job(scene)[0][0]["name"] == name


def test_sweep_is_samples_against_its_own_converged_render(oracle):
    scene = _scene("exercise", 16)
    (series,) = oracle.sweep(scene, resolve(scene), {"spp": (1, 4)})
    assert series.knob == "spp" and [s.options["spp"] for s in series.settings] == [1, 4]
    assert series.error == "color_exposure" and series.truth.backend == "cycles"
    assert series.truth.options["spp"] > 1000 and series.truth.options["seed"] != series.settings[0].options["seed"]
    assert series.rules == oracle.adapt(resolve(scene))


# ---- faults -----------------------------------------------------------------------------------


def test_missing_blender_is_a_skip(monkeypatch, tmp_path):
    monkeypatch.setenv(run.ENV, str(tmp_path / "no-such-python"))
    o = CyclesOracle()
    ok, why = o.available()
    assert not ok and "no-such-python" in why
    scene = _scene("matte", 8)
    res = o.render(scene, o.adapt(resolve(scene)))
    assert res.status == "skip" and "\n" not in res.reason


# A fake Blender Python: answers the version like the real one (on the command line, or as a serving
# process's first question), then crashes or talks garbage on its first job.
ANSWERS_VERSION = r"""if [ "$2" = "--version" ]; then echo 'minirt-cycles {"blender": "5.0.1"}'; exit 0; fi
if [ "$2" = "--serve" ]; then read question; echo 'minirt-cycles {"blender": "5.0.1"}'; echo minirt-cycles-done; \
  read job; fi
"""
FAKE = (
    r"""#!/bin/sh
"""
    + ANSWERS_VERSION
    + r"""
case "$FAKE_MODE" in
  segv) kill -SEGV $$ ;;
  fail) echo "Error: Python: Traceback ... RuntimeError: simulated bpy failure" >&2; exit 1 ;;
  nothing) echo 'minirt-cycles {"blender": "5.0.1", "timings": {"setup": 0, "render": 0}}'; exit 0 ;;
esac
exit 3
"""
)


@pytest.mark.parametrize(
    "mode, words",
    [("segv", "Blender crashed (signal 11)"), ("fail", "simulated bpy failure"), ("nothing", "render.exr")],
)
def test_a_crashing_blender_is_an_error_and_the_others_finish(monkeypatch, tmp_path, mode, words):
    fake = tmp_path / f"python-{mode}"
    fake.write_text(FAKE)
    fake.chmod(0o755)
    monkeypatch.setenv(run.ENV, str(fake))
    monkeypatch.setenv("FAKE_MODE", mode)
    assert CyclesOracle().available() == (True, "Blender 5.0.1 (Cycles, CPU)")
    sc = check_scene(ROOT / "scenes" / "exercise.toml", ["cycles", "embree"], (16, 16))
    b = sc.backends["cycles"]
    assert b.verdict == "error" and words in b.reason and "\n" not in b.reason, b.reason
    assert sc.backends["embree"].verdict == "pass"
    assert CheckResult(worst([sc.verdict]), [sc]).exit_code() == 2


def test_a_hanging_blender_times_out(monkeypatch, tmp_path):
    fake = tmp_path / "python-hang"
    fake.write_text("#!/bin/sh\n" + ANSWERS_VERSION + "sleep 600\n")
    fake.chmod(0o755)
    monkeypatch.setenv(run.ENV, str(fake))
    scene = _scene("matte", 8)
    o = CyclesOracle()
    res = o.render(scene, o.adapt(resolve(scene)), {"timeout": 1.0})
    assert res.status == "error" and "timed out after 1 s" in res.reason, res.reason


def test_scene_job_is_blenders_frame():
    """The job the child builds: z negated, each quad wound along its plane's normal, the light's power
    4 pi (radiant intensity lc), materials named as in the scene file."""
    scene = _scene("exercise", 16)
    rules = resolve(scene)
    job = cs.job(scene, rules, cs.quads(scene, rules))
    assert job["camera"]["location"] == [0.0, 0.0, scene.camera.distance]
    assert job["balls"][0]["center"] == [0.0, 0.0, -4.0] and job["balls"][0]["index"] == 1
    (plane,) = job["planes"]
    a, b, c = (np.asarray(plane["corners"][i]) for i in range(3))
    n = np.cross(b - a, c - a)
    assert np.dot(n, [0.0, 1.0, 0.0]) > 0  # the floor's normal (0, 1, 0), unchanged by the mirror
    assert job["light"]["energy"] == pytest.approx(4 * math.pi) and job["light"]["color"] == [1.0, 1.0, 1.0]
    assert [m["name"] for m in job["materials"]] == ["red", "floor"]
    json.dumps(job)  # plain JSON for the child


def test_planes_cover_every_ray_cycles_casts(oracle):
    """Each quad holds every pixel corner's hit on its plane (within the quad, not at its edge)."""
    scene = _scene("three_balls", 32)
    rules = oracle.adapt(resolve(scene))
    quads = cs.quads(scene, rules)
    o, d = cs.pixel_corner_rays(scene, rules)
    size = cs.scene_size(scene)
    for qd in quads.values():
        t = qd.hits(o, d)
        p = o[np.isfinite(t)] + t[np.isfinite(t), None] * d[np.isfinite(t)]
        c = qd.corners(size)
        uv = np.stack([(p - c[0]) @ (c[1] - c[0]), (p - c[0]) @ (c[3] - c[0])], axis=1)
        assert np.all(uv > 0) and np.all(uv[:, 0] < np.sum((c[1] - c[0]) ** 2))
        assert np.all(uv[:, 1] < np.sum((c[3] - c[0]) ** 2))


def test_one_blender_serves_jobs_one_after_another_as_a_new_one_would(oracle, monkeypatch, tmp_path):
    """Renders run as jobs on one Blender process (run._Blender), each from Blender's empty factory
    settings: its passes are the pixels a process of one job writes, whatever ran before (the files' headers
    hold the date and the render time); a job that fails in Blender leaves it serving; one found dead idle
    is replaced."""
    jobs = []
    real = run.run_job
    monkeypatch.setattr(run, "run_job", lambda job, folder, t: jobs.append(dict(job)) or real(job, folder, t))
    for b in list(run._idle):
        b.close()
    spawned = []
    monkeypatch.setattr(run, "_Blender", lambda exe, _B=run._Blender: spawned.append(_B(exe)) or spawned[-1])
    scenes = [_scene("three_balls", 24), _scene("rules", 20), _scene("three_balls", 24)]
    first, _, again = (oracle.render(sc, oracle.adapt(resolve(sc))) for sc in scenes)
    assert len(spawned) == 1 and len(jobs) == 3
    assert np.array_equal(first.color, again.color) and np.array_equal(first.t, again.t, equal_nan=True)

    # the third job again, in a process of its own
    def into(stem: str) -> dict:
        return {
            **jobs[2],
            "renders": [{**r, "exr": str(tmp_path / f"{stem}{i}.exr")} for i, r in enumerate(jobs[2]["renders"])],
        }

    job, served = into("alone"), into("served")
    (tmp_path / "job.json").write_text(json.dumps(job))
    p = subprocess.run([str(run.blender_python()), str(run.SCRIPT), str(tmp_path / "job.json")], capture_output=True,
                       timeout=300)  # fmt: skip
    assert p.returncode == 0, p.stderr[-2000:]
    (tmp_path / "s").mkdir()
    real(served, tmp_path / "s", 300)
    w, h = jobs[2]["width"], jobs[2]["height"]
    for a, b in zip(job["renders"], served["renders"], strict=True):  # every pass's pixels (the headers hold
        alone, by_server = run.read_exr(Path(a["exr"]), w, h), run.read_exr(Path(b["exr"]), w, h)  # a date)
        assert alone.keys() == by_server.keys()
        assert all(np.array_equal(alone[k], by_server[k], equal_nan=True) for k in alone)
    # a job Blender cannot do: an error of one line, and the same process serves the next job
    (tmp_path / "bad").mkdir()
    with pytest.raises(run.CyclesError, match="Blender failed: KeyError: 'sample_offset'") as e:
        real({**served, "renders": [{"exr": str(tmp_path / "bad" / "x.exr")}]}, tmp_path / "bad", 300)
    assert "\n" not in str(e.value)
    assert len(run._idle) == 1 and run._idle[0] is spawned[0] and spawned[0].p.poll() is None
    # killed while idle: the next render starts another
    spawned[0].p.kill()
    spawned[0].p.wait()
    sc = _scene("three_balls", 24)
    assert np.array_equal(oracle.render(sc, oracle.adapt(resolve(sc))).color, first.color)
    assert len(spawned) == 2


def test_the_version_question_and_the_first_render_share_one_blender(oracle, monkeypatch):
    """Blender's version is asked of the process that then serves the first render: bpy imported once."""
    for b in list(run._idle):
        b.close()
    run._version.cache_clear()
    spawned = []
    monkeypatch.setattr(run, "_Blender", lambda exe, _B=run._Blender: spawned.append(_B(exe)) or spawned[-1])
    assert oracle.available() == (True, "Blender 5.0.1 (Cycles, CPU)")
    sc = _scene("three_balls", 16)
    assert oracle.render(sc, oracle.adapt(resolve(sc))).ok
    assert len(spawned) == 1


def test_a_sensor_render_started_ahead_is_the_one_rendered_in_line(monkeypatch):
    """A scene of samples > 1: the stochastic check's sensor render of a physical model that runs apart
    (Blender) starts with the reference (harness.compare.start_samples), not on the check's own thread;
    the stochastic check is the one a render in line gives."""
    from minirt.harness import compare
    from minirt.harness import run as run_module
    from minirt.harness.references import ReferenceCache

    path = ROOT / "scenes" / "soft.toml"
    scene = load_scene(path).with_overrides(width=32, height=32, samples=4)
    rules = resolve(scene)
    started = []
    monkeypatch.setattr(run_module, "start_samples", lambda *a: started.append(got := compare.start_samples(*a)) or got)
    sc = check_scene(path, ["reference", "cycles"], size=(32, 32), loaded=(scene, rules))
    assert list(started[0]) == ["cycles"]
    ahead = sc.backends["cycles"].checks["stochastic"]
    in_line = compare.check_backend(scene, rules, "cycles", ReferenceCache(scene)).checks["stochastic"]
    assert ahead.verdict == in_line.verdict and ahead.verdict in ("pass", "warn")
    assert ahead.figures == in_line.figures
