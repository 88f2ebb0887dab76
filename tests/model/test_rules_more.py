"""The newer rules: specular_exponent, clamp "specular", background "none", offset_along, pixel_shift,
the output rules and profile eth2014.

The fast tracer against tests/support/plain.py for every candidate value (rules.values) of every newer trace
rule, on every bundled scene, from every profile; pixel_shift's rays (bit-identical between NumPy and
Dr.Jit, one and many samples); validation messages; format_rule_value round trips through the CLI's
parsing; flipped and adapt always give valid rules; the course's 2014 test (b).
"""

from __future__ import annotations

import math
import subprocess
import sys
from dataclasses import fields, replace

import drjit as dr
import numpy as np
import pytest
from support.plain import Plain
from support.scenes import ball, material, scene_text
from support.versus_plain import SIZE, _compare

from minirt.cli.options import parse_rules as _parse_rules
from minirt.errors import MinirtError
from minirt.model import camera
from minirt.model.effects import effects
from minirt.model.rules import (
    CHOICES,
    OUTPUT_RULES,
    PROFILES,
    TRACE_RULES,
    Rules,
    flipped,
    format_rule_value,
    resolve,
    validate_model_table,
    values,
)
from minirt.model.scene import load_scene, parse_scene
from minirt.reference.shading import _power
from minirt.reference.tracer import Tracer

NEW_TRACE_RULES = ("background", "clamp", "offset", "offset_along", "specular_exponent", "pixel_shift")


def _with(rules: Rules, name: str, value) -> Rules:
    """rules with one rule set, kept valid: "ray" needs a numeric offset."""
    out = replace(rules, **{name: value})
    if out.offset_along == "ray" and out.offset == "error-bound":
        out = replace(out, offset_along="normal") if name == "offset" else replace(out, offset=1e-3)
    return out


def _valid(rules: Rules, profile: str = "exercise") -> list[str]:
    return validate_model_table(profile, rules.as_dict())


CASES = [(name, v) for name in NEW_TRACE_RULES for v in values(name)]
# offset 0: a secondary ray starts exactly on its surface and whether it re-hits it is decided by the last
# bit of t, where the two legitimately differ (Dr.Jit's dot products fuse multiply-adds, Python's do not).
PLAIN_CASES = [(n, v) for n, v in CASES if (n, v) != ("offset", 0.0)]


# ---- the tracer against the plain transcription ------------------------------------------------
@pytest.mark.parametrize("profile", list(PROFILES))
@pytest.mark.parametrize(("rule", "value"), PLAIN_CASES, ids=[f"{n}={format_rule_value(n, v)}" for n, v in PLAIN_CASES])
def test_every_value_agrees_with_plain(scene_path, profile, rule, value):
    scene = load_scene(scene_path).with_overrides(width=SIZE, height=SIZE, samples=1)
    rules = _with(PROFILES[profile], rule, value)
    assert _valid(rules) == []
    _compare(scene, rules)


def test_every_new_value_changes_the_rules_scene():
    """scenes/rules.toml shows every newer trace rule: each candidate value changes the exercise's picture."""
    scene = load_scene("scenes/rules.toml").with_overrides(width=48, height=48)
    base_rules = PROFILES["exercise"]
    base = Tracer(scene, base_rules).render().color
    same = []
    for name, v in CASES:
        rules = _with(base_rules, name, v)
        if rules != base_rules and np.array_equal(base, Tracer(scene, rules).render().color):
            same.append(f"{name}={v}")
    assert same == []


@pytest.mark.parametrize("scene_name", ["rules", "three_balls"])
def test_pruning_stays_bit_identical(scene_name):
    scene = load_scene(f"scenes/{scene_name}.toml").with_overrides(width=24, height=24)
    for profile in PROFILES:
        for name, v in CASES:
            rules = _with(PROFILES[profile], name, v)
            a, b = Tracer(scene, rules, prune=True).render(), Tracer(scene, rules, prune=False).render()
            assert a.color.tobytes() == b.color.tobytes(), (profile, name, v)
            for k in a.terms:
                assert a.terms[k].tobytes() == b.terms[k].tobytes(), (profile, name, v, k)


def test_background_none_is_not_simulated():
    scene = load_scene("scenes/exercise.toml")
    assert effects(scene, PROFILES["exercise"]).background
    assert not effects(scene, replace(PROFILES["exercise"], background="none")).background
    r = Tracer(scene.with_overrides(width=16, height=16), PROFILES["eth2014"]).render()
    assert "background" in r.meta["effects"]["skipped"]
    assert not r.terms["background"].any()


def test_clamp_specular_terms():
    """clamp "specular": the diffuse term is s·n raw (negative on the dark side), specular only where r·s > 0."""
    scene = load_scene("scenes/rules.toml").with_overrides(width=32, height=32)
    base = PROFILES["eth2014"]  # its offset along the ray lets the wall seen from behind be lit
    raw = Tracer(scene, replace(base, clamp=False)).render()
    spec = Tracer(scene, base).render()
    clamped = Tracer(scene, replace(base, clamp=True)).render()
    assert np.array_equal(raw.terms["diffuse"], spec.terms["diffuse"])
    assert (spec.terms["diffuse"] < 0).any() and not (clamped.terms["diffuse"] < 0).any()
    assert (spec.terms["specular"] <= raw.terms["specular"]).all()
    assert (spec.terms["specular"] < raw.terms["specular"]).any()


# ---- specular_exponent ---------------------------------------------------------------------------
def test_power_is_square_and_multiply():
    F = dr.llvm.Float64
    x = F(np.linspace(-1.0, 1.0, 101))
    xs = np.asarray(x)
    x2 = np.asarray(x * x)
    x4 = x2 * x2
    assert np.asarray(_power(x, 8)).tobytes() == (x4 * x4).tobytes()  # today's (r·s)^8, bit for bit
    assert np.asarray(_power(x, 16)).tobytes() == ((x4 * x4) * (x4 * x4)).tobytes()
    assert np.asarray(_power(x, 1)).tobytes() == xs.tobytes()
    for e in (2, 3, 5, 7, 13, 100, 1023, 1024):
        np.testing.assert_allclose(np.asarray(_power(x, e)), xs**e, rtol=1e-12, atol=1e-300)


# ---- pixel_shift ---------------------------------------------------------------------------------
SHIFTS = [s for s in values("pixel_shift") if s != (0.0, 0.0)] + [(0.25, -3.5)]


@pytest.mark.parametrize("pixel_sample", ["corner", "center"])
@pytest.mark.parametrize("shift", SHIFTS)
def test_shifted_rays_are_bit_identical_numpy_and_drjit(shift, pixel_sample):
    scene = load_scene("scenes/exercise.toml").with_overrides(width=13, height=7)
    for origin in ("image-plane", "camera"):
        rules = replace(PROFILES["exercise"], pixel_shift=shift, pixel_sample=pixel_sample, ray_origin=origin)
        tr = Tracer(scene, rules)
        o, d = tr.primary_rays()
        o_np, d_np = camera.primary_rays(scene, rules)
        assert tr.to_numpy3(o).tobytes() == o_np.tobytes()
        assert tr.to_numpy3(d).tobytes() == d_np.tobytes()
        # several samples per pixel: the same sub-pixel offsets through both
        u, v = camera.sample_offsets(4, 1, 13 * 7)
        o, d = tr.sample_rays(u, v)
        o_np, d_np = camera.rays_through(scene, rules, u, v)
        assert tr.to_numpy3(o).tobytes() == o_np.tobytes()
        assert tr.to_numpy3(d).tobytes() == d_np.tobytes()


@pytest.mark.parametrize("pixel_sample", ["corner", "center"])
def test_whole_pixel_shift_is_the_neighbours_ray(pixel_sample):
    """A shift by (1, 0) gives pixel x the unshifted ray of pixel x + 1, exactly; (0, 1) the row below's."""
    w, h = 9, 5
    scene = load_scene("scenes/exercise.toml").with_overrides(width=w, height=h)
    base = replace(PROFILES["exercise"], pixel_sample=pixel_sample)
    _, d0 = camera.primary_rays(scene, base)
    d0 = d0.reshape(h, w, 3)
    _, dx = camera.primary_rays(scene, replace(base, pixel_shift=(1.0, 0.0)))
    _, dy = camera.primary_rays(scene, replace(base, pixel_shift=(0.0, 1.0)))
    assert dx.reshape(h, w, 3)[:, :-1].tobytes() == d0[:, 1:].tobytes()
    assert dy.reshape(h, w, 3)[:-1].tobytes() == d0[1:].tobytes()


def test_shifted_samples_render():
    """samples > 1 with a shift: the mean image moves with the grid (and differs from the unshifted one)."""
    scene = load_scene("scenes/soft.toml").with_overrides(width=16, height=16, samples=4)
    a = Tracer(scene, PROFILES["exercise"]).render()
    b = Tracer(scene, replace(PROFILES["exercise"], pixel_shift=(0.5, 0.5))).render()
    assert not np.array_equal(a.color, b.color)
    assert np.isfinite(b.color).all()


def test_zero_shift_is_the_default_bit_for_bit():
    scene = load_scene("scenes/three_balls.toml").with_overrides(width=32, height=32)
    rules = resolve(scene, overrides={"pixel_shift": "-0,0"})
    assert rules.pixel_shift == (0.0, 0.0) and math.copysign(1, rules.pixel_shift[0]) == 1
    assert rules == resolve(scene)
    a, b = Tracer(scene, rules).render(), Tracer(scene, resolve(scene)).render()
    assert a.color.tobytes() == b.color.tobytes()


# ---- the 2014 edition --------------------------------------------------------------------------
SCENE_B = scene_text(ball((0.0, 0.0, 0.0), 1.0), distance=3.0, materials={"m": material(1.0)})


@pytest.mark.parametrize("precision", ["f64", "f32"])
def test_eth2014_problem_b(precision):
    """The 2014 edition's test (b): ball (0,0,0) radius 1, ray from (0,0,-3) along +z: t = 2."""
    scene = parse_scene(SCENE_B)
    rules = PROFILES["eth2014"]
    tr = Tracer(scene, rules, precision=precision)
    o, d = tr.load(np.array([[0.0, 0.0, -3.0]])), tr.load(np.array([[0.0, 0.0, 1.0]]))
    assert float(np.asarray(tr.intersect(scene.shapes[0], o, d))[0]) == 2.0
    ids, t = tr.closest(o, d)
    assert int(np.asarray(ids)[0]) == 0 and float(np.asarray(t)[0]) == 2.0
    assert Plain(scene, rules).intersect(scene.shapes[0], (0.0, 0.0, -3.0), (0.0, 0.0, 1.0)) == 2.0
    # from inside (no near-root-only rule in 2014): the far root
    o_in = tr.load(np.array([[0.0, 0.0, 0.0]]))
    assert float(np.asarray(tr.intersect(scene.shapes[0], o_in, d))[0]) == 1.0


def test_eth2014_profile():
    r = PROFILES["eth2014"]
    assert (r.background, r.near_root_only, r.shadow_range, r.two_sided, r.clamp) == (
        "none",
        False,
        "to-light",
        False,
        "specular",
    )
    assert (r.offset, r.offset_along, r.ray_origin, r.pixel_sample, r.specular_exponent) == (
        1e-3,
        "ray",
        "camera",
        "center",
        16,
    )
    assert r.encoding == "floor256" and r.pixel_shift == (0.0, 0.0)
    assert _valid(r, "eth2014") == []
    # pixel centres ((2x+1-W)/(2W), (H-2y-1)/(2H), 0), rays from the camera
    scene = load_scene("scenes/exercise.toml").with_overrides(width=4, height=3)
    o, d = camera.primary_rays(scene, r)
    dist = scene.camera.distance
    assert np.all(o == [0.0, 0.0, -dist])
    for y in range(3):
        for x in range(4):
            p = np.array([(2 * x + 1 - 4) / 8, (3 - 2 * y - 1) / 6, dist])
            np.testing.assert_allclose(d[y * 4 + x], p / np.linalg.norm(p), rtol=0, atol=1e-15)


# ---- rule sets: output rules, traced(), flipped, values ------------------------------------------
def test_trace_and_output_rules_partition_the_fields():
    names = [f.name for f in fields(Rules)]
    assert sorted(TRACE_RULES + OUTPUT_RULES) == sorted(names)
    assert not set(TRACE_RULES) & set(OUTPUT_RULES)
    assert set(CHOICES) == set(names)


def test_output_rules_do_not_change_the_render():
    scene = load_scene("scenes/exercise.toml").with_overrides(width=16, height=16)
    out = Rules(encoding="floor", gamma="srgb", rows="bottom-up", channels="bgr", transpose=True)
    assert out.traced() == Rules()
    assert PROFILES["eth2014"].traced() == replace(PROFILES["eth2014"], encoding="round")
    assert hash(out.traced()) == hash(Rules())
    a, b = Tracer(scene, Rules()).render(), Tracer(scene, out).render()
    assert a.color.tobytes() == b.color.tobytes()


@pytest.mark.parametrize("profile", list(PROFILES))
@pytest.mark.parametrize("name", list(CHOICES))
def test_flipped_changes_the_rule_and_stays_valid(profile, name):
    base = PROFILES[profile]
    f = flipped(base, name)
    assert getattr(f, name) != getattr(base, name) or type(getattr(f, name)) is not type(getattr(base, name))
    assert name in base.differs(f)
    assert _valid(f) == []
    assert flipped(base, name) == f  # deterministic
    extra = set(base.differs(f)) - {name}
    assert extra <= {"offset"} and (not extra or (name == "offset_along" and base.offset == "error-bound"))


@pytest.mark.parametrize("name", list(CHOICES))
def test_values_are_valid_and_include_the_default(name):
    vals = values(name)
    assert len(vals) >= 2
    for v in vals:
        assert validate_model_table("exercise", {name: v} | ({"offset": 1e-3} if v == "ray" else {})) == []
    assert getattr(Rules(), name) in vals
    for p in PROFILES.values():
        assert getattr(p, name) in vals


@pytest.mark.parametrize("name", list(CHOICES))
def test_format_rule_value_round_trips(name):
    scene = load_scene("scenes/exercise.toml")
    for v in values(name):
        text = format_rule_value(name, v)
        parsed = _parse_rules([f"{name}={text}"])
        overrides = parsed | ({"offset": 1e-3} if v == "ray" else {})
        rules = resolve(scene, "exercise", overrides)
        got = getattr(rules, name)
        assert got == v and type(got) is type(v), (name, v, text, got)


def test_format_rule_value_forms():
    assert format_rule_value("near_root_only", True) == "true"
    assert format_rule_value("offset", 1e-6) == "1e-06"
    assert format_rule_value("specular_exponent", 16) == "16"
    assert format_rule_value("pixel_shift", (1.0, 0.0)) == "1,0"
    assert format_rule_value("pixel_shift", (0.5, -0.5)) == "0.5,-0.5"
    assert format_rule_value("pixel_shift", (0.1234567, 0.0)) == "0.1234567,0"  # :g would lose digits
    assert format_rule_value("clamp", "specular") == "specular"
    assert format_rule_value("gamma", "2.2") == "2.2"


# ---- validation ----------------------------------------------------------------------------------
BAD = [
    ("specular_exponent", 2.5, "model.specular_exponent: must be an integer from 1 to 1024, got 2.5"),
    ("specular_exponent", 0, "model.specular_exponent: must be an integer from 1 to 1024, got 0"),
    ("specular_exponent", 2048, "model.specular_exponent: must be an integer from 1 to 1024, got 2048"),
    ("specular_exponent", True, "model.specular_exponent: must be an integer from 1 to 1024, got True"),
    ("specular_exponent", "8", "model.specular_exponent: must be an integer from 1 to 1024, got '8'"),
    ("specular_exponent", math.inf, "model.specular_exponent: must be an integer from 1 to 1024, got inf"),
    ("clamp", "yes", "model.clamp: must be one of true, false, 'specular', got 'yes'"),
    ("clamp", 1.0, "model.clamp: must be one of true, false, 'specular', got 1.0"),
    ("background", "never", "model.background: must be one of 'on-hit', 'on-miss', 'none', got 'never'"),
    ("offset_along", "tangent", "model.offset_along: must be one of 'normal', 'ray', got 'tangent'"),
    ("pixel_shift", 1.0, 'model.pixel_shift: must be two numbers, [dx, dy] or "dx,dy" (pixels), got 1.0'),
    ("pixel_shift", "1;0", "model.pixel_shift: must be two numbers, [dx, dy] or \"dx,dy\" (pixels), got '1;0'"),
    ("pixel_shift", [1, 2, 3], 'model.pixel_shift: must be two numbers, [dx, dy] or "dx,dy" (pixels), got [1, 2, 3]'),
    ("pixel_shift", [True, 0], 'model.pixel_shift: must be two numbers, [dx, dy] or "dx,dy" (pixels), got [True, 0]'),
    ("pixel_shift", "5,0", "model.pixel_shift: each part must be a finite number from -4 to 4, got '5,0'"),
    ("pixel_shift", "nan,0", "model.pixel_shift: each part must be a finite number from -4 to 4, got 'nan,0'"),
    ("encoding", "ceil", "model.encoding: must be one of 'round', 'floor256', 'floor', got 'ceil'"),
    ("gamma", 2.4, "model.gamma: must be one of 'linear', 'srgb', '2.2', got 2.4"),
    ("rows", "up", "model.rows: must be one of 'top-down', 'bottom-up', got 'up'"),
    ("channels", "rgba", "model.channels: must be one of 'rgb', 'bgr', got 'rgba'"),
    ("transpose", "no", "model.transpose: must be true or false, got 'no'"),
]


@pytest.mark.parametrize(("name", "value", "message"), BAD, ids=[f"{n}={v!r}" for n, v, _ in BAD])
def test_bad_values_one_line_each(name, value, message):
    assert validate_model_table("exercise", {name: value}) == [message]


def test_offset_along_ray_needs_a_number():
    msg = 'model.offset_along: "ray" needs a numeric offset, got offset = "error-bound"'
    assert validate_model_table("conventional", {"offset_along": "ray"}) == [msg]
    assert validate_model_table("eth2014", {"offset": "error-bound"}) == [msg]
    assert validate_model_table("exercise", {"offset_along": "ray"}) == []
    scene = load_scene("scenes/exercise.toml")
    with pytest.raises(MinirtError, match="needs a numeric offset"):
        resolve(scene, "conventional", {"offset_along": "ray"})


def test_scene_model_table_forms():
    text = SCENE_B + '[model]\npixel_shift = [1, -0.5]\nspecular_exponent = 16\nclamp = "specular"\ngamma = 2.2\n'
    rules = resolve(parse_scene(text))
    assert rules.pixel_shift == (1.0, -0.5) and rules.specular_exponent == 16 and rules.clamp == "specular"
    assert rules.gamma == "2.2"
    assert type(rules.specular_exponent) is int
    with pytest.raises(MinirtError, match="pixel_shift"):
        parse_scene(SCENE_B + "[model]\npixel_shift = 1\n")


def test_rules_the_tracer_tolerates():
    """Attribution swaps single rules, so the tracer may see offset_along "ray" with "error-bound"
    (which validation rejects): the error-bound offset is along the normal then, as without the rule."""
    scene = load_scene("scenes/three_balls.toml").with_overrides(width=16, height=16)
    conv = PROFILES["conventional"]
    a = Tracer(scene, conv).render()
    b = Tracer(scene, replace(conv, offset_along="ray")).render()
    assert a.color.tobytes() == b.color.tobytes()


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "minirt", *args], capture_output=True, text=True, timeout=300)


def test_cli_rejects_bad_rule_values(tmp_path):
    p = _cli("render", "scenes/exercise.toml", "--rule", "specular_exponent=2.5", "--out", str(tmp_path))
    assert p.returncode == 2
    assert "model.specular_exponent: must be an integer from 1 to 1024, got 2.5" in p.stderr
    assert "Traceback" not in p.stderr
    p = _cli("render", "scenes/exercise.toml", "--rule", "pixel_shift=1", "--out", str(tmp_path))
    assert p.returncode == 2 and "model.pixel_shift: must be two numbers" in p.stderr
    p = _cli("render", "scenes/exercise.toml", "--profile", "conventional", "--rule", "offset_along=ray")
    assert p.returncode == 2 and '"ray" needs a numeric offset' in p.stderr
    assert not list(tmp_path.iterdir())


def test_cli_accepts_new_rules(tmp_path):
    import json

    args = ["--rule", "pixel_shift=1,0", "--rule", "specular_exponent=16", "--rule", "clamp=specular"]
    p = _cli("render", "scenes/exercise.toml", "--width", "8", "--height", "8", *args, "--out", str(tmp_path))
    assert p.returncode == 0, p.stderr
    meta = json.loads(next(tmp_path.glob("*.json")).read_text())
    assert meta["rules"]["pixel_shift"] == [1.0, 0.0]
    assert meta["rules"]["specular_exponent"] == 16 and meta["rules"]["clamp"] == "specular"


# ---- oracles: what they declare is valid ---------------------------------------------------------
def test_oracle_tables_are_valid():
    from minirt.oracles.embree import EmbreeOracle
    from minirt.oracles.mitsuba import MitsubaOracle
    from minirt.oracles.povray import PovrayOracle

    for cls in (PovrayOracle, MitsubaOracle, EmbreeOracle):
        o = cls()
        for name, vals in o.supported.items():
            assert name in TRACE_RULES, (cls.name, name)
            for v in vals:
                assert validate_model_table("exercise", {name: v} | ({"offset": 1e-3} if v == "ray" else {})) == []
        for profile, rules in PROFILES.items():
            assert _valid(o.adapt(rules), profile) == [], (cls.name, profile)
            for name in CHOICES:
                assert _valid(o.adapt(flipped(rules, name)), profile) == [], (cls.name, profile, name)


@pytest.mark.parametrize("shift", [(2.0, -1.0), (0.5, 0.5)])
def test_mitsuba_sensor_follows_pixel_shift(shift):
    """Mitsuba's own sensor (not minirt.model.camera's rays) takes the shift through its principal point."""
    from minirt.oracles.mitsuba import MitsubaOracle

    o = MitsubaOracle()
    ok, why = o.available()
    if not ok:
        pytest.skip(why)
    scene = load_scene("scenes/three_balls.toml").with_overrides(width=48, height=48, samples=1)
    rules = o.adapt(replace(PROFILES["conventional"], pixel_shift=shift))
    ref = Tracer(scene, rules).render()
    unshifted = Tracer(scene, replace(rules, pixel_shift=(0.0, 0.0))).render()
    got = o.render(scene, rules, {"mode": "sensor"})
    assert got.status == "ok", got.reason
    assert (got.hit != ref.hit).sum() == 0
    assert (got.hit != unshifted.hit).sum() > 0  # the check can see a shift


@pytest.mark.parametrize("profile", ["exercise", "eth2014"])
def test_runtime_exponent_same_bits(profile):
    """The diagnosis's renders read the exponent at run time (one kernel for every exponent): the same
    bits as the exponent compiled in, for exponents with one bit, several bits, and the largest."""
    from minirt.reference.tracer import Tracer

    scene = load_scene("scenes/rules.toml").with_overrides(width=32, height=32, samples=1)
    for e in (1, 5, 8, 12, 16, 777, 1024):
        rules = replace(PROFILES[profile], specular_exponent=e)
        a = Tracer(scene, rules, runtime=False).render().color
        b = Tracer(scene, rules, runtime=True).render().color
        assert np.array_equal(a.view(np.uint64), b.view(np.uint64)), e


RUNTIME_RULES = [
    {"pixel_sample": "center"},
    {"pixel_shift": (0.5, -0.25)},
    {"pixel_shift": (0.0, 1.0)},
    {"ray_origin": "camera"},
    {"near_root_only": False},
    {"near_root_only": True},
    {"two_sided": True},
    {"clamp": True},
    {"clamp": False},
    {"clamp": "specular"},
    {"offset": 0.0},
    {"offset": 1e-3},
    {"offset_along": "ray"},
    {"offset": "error-bound", "offset_along": "normal"},
]


@pytest.mark.parametrize("precision", ["f64", "f32"])
@pytest.mark.parametrize("profile", ["exercise", "conventional"])
def test_runtime_rules_same_bits(profile, precision):
    """Under ``runtime`` the camera rules and near_root_only, two_sided, clamp, a numeric offset and
    offset_along are values the kernel reads: every buffer -- the diagnosis's (colour, terms, the ray
    tree's decisions) and the check's (geometry, shadow margins) -- has the same bits as with the rule
    compiled in."""
    from minirt.reference.tracer import Tracer

    scene = load_scene("scenes/rules.toml").with_overrides(width=40, height=32, samples=1)
    for change in RUNTIME_RULES:
        rules = replace(PROFILES[profile], **change)
        a = Tracer(scene, rules, precision=precision, runtime=False).render(diagnostics=True)
        b = Tracer(scene, rules, precision=precision, runtime=True).render(diagnostics=True)
        for f in ("color", "hit", "shape_id", "t", "position", "normal"):
            assert getattr(a, f).tobytes() == getattr(b, f).tobytes(), (change, f)
        assert set(a.aux) == set(b.aux) and set(a.terms) == set(b.terms)
        for k in a.aux:
            assert a.aux[k].tobytes() == b.aux[k].tobytes(), (change, k)
        for k in a.terms:
            assert a.terms[k].tobytes() == b.terms[k].tobytes(), (change, k)


@pytest.mark.parametrize("precision", ["f64", "f32"])
def test_runtime_subset_rays_same_bits(precision):
    """The rays of a few pixels (``primary_rays(pixels)``) are those pixels' rays in the whole image's,
    bit for bit, whatever the camera rules; so a subset render is the full render's pixels."""
    from minirt.reference.tracer import Tracer

    scene = load_scene("scenes/rules.toml").with_overrides(width=37, height=23, samples=1)
    idx = np.random.default_rng(5).choice(37 * 23, 200, replace=False)
    for change in [{}, {"pixel_sample": "center", "pixel_shift": (1.0, -0.5), "ray_origin": "camera"}]:
        tr = Tracer(scene, replace(PROFILES["exercise"], **change), precision=precision, runtime=True)
        (o, d), (os_, ds) = tr.primary_rays(), tr.primary_rays(idx)
        for full, sub in ((o, os_), (d, ds)):
            whole = tr.to_numpy3(full)
            assert np.array_equal(whole[idx].view(np.uint8), tr.to_numpy3(sub).view(np.uint8)), change


# ---------------------------------------------------------------------------------------------
# near_root_only with the error-bound offset: back faces shadow themselves

_BACK_FACE = scene_text(
    ball((0.3, 0.0, 3.0), 1.0),
    size=24,
    light=(0.0, 0.0, 12.0),
    render={"background": (0.1, 0.2, 0.3), "max_depth": 0},
    materials={"m": material((0.7, 0.6, 0.5), ambient=0.1, specular=0.5)},
)


@pytest.mark.parametrize("big", [False, True], ids=["unrolled", "bvh"])
def test_near_root_only_with_the_error_bound_offset_keeps_back_face_self_shadows(big):
    """The light is behind the ball: every point the camera sees faces away from it (s·n < 0), and the
    shadow ray runs into the ball itself. Under near_root_only with the error-bound offset the ray used
    to start inside the ball (the side it leaves to), where near_root_only sees nothing: every such point
    lit, with a negative diffuse term and (r·s)^8 on the wrong side. Started outside, it is blocked, as
    under the exercise's numeric offset along the normal and as without near_root_only."""
    text = _BACK_FACE
    if big:  # from 16 shapes on the tracer goes through the shape table and the BVH: far, unseen balls
        text += "".join(ball((40.0 + 3 * k, 40.0, -20.0), 0.5) for k in range(16))
    scene = parse_scene(text)
    base = replace(PROFILES["exercise"], offset="error-bound")
    assert base.near_root_only is True and base.clamp is False
    res = Tracer(scene, base).render()
    on_ball = res.shape_id == 0
    assert on_ball.sum() > 100
    assert not res.terms["diffuse"][on_ball].any() and not res.terms["specular"][on_ball].any()
    for other in (replace(base, offset=1e-6), replace(base, near_root_only=False)):
        alt = Tracer(scene, other).render()
        assert np.array_equal(alt.terms["diffuse"][on_ball], res.terms["diffuse"][on_ball]), other
    o, d = camera.primary_rays(scene, base)
    plain = Plain(scene, base)
    got = np.array([plain.trace(tuple(o[i]), tuple(d[i]), 0) for i in range(len(o))]).reshape(24, 24, 3)
    assert np.abs(got - res.color).max() < 1e-9  # the plain reference agrees
