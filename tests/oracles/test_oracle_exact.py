"""The exact oracle (python-flint ball arithmetic): certified decisions on constructed tangent and tie cases,
the reference judged with zero tolerance on decisions, and a known-wrong reference caught.

The constructed scenes put the decisive quantity exactly at 0 in rational arithmetic on binary64 numbers
(an axis ray tangent to a ball, a plane through a ray's origin, a ball given twice), so what the oracle
must say is known without it; the reference's float64 answers there are whatever its rounding gives.
"""

from __future__ import annotations

import numpy as np
import pytest
from flint import fmpq
from support.exact_cases import FLOOR, TANGENT_BALL, exact_case

from minirt.campaign.campaign import DEFECTS, _DefectiveReference
from minirt.harness import backends, judge
from minirt.harness.backends import get
from minirt.harness.compare import check_backend
from minirt.harness.references import ReferenceCache
from minirt.model.bundled import find_scene
from minirt.model.result import edge_classes
from minirt.model.rules import PROFILES, Rules, resolve
from minirt.model.scene import load_scene
from minirt.oracles.exact import CHECK_WHOLE_PIXELS, WHOLE_IMAGE_PIXELS, choose_pixels, stratified
from minirt.oracles.exact.model import CULL_FROM
from minirt.oracles.exact.render import PRECISIONS, PixelTracer


def _scene(shapes: str, model: str = 'ray_origin = "camera"'):
    return exact_case(shapes, model)


def _exact(scene, rules=None, **options):
    res = get("exact").render(scene, rules or resolve(scene), options)
    assert res.ok, res.reason
    return res


def test_a_tangent_primary_ray_is_a_certified_hit():
    # pixel (2, 2)'s corner ray from the camera (0, 0, -1) runs along +z; the ball (1, 0, 5), r = 1 touches it
    # at (0, 0, 5): discriminant exactly 0, which counts as a hit at t = 6 -- decided exactly, no tie
    scene = _scene('[[shapes]]\ntype = "ball"\ncenter = [1.0, 0.0, 5.0]\nradius = 1.0\nmaterial = "m"')
    res = _exact(scene)
    assert res.hit[2, 2] and res.t[2, 2] == 6.0
    assert not res.aux["exact_tie"].any()
    assert res.aux["certified_bits"][2, 2] == PRECISIONS[0]
    assert not res.hit[2, 1]  # the pixel to its left: its ray bends away from the ball


def test_a_shadow_ray_exactly_tangent_to_a_ball_is_a_tie_not_a_guess():
    # pixel (2, 3) meets the floor y = -1 at (0, -1, 3) exactly; the light (0, 9, 3) straight above; the shadow
    # ray runs along +y and touches the ball (1, 4, 3), r = 1 at (0, 4, 3): an exact tangent, lit or not is the
    # sign of a discriminant that is exactly 0 -- undecidable in intervals at any precision: a tie
    floor, ball = FLOOR, TANGENT_BALL
    scene = _scene(f"{floor}\n{ball}", 'ray_origin = "camera"\noffset = 0.0')
    res = _exact(scene)
    assert res.shape_id[3, 2] == 0 and res.position[3, 2].tolist() == [0.0, -1.0, 3.0]
    assert res.aux["exact_tie"][3, 2] and res.aux["certified_bits"][3, 2] == PRECISIONS[-1]
    assert "ball 1" in res.meta["ties"][0]["decision"] and res.meta["ties"][0]["pixel"] == 14
    # moved by one binary64 step the shadow ray misses it, certified
    moved = _scene(f"{floor}\n{ball.replace('radius = 1.0', 'radius = 0.9999999999999999')}",
                   'ray_origin = "camera"\noffset = 0.0')  # fmt: skip
    got = _exact(moved)
    assert not got.aux["exact_tie"].any() and got.terms["diffuse"][3, 2].max() > 0


def _far_balls(n: int) -> str:
    """n small balls well away from every ray of the constructed cases (behind the camera)."""
    return "\n".join(
        f'[[shapes]]\ntype = "ball"\ncenter = [{x}.0, {y}.0, -40.0]\nradius = 0.5\nmaterial = "m"'
        for x, y in ((i % 5, i // 5) for i in range(n))
    )


def test_many_balls_keep_a_tangent_and_its_tie():
    # enough balls for the cull (CULL_FROM): the tangent ball (h = r exactly) is never culled, the tie stays
    assert CULL_FROM <= 12
    tangent = _scene(f"{FLOOR}\n{TANGENT_BALL}\n{_far_balls(12)}", 'ray_origin = "camera"\noffset = 0.0')
    res = _exact(tangent)
    assert res.aux["exact_tie"][3, 2] and "ball 1" in res.meta["ties"][0]["decision"]
    primary = _scene(
        f'[[shapes]]\ntype = "ball"\ncenter = [1.0, 0.0, 5.0]\nradius = 1.0\nmaterial = "m"\n{_far_balls(12)}'
    )
    got = _exact(primary)
    assert got.hit[2, 2] and got.t[2, 2] == 6.0 and not got.aux["exact_tie"].any()


@pytest.mark.parametrize(("profile", "groups"), [("exercise", False), ("conventional", False), ("exercise", True)])
def test_culling_balls_changes_no_bit_and_culls(profile, groups, monkeypatch):
    from minirt.campaign.generate import balls_scene
    from minirt.model.scene import parse_scene
    from minirt.oracles.exact import model

    if groups:  # the lines tested against groups of balls first (GROUP_FROM), groups of 4
        monkeypatch.setattr(model, "GROUP_FROM", 1)
        monkeypatch.setattr(model, "GROUP_SIZE", 4)
    scene = parse_scene(balls_scene(40, seed=3, width=10, height=10), "balls.toml").with_overrides(profile=profile)
    rules = resolve(scene)
    calls = []
    near = model.Model.near_balls

    def counted(self, o, w, keep=()):
        got = near(self, o, w, keep)
        calls.append(len(got))
        return got

    monkeypatch.setattr(model.Model, "near_balls", counted)
    culled = _exact(scene, rules)
    assert calls and sum(calls) < 0.25 * 40 * len(calls)  # most balls culled from most rays
    monkeypatch.setattr(model, "CULL_FROM", 10**9)
    monkeypatch.setattr(model, "PRIMARY_CULL_FROM", 10**9)
    every = _exact(scene, rules)
    for k in ("hit", "shape_id", "t", "position", "normal", "color"):
        assert np.array_equal(getattr(culled, k), getattr(every, k), equal_nan=True), k
    for k, v in every.aux.items():
        assert np.array_equal(culled.aux[k], v, equal_nan=True), k


@pytest.mark.parametrize(
    ("name", "rule"),
    [
        ("three_balls", {}),
        ("rules", {"ray_origin": "image-plane"}),
        ("shadows", {"pixel_shift": [0.5, -0.25], "pixel_sample": "center"}),
    ],
)
def test_the_primary_rays_cull_for_a_batch_changes_no_bit(name, rule, monkeypatch):
    # every primary ray of a batch tested against every ball at once (PRIMARY_CULL_FROM, from one ball): most
    # balls are culled from most rays, and every buffer -- robust bounds and radii included -- is the same as
    # with each ray testing every ball in ball arithmetic
    from minirt.oracles.exact import model
    from minirt.oracles.exact import render as exact_render

    scene = load_scene(find_scene(name)).with_overrides(width=24, height=20)
    rules = resolve(scene, overrides=rule)
    kept = []
    prepare = exact_render.PixelTracer.prepare

    def counted(self, indices, uv):
        prepare(self, indices, uv)
        kept.extend(len(v) for v in self._near.values())

    monkeypatch.setattr(exact_render.PixelTracer, "prepare", counted)
    culled = _exact(scene, rules)
    balls = sum(1 for s in scene.shapes if type(s).__name__ == "Ball")
    assert len(kept) == 24 * 20 and sum(kept) < 0.5 * balls * len(kept)
    monkeypatch.setattr(model, "PRIMARY_CULL_FROM", 10**9)
    every = _exact(scene, rules)
    for k in ("hit", "shape_id", "t", "position", "normal", "color"):
        assert np.array_equal(getattr(culled, k), getattr(every, k), equal_nan=True), k
    assert culled.aux.keys() == every.aux.keys()
    for k, v in every.aux.items():
        assert np.array_equal(culled.aux[k], v, equal_nan=True), k


def test_an_offset_of_zero_starts_on_the_surface_exactly():
    # the floor point's shadow ray starts on the floor itself (offset 0): its root t = 0 does not count, so the
    # point is lit -- certified (a computed origin would put the floor's own root at +-0 forever)
    scene = _scene('[[shapes]]\ntype = "plane"\nnormal = [0.0, 1.0, 0.0]\ndistance = -1.0\nmaterial = "m"',
                   'ray_origin = "camera"\noffset = 0.0')  # fmt: skip
    res = _exact(scene)
    assert not res.aux["exact_tie"].any()
    assert (res.terms["diffuse"][res.hit] > 0).all()


def test_a_ray_starting_on_a_plane_misses_it_exactly():
    # the plane y = 1/4 holds the image-plane origin of row 1 ((-y/4 + 1/2) = 1/4), whose rays leave it upwards:
    # t = 0 exactly, no hit -- decided at the first precision (an interval around the origin never would be)
    scene = _scene('[[shapes]]\ntype = "plane"\nnormal = [0.0, 1.0, 0.0]\ndistance = 0.25\nmaterial = "m"',
                   'ray_origin = "image-plane"')  # fmt: skip
    res = _exact(scene)
    assert not res.hit[1].any() and not res.aux["exact_tie"].any()
    assert (res.aux["certified_bits"][1] == PRECISIONS[0]).all()


def test_a_shape_given_twice_keeps_the_lower_id():
    ball = '[[shapes]]\ntype = "ball"\ncenter = [0.0, 0.0, 3.0]\nradius = 1.0\nmaterial = "m"'
    res = _exact(_scene(f"{ball}\n{ball}"))
    assert res.hit.any() and (res.shape_id[res.hit] == 0).all() and not res.aux["exact_tie"].any()


@pytest.mark.parametrize("profile", list(PROFILES))
def test_every_profile_passes_on_a_bundled_scene(profile):
    scene = load_scene(find_scene("three_balls")).with_overrides(width=24, height=24, profile=profile)
    rules = resolve(scene)
    bc = check_backend(scene, rules, "exact", ReferenceCache(scene), explain=False)
    assert bc.verdict == "pass", bc.reason
    geom = bc.checks["geometry"].figures
    assert geom["band_pixels"] < 0.05 * geom["pixels"]  # conclusive: nearly every pixel judged


def test_a_known_wrong_reference_is_caught():
    scene = load_scene(find_scene("shadows")).with_overrides(width=24, height=24)
    rules = resolve(scene)
    for name in ("no-shadows", "light-moved", "t-scaled"):
        bad = _DefectiveReference(scene, DEFECTS[name])
        bc = check_backend(scene, rules, "exact", bad, explain=False)
        assert bc.verdict == "fail", (name, bc.reason)


def test_a_check_of_a_large_image_traces_the_edges_and_a_sample_and_judges_only_those():
    # 96^2 > CHECK_WHOLE_PIXELS: the check asks for the reference's edges and the stratified sample
    scene = load_scene(find_scene("shadows")).with_overrides(width=96, height=96)
    rules = resolve(scene)
    refs = ReferenceCache(scene)
    ref = refs.get(rules, samples=1)
    edges = np.logical_or.reduce(list(edge_classes(ref).values()))
    assert CHECK_WHOLE_PIXELS < 96 * 96 and 0 < edges.sum() < 0.5 * edges.size
    bc = check_backend(scene, rules, "exact", refs)
    assert bc.verdict == "pass", bc.reason
    traced = bc.result.aux["rendered"]
    assert traced[edges].all() and not traced.all()  # every edge, not every pixel
    assert set(stratified(96, 96).tolist()) <= set(np.flatnonzero(traced).tolist())
    geom, shading = bc.checks["geometry"].figures, bc.checks["shading"].figures
    assert geom["traced_pixels"] == traced.sum() and geom["mask_mismatch"] == 0
    assert not geom["inconclusive"]["reasons"]  # judged on what it traced, not inconclusive for the rest
    assert 0 < shading["compared_pixels"] <= traced.sum() and shading["delta_e_max"] == 0.0
    assert "traced" in bc.rule_diagnosis.reason and not bc.rule_diagnosis.ran
    # and it can fail: a reference in the wrong on the traced pixels is caught
    bad = _DefectiveReference(scene, DEFECTS["no-shadows"])
    assert check_backend(scene, rules, "exact", bad, explain=False).verdict == "fail"


def test_a_checks_certified_render_runs_beside_the_others_with_the_same_result(monkeypatch):
    """Above CHECK_WHOLE_PIXELS a check renders the chosen pixels on a worker process per core, started once
    the reference is there and checked after the other oracles: the same buffers as in this process, the
    document's oracles in the order asked."""
    from minirt.harness.run import check_scene
    from minirt.jobs import batch
    from minirt.oracles.exact import render as exact_render

    monkeypatch.setattr(batch, "cores", lambda: 2)  # a worker process per core, also on a one-core runner
    path = find_scene("shadows")
    scene = load_scene(path).with_overrides(width=72, height=72)
    rules = resolve(scene)
    options = get("exact").check_options(scene, ReferenceCache(scene).get(rules, samples=1))
    assert options["workers"] == 2 and get("exact").runs_apart(options)
    started = []
    real = exact_render.trace_columns
    monkeypatch.setattr(exact_render, "trace_columns", lambda *a, **k: started.append(a[4]) or real(*a, **k))
    sc = check_scene(path, ["reference", "exact", "embree"], size=(72, 72))
    assert list(sc.backends) == ["exact", "embree"] and started == [2]
    here = backends.render("exact", scene, rules, {**options, "workers": 1})
    there = sc.backends["exact"].result
    for k in ("hit", "shape_id", "t", "normal", "color"):
        assert np.array_equal(getattr(here, k), getattr(there, k), equal_nan=True), k
    for k in ("rendered", "robust", "color_lo", "color_hi"):
        assert np.array_equal(here.aux[k], there.aux[k]), k
    assert sc.backends["exact"].verdict == "pass", sc.backends["exact"].reason


def test_a_several_sample_render_started_ahead_is_the_one_rendered_in_line(monkeypatch):
    """A scene of samples > 1: the check's several-sample render of an oracle that runs apart starts with
    the reference (harness.compare.start_samples); the samples check is the one a render in line gives."""
    from minirt.harness import compare
    from minirt.harness import run as run_module
    from minirt.jobs import batch

    monkeypatch.setattr(batch, "cores", lambda: 2)
    path = find_scene("shadows")
    scene = load_scene(path).with_overrides(width=72, height=72, samples=4)
    rules = resolve(scene)
    started = []
    monkeypatch.setattr(run_module, "start_samples", lambda *a: started.append(got := compare.start_samples(*a)) or got)
    sc = run_module.check_scene(path, ["reference", "exact"], size=(72, 72), loaded=(scene, rules))
    assert list(started[0]) == ["exact"]
    ahead = sc.backends["exact"].checks["samples"]
    in_line = check_backend(scene, rules, "exact", ReferenceCache(scene)).checks["samples"]
    assert ahead.verdict == in_line.verdict == "pass" and ahead.figures == in_line.figures


def test_a_check_of_a_small_image_traces_every_pixel():
    scene = load_scene(find_scene("shadows")).with_overrides(width=32, height=32)
    assert get("exact").check_options(scene, ReferenceCache(scene).get(resolve(scene), samples=1)) == {}


def test_rays_are_the_exercises_exact_ones_not_the_references():
    # a pixel shift and a sub-pixel position the reference rounds: the exact origin is (x + u + dx)/W - 1/2
    scene = load_scene(find_scene("three_balls")).with_overrides(width=3, height=3)
    rules = Rules(pixel_shift=(0.1, 0.0), pixel_sample="center")
    tracer = PixelTracer(scene, rules)
    fx, fy = tracer.position(4, 0.5, 0.5)
    m = tracer.model(PRECISIONS[0])
    o, _ = m.primary(fx, fy)

    assert o[0] == (fmpq(1) + fmpq(1, 2) + fmpq(3602879701896397, 2**55)) / 3 - fmpq(1, 2)


def test_pixels_chosen_for_large_images():
    scene = load_scene(find_scene("three_balls")).with_overrides(width=1024, height=1024)
    chosen = choose_pixels(scene, [5, 7])
    assert {5, 7} <= set(chosen.tolist()) and len(chosen) < 2 * 4096
    assert np.array_equal(stratified(1024, 1024), stratified(1024, 1024))  # deterministic
    small = load_scene(find_scene("three_balls")).with_overrides(width=64, height=64)
    assert len(choose_pixels(small, None)) == 64 * 64 <= WHOLE_IMAGE_PIXELS
    res = _exact(load_scene(find_scene("three_balls")).with_overrides(width=16, height=16), pixels=[3, 200])
    assert res.aux["rendered"].sum() == 2


@pytest.mark.parametrize("options", [{"pixels": "some"}, {"pixels": [-1]}, {"samples": 0}, {"colour": 1}])
def test_bad_options_are_an_error_result(options):
    scene = load_scene(find_scene("three_balls")).with_overrides(width=8, height=8)
    res = get("exact").render(scene, resolve(scene), options)
    assert res.status == "error" and res.reason


def test_found_by_capability_not_by_name():
    certified = [n for n in backends.oracle_names() if getattr(backends.get(n), "certified", False)]
    assert certified == ["exact"]


def test_several_samples_take_the_references_own_sub_pixel_positions():
    scene = load_scene(find_scene("three_balls")).with_overrides(width=12, height=12, samples=4)
    rules = resolve(scene)
    res = _exact(scene, rules, samples=4)
    ref = backends.render("reference", scene, rules)
    assert res.meta["settings"]["samples_cast"] == 4 and not res.aux["exact_tie"].any()
    # the same rays (binary64 sub-pixel offsets, taken exactly), so the same mean colour to float64's rounding
    assert np.abs(res.aux["color_exact"] - ref.color).max() < 1e-12
    one = _exact(scene, rules)
    assert np.abs(one.aux["color_exact"] - ref.color).max() > 1e-3  # one ray per pixel is another picture
    # robust bounds are of one ray: the mean of four has none, so the judge settles nothing on it
    assert one.aux["robust"].any() and not res.aux["robust"].any()
    assert judge.reference_errors(ref, res)[0].sum() == 0


def _tangent_shadow_rays():
    """The tangent shadow ray's case (a tie at pixel 14), every pixel at the corner, the centre, the corner
    again and (0.25, 0.75): its scene, rules, pixel count, and the rays' pixel indices and sub-pixel positions."""
    scene = _scene(f"{FLOOR}\n{TANGENT_BALL}", 'ray_origin = "camera"\noffset = 0.0')
    n = scene.camera.width * scene.camera.height
    uv = np.repeat([[0.0, 0.0], [0.5, 0.5], [0.0, 0.0], [0.25, 0.75]], n, axis=0)
    return scene, resolve(scene), n, np.tile(np.arange(n), 4), uv


@pytest.mark.parametrize("workers", [1, 2])
def test_colours_alone_are_the_pixels_colours_ties_and_precisions(workers):
    """The later samples of a several-sample render are traced as colours alone (render.trace_colours): the
    colour, precision and tie of each ray as trace_pixels has them, in the order given, pixels repeated --
    here every pixel of the tangent shadow ray's case at the corner and at the centre, twice, a tie among them."""
    from minirt.oracles.exact import render as exact_render

    scene, rules, n, idx, uv = _tangent_shadow_rays()
    got = exact_render.trace_colours(scene, rules, idx, uv, workers)
    tracer = exact_render.PixelTracer(scene, rules)
    want = [tracer.pixel(int(i), u, v, False) for i, (u, v) in zip(idx, uv, strict=True)]
    assert got.color.tolist() == [list(px.color) for px in want]
    assert got.bits.tolist() == [px.bits for px in want]
    assert got.ties == {k: px.tie for k, px in enumerate(want) if px.tie}
    assert list(got.ties) == [14, 2 * n + 14]


@pytest.mark.parametrize("workers", [1, 2])
def test_pixels_as_columns_are_the_pixels_values(workers):
    """A check's render reads its pixels as columns (render.Pixels: a worker's answer is a few arrays, not a
    Pixel object a pixel): each column holds the Pixels' values in the order given, bounds and a tie among
    them -- the tangent shadow ray's case, every pixel at two sub-pixel positions, twice."""
    from minirt.oracles.exact import render as exact_render

    scene, rules, n, idx, uv = _tangent_shadow_rays()
    got = exact_render.trace_columns(scene, rules, idx, uv, workers)
    want = exact_render.trace_pixels(scene, rules, idx, uv)
    for name in ("index", "shape_id", "t", "position", "normal", "color", "color_rad", "t_rel", "bits", "robust",
                 "robust_geometry", "t_bounds"):  # fmt: skip
        assert np.array_equal(getattr(got, name), np.array([getattr(px, name) for px in want]), equal_nan=True), name
    assert np.array_equal(got.color_lo, [px.color_bounds[0] for px in want])
    assert np.array_equal(got.normal_hi, [px.normal_bounds[1] for px in want])
    for k, col in got.terms.items():
        assert np.array_equal(col, [px.terms.get(k, (0.0, 0.0, 0.0)) for px in want]), k
    assert got.ties == {k: px.tie for k, px in enumerate(want) if px.tie} and list(got.ties) == [14, 2 * n + 14]
    assert got.robust.any() and got.terms["diffuse"].any()


def test_buffers_from_columns_are_the_buffers_from_pixels():
    """``buffers`` from a worker pool's columns and from this process's Pixel objects: the same arrays, bit for bit."""
    from minirt.oracles.exact import render as exact_render

    scene = load_scene(find_scene("three_balls")).with_overrides(width=16, height=12)
    rules = resolve(scene)
    idx = np.arange(0, 16 * 12, 2)
    uv = np.full((idx.size, 2), 0.5)
    a = exact_render.buffers(16, 12, exact_render.trace_pixels(scene, rules, idx, uv))
    b = exact_render.buffers(16, 12, exact_render.trace_columns(scene, rules, idx, uv, workers=2))
    assert set(a) == set(b) and set(a["terms"]) == set(b["terms"]) and {"reflection", "specular"} <= set(a["terms"])
    for k in a:
        for x, y in ((a[k], b[k]),) if k != "terms" else ((a[k][t], b[k][t]) for t in a[k]):
            assert x.dtype == y.dtype and np.array_equal(x, y, equal_nan=True), k
    assert a["rendered"].sum() == idx.size


def test_a_several_sample_render_is_the_mean_of_its_samples_pixels():
    """Its colour is the mean of each sample's Pixels, summed in sample order (bit for bit), its ties and
    certified precisions those of every sample, on worker processes as in this one."""
    from minirt.model import camera
    from minirt.oracles.exact import render as exact_render

    scene = load_scene(find_scene("three_balls")).with_overrides(width=12, height=12, samples=4)
    rules = resolve(scene)
    pixels = np.arange(144)
    total, bits = 0, np.zeros(144, dtype=np.int32)
    for s in range(4):
        u, v = camera.sample_offsets(4, s, 144)
        pxs = exact_render.trace_pixels(scene, rules, pixels, np.stack([u, v], axis=1), bounds=False)
        total = total + exact_render.buffers(12, 12, pxs)["color"]
        bits = np.maximum(bits, [px.bits for px in pxs])
    for workers in (1, 2):
        res = _exact(scene, rules, samples=4, pixels="all", workers=workers)
        assert np.array_equal(res.aux["color_exact"], total / 4)
        assert np.array_equal(res.aux["certified_bits"].reshape(-1), bits)
        assert res.meta["certified"]["pixels"] == 144 and res.meta["certified"]["bits"] == {"128": 576}


def test_worker_processes_that_die_are_an_error_result_and_are_started_again(monkeypatch):
    from minirt.oracles.exact import render as exact_render

    scene = load_scene(find_scene("three_balls")).with_overrides(width=12, height=12)
    rules = resolve(scene)
    here = backends.render("exact", scene, rules, {"pixels": "all"})
    pool = exact_render._pool(2)
    for p in pool.procs:  # dying while the render runs (seen only when it answers no more)
        p.kill()
        p.wait()
    with monkeypatch.context() as m:
        m.setattr(exact_render.Workers, "alive", lambda self: True)
        res = backends.render("exact", scene, rules, {"pixels": "all", "workers": 2})
    assert res.status == "error" and "worker process of the certified oracle died" in res.reason, res.reason
    again = backends.render("exact", scene, rules, {"pixels": "all", "workers": 2})  # a new pool
    assert exact_render._pool(2) is not pool and again.ok, again.reason
    assert np.array_equal(again.color, here.color) and np.array_equal(again.aux["color_hi"], here.aux["color_hi"])


def test_a_script_without_a_main_guard_runs_once(tmp_path):
    """The workers are fresh interpreters, not multiprocessing children (which import the caller's main
    script again): a user's script calling the API runs once, whatever it lacks."""
    import subprocess
    import sys

    script = tmp_path / "use.py"
    script.write_text(
        "from minirt.harness import backends\n"
        "from minirt.model.bundled import bundled_scene\n"
        "from minirt.model.rules import resolve\n"
        "scene = bundled_scene('three_balls').with_overrides(width=10, height=10)\n"
        "res = backends.render('exact', scene, resolve(scene), {'pixels': 'all', 'workers': 2})\n"
        "print('ran', res.status)\n"
    )
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120)
    assert out.stdout.splitlines() == ["ran ok"], out.stdout + out.stderr


def test_two_scenes_taking_turns_keep_their_tracers(monkeypatch):
    """A check renders the next scene beside this one (minirt.harness.run), their batches taking turns on a
    worker: each scene's tracer is built once, not once a turn."""
    from minirt.oracles.exact import render as exact_render

    built = []
    real = exact_render.PixelTracer
    monkeypatch.setattr(exact_render, "PixelTracer", lambda *a: built.append(a[0].name) or real(*a))
    monkeypatch.setattr(exact_render, "_KEPT", {})
    a, b = (load_scene(find_scene(n)).with_overrides(width=8, height=8) for n in ("shadows", "matte"))
    for _ in range(3):
        for sc in (a, b):
            assert exact_render.tracer_for(sc, resolve(sc)).scene == sc
    assert built == ["shadows", "matte"]
