"""Property-based hostile input over the scene schema (hypothesis): whatever a scene file holds, loading
it gives a Scene or a SceneError -- one line per problem, naming the file -- never another exception;
its name always makes a safe file stem and inert terminal text."""

from __future__ import annotations

import json
import math

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from minirt.errors import SceneError
from minirt.io.untrusted import file_stem, terminal_text
from minirt.model.scene import parse_scene

HOSTILE_TEXT = st.one_of(
    st.text(max_size=40),
    st.sampled_from(["../../x", "/etc/passwd", "x[/]", "[link=file:///etc]a[/link]", "\x1b]0;t\x07", "\x00", "..", ""]),
    st.text(alphabet=st.characters(codec="utf-8"), min_size=200, max_size=600),
)
NUMBER = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.sampled_from([0, -0.0, 1e-320, 1e308, -1e308, 5e-324]),
)
VALUE = st.recursive(
    st.one_of(NUMBER, HOSTILE_TEXT, st.booleans()), lambda inner: st.lists(inner, max_size=4), max_leaves=8
)
VEC = st.one_of(st.lists(NUMBER, min_size=3, max_size=3), VALUE)


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, int):
        return str(v)
    if isinstance(v, str):
        return json.dumps(v)  # JSON string escapes are TOML basic-string escapes
    return "[" + ", ".join(_toml_value(x) for x in v) + "]"


@st.composite
def scene_text(draw) -> str:
    lines = ["[scene]", f"name = {_toml_value(draw(HOSTILE_TEXT))}"]
    if draw(st.booleans()):
        lines.append(f"description = {_toml_value(draw(HOSTILE_TEXT))}")
    lines += ["[camera]", f"distance = {_toml_value(draw(st.one_of(NUMBER, VALUE)))}"]
    for key in ("width", "height"):
        if draw(st.booleans()):
            lines.append(f"{key} = {_toml_value(draw(st.one_of(st.integers(-5, 70000), VALUE)))}")
    lines += ["[light]", f"position = {_toml_value(draw(VEC))}"]
    lines += ["[render]", f"max_depth = {_toml_value(draw(st.one_of(st.integers(-2, 100), VALUE)))}"]
    if draw(st.booleans()):
        lines.append(f"samples = {_toml_value(draw(st.one_of(st.integers(-2, 10**9), VALUE)))}")
    if draw(st.booleans()):
        lines.append(f"profile = {_toml_value(draw(st.one_of(st.sampled_from(['exercise', 'conventional']), VALUE)))}")
    material = draw(st.one_of(st.just("m"), st.text(min_size=1, max_size=20)))
    lines += [f"[materials.{json.dumps(material)}]", f"diffuse = {_toml_value(draw(VEC))}"]
    for _ in range(draw(st.integers(0, 3))):
        if draw(st.booleans()):
            lines += ["[[balls]]", f"center = {_toml_value(draw(VEC))}", f"radius = {_toml_value(draw(NUMBER))}"]
        else:
            lines += ["[[planes]]", f"normal = {_toml_value(draw(VEC))}", f"distance = {_toml_value(draw(NUMBER))}"]
        mat = draw(st.one_of(st.just(material), HOSTILE_TEXT))
        lines.append(f"material = {_toml_value(mat)}")
    if draw(st.booleans()):
        lines.append(f"{json.dumps(draw(st.text(min_size=1, max_size=12)))} = {_toml_value(draw(VALUE))}")
    return "\n".join(lines) + "\n"


@settings(max_examples=300, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(scene_text())
def test_any_scene_text_loads_or_says_why(text):
    try:
        scene = parse_scene(text, "hostile.toml")
    except SceneError as e:
        assert e.lines and all(line.startswith("hostile.toml") for line in e.lines)
        for line in e.lines:
            shown = terminal_text(line, 2000)
            assert "\x1b" not in shown and "\x00" not in shown and "\n" not in shown
        return
    stem = file_stem(scene.name, "hostile")
    assert stem and "/" not in stem and not stem.startswith(".")
    assert "\x1b" not in terminal_text(scene.name) and "\x1b" not in terminal_text(scene.description)


@settings(max_examples=500, deadline=None, derandomize=True)
@given(st.text())
def test_any_name_makes_a_safe_stem(name):
    stem = file_stem(name)
    assert stem == file_stem(name)
    assert 0 < len(stem) <= 80 and stem.isascii()
    assert "/" not in stem and "\x00" not in stem and ".." not in stem and stem[0] not in ".-_"
