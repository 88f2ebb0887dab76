"""Every kind of bad input gives one clear line naming file and key, exit status 2, no traceback."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest
from support.inproc import minirt
from support.scenes import ball, plane, scene_text, write_scene

# A good scene file (8x8, a ball over a floor, tests/support/scenes.py): each case edits one line of its text.
GOOD = scene_text(ball((0.0, 0.0, 4.0), 0.5), plane((0.0, 1.0, 0.0), -1.0), size=8, render={"max_depth": 1})

CASES = [
    ("unknown key", ("[camera]\n", "[camera]\nzoom = 2\n"), "camera.zoom: unknown key"),
    ("unknown table", ("[light]\n", "[lights]\nx = 1\n[light]\n"), "lights: unknown key"),
    ("missing key", ("distance = 2.0\n", ""), "camera.distance: missing"),
    ("missing table", ("[light]\nposition = [10.0, 10.0, -1.0]\n", ""), "light: missing"),
    ("wrong type", ("width = 8", 'width = "8"'), "camera.width: must be an integer, got str '8'"),
    ("bool is not a number", ("radius = 0.5", "radius = true"), "shapes[0].radius: must be a number"),
    ("nan", ("radius = 0.5", "radius = nan"), "shapes[0].radius: must be a finite number, got nan"),
    ("infinite", ("center = [0.0, 0.0, 4.0]", "center = [0.0, inf, 4.0]"), "shapes[0].center[1]: must be a finite"),
    (  # (a material's colours may be negative: tests/diagnose/test_honest.py)
        "negative light colour",
        ("position = [10.0, 10.0, -1.0]", "position = [10.0, 10.0, -1.0]\ncolor = [1.0, -1.0, 1.0]"),
        "light.color[1]: must be >= 0",
    ),
    ("radius zero", ("radius = 0.5", "radius = 0"), "shapes[0].radius: must be > 0, got 0"),
    ("radius negative", ("radius = 0.5", "radius = -1"), "shapes[0].radius: must be > 0, got -1"),
    ("zero normal", ("normal = [0.0, 1.0, 0.0]", "normal = [0.0, 0.0, 0.0]"), "shapes[1].normal: must be a non-zero"),
    ("width 0", ("width = 8", "width = 0"), "camera.width: must be >= 1, got 0"),
    ("height 0", ("height = 8", "height = 0"), "camera.height: must be >= 1, got 0"),
    ("samples 0", ("max_depth = 1", "max_depth = 1\nsamples = 0"), "render.samples: must be >= 1, got 0"),
    ("max_depth negative", ("max_depth = 1", "max_depth = -1"), "render.max_depth: must be >= 0, got -1"),
    (
        "unknown material",
        ('material = "m"\n[[shapes]]', 'material = "gold"\n[[shapes]]'),
        "shapes[0].material: unknown material 'gold'",
    ),
    (
        "unknown profile",
        ("max_depth = 1", 'max_depth = 1\nprofile = "fancy"'),
        "render.profile: unknown profile 'fancy'",
    ),
    ("unknown rule", ("[materials.m]", "[model]\nfog = true\n[materials.m]"), "model.fog: unknown rule"),
    (
        "bad rule value",
        ("[materials.m]", '[model]\nshadow_range = "some"\n[materials.m]'),
        "model.shadow_range: must be one of",
    ),
    (
        "bad offset",
        ("[materials.m]", "[model]\noffset = -1.0\n[materials.m]"),
        "model.offset: must be a finite number >= 0",
    ),
    ("unknown shape type", ('type = "ball"', 'type = "cube"'), "unknown shape type 'cube'"),
    (
        "vector too short",
        ("center = [0.0, 0.0, 4.0]", "center = [0.0, 4.0]"),
        "shapes[0].center[2]: must have 3 components",
    ),
    ("toml syntax", ("width = 8", "width = = 8"), "TOML syntax error"),
]


def run(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return minirt(
        *args, cwd=cwd
    )  # in this process: the command's own exit status and messages (tests/support/inproc.py)


@pytest.mark.parametrize(("what", "edit", "message"), CASES, ids=[c[0] for c in CASES])
def test_bad_scene(tmp_path, what, edit, message):
    old, new = edit
    assert old in GOOD
    path = write_scene(tmp_path, "x", GOOD.replace(old, new, 1))
    out = tmp_path / "out"
    p = run("render", str(path), "--out", str(out))
    assert p.returncode == 2, p.stderr
    assert "Traceback" not in p.stderr
    lines = [ln for ln in p.stderr.splitlines() if ln.startswith("minirt: error:")]
    assert lines, p.stderr
    assert any(f"{path}: " in ln and message in ln for ln in lines), p.stderr
    assert not out.exists(), "no output for bad input"


def test_toml_syntax_error_names_line(tmp_path):
    path = write_scene(tmp_path, "x", GOOD.replace("width = 8", "width = = 8"))
    p = run("render", str(path))
    assert "line 4" in p.stderr


def test_good_scene_renders(tmp_path):
    path = write_scene(tmp_path, "x", GOOD)
    p = run("render", str(path), "--out", str(tmp_path / "out"))
    assert p.returncode == 0, p.stderr
    assert sorted(f.name for f in (tmp_path / "out").iterdir()) == [
        "x.reference.exr",
        "x.reference.json",
        "x.reference.png",
    ]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["render", "no/such.toml"], "no/such.toml: no such scene file"),
        (["render", "scenes/exercise.toml", "--backend", "blender"], "unknown backend blender"),
        (["render", "scenes/exercise.toml", "--rule", "clamp"], "expected NAME=VALUE"),
        (["render", "scenes/exercise.toml", "--rule", "fog=1"], "model.fog: unknown rule"),
        (["render", "scenes/exercise.toml", "--profile", "fancy"], "unknown profile 'fancy'"),
        (["probe", "scenes/exercise.toml", "999", "0"], "outside the 256x256 image"),
        (["render", "scenes/exercise.toml", "--width", "0"], "Invalid value"),
        (["render", "scenes/exercise.toml", "--width", "100000"], "--width 100000: must be between 1 and 16384"),
        (["render", "scenes/exercise.toml", "--samples", "100000000"], "--samples 100000000: must be between 1 and"),
        (["render", "scenes/exercise.toml", "--precision", "f16"], "Invalid value"),
        (["export", "scenes/exercise.toml", "--to", "maya"], "unknown target 'maya'"),
        (["frobnicate"], "No such command"),
    ],
)
def test_bad_arguments(args, message):
    root = Path(__file__).resolve().parents[2]
    p = run(*args, cwd=root)
    assert p.returncode == 2, (p.returncode, p.stderr)
    assert message in p.stderr
    assert "Traceback" not in p.stderr


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["render", "scenes/exercise.toml", "--out", "{blocked}/out"], "--out {blocked}/out: cannot create the folder"),
        (["report", "scenes/exercise.toml", "--out", "{blocked}/rep"], "--out {blocked}/rep: cannot create the folder"),
        (["sweep", "scenes/exercise.toml", "--out", "{blocked}/sw"], "--out {blocked}/sw: cannot create the folder"),
        (["export", "scenes/exercise.toml", "--to", "povray", "--out", "{blocked}/e"], "cannot create the folder"),
        (["check", "scenes/exercise.toml", "--json", "{blocked}/c.json"], "--json {blocked}: cannot create"),
        (["check", "scenes/exercise.toml", "--junit", "{tmp}"], "is a folder, expected a file name"),
    ],
    ids=["render", "report", "sweep", "export", "check-json", "check-junit"],
)
def test_unusable_output_fails_before_any_work(tmp_path, args, message):
    """An output path under a regular file cannot be made (even as root): exit 2 and one line, and
    nothing else -- the command checks its outputs before it renders or checks anything."""
    blocked = tmp_path / "a-file"
    blocked.write_text("")
    fill = {"blocked": str(blocked), "tmp": str(tmp_path)}
    root = Path(__file__).resolve().parents[2]
    p = run(*(a.format(**fill) for a in args), cwd=root)
    assert p.returncode == 2, (p.returncode, p.stderr)
    assert message.format(**fill) in p.stderr and "Traceback" not in p.stderr, p.stderr
    assert [ln for ln in (p.stdout + p.stderr).splitlines() if ln.strip()] == p.stderr.strip().splitlines()[-1:]


def test_missing_llvm_is_explained(monkeypatch):
    from minirt.errors import MinirtError
    from minirt.jit import engine

    monkeypatch.setattr(engine, "llvm_status", lambda: (False, "Dr.Jit found no libLLVM; " + engine.INSTALL_HINT))
    with pytest.raises(MinirtError, match="apt-get install -y libllvm19"):
        engine.require_llvm()


@pytest.mark.parametrize("command", ["check", "report"])
def test_the_reference_alone_has_nothing_to_compare_with(command, tmp_path):
    """A comparison with no oracle would check nothing: bad input, before any work, not a PASS."""
    p = run(command, "exercise", "-b", "reference", "--out" if command == "report" else "--json", str(tmp_path / "o"),
            "-q", cwd=Path(__file__).resolve().parents[2])  # fmt: skip
    assert p.returncode == 2 and p.stderr.strip().splitlines() == [
        "minirt: error: --backend reference: no oracle to compare with (give one or more of mitsuba, povray, "
        "embree, cycles, exact, or all)"
    ], p.stderr
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(
    "args",
    [("probe", "exercise", "3", "3", "--json"), ("probe", "exercise", "3", "3"),
     ("render", "exercise", "-b", "reference", "--width", "8", "--height", "8", "--out", "out")],
)  # fmt: skip
def test_a_reader_that_goes_away_is_not_a_verdict(tmp_path, args):
    """``minirt ... | head -1``: standard output closed before minirt writes to it. The status is a
    SIGPIPE's 141 -- not 1, which check and grade give a FAIL (Click's and Rich's own exit on a broken
    pipe), not 2 -- with no traceback and no "Exception ignored" at the interpreter's exit; and what the
    command wrote to files is whole."""
    import sys

    r, w = os.pipe()
    os.close(r)  # nobody will read: the first write to standard output fails with EPIPE
    try:
        p = subprocess.run([sys.executable, "-m", "minirt", *args], cwd=tmp_path, stdout=w, stderr=subprocess.PIPE,
                           text=True, timeout=120)  # fmt: skip
    finally:
        os.close(w)
    assert p.returncode == 141, (p.returncode, p.stderr)
    assert "Traceback" not in p.stderr and "Exception ignored" not in p.stderr and "Broken pipe" not in p.stderr
    if args[0] == "render":
        assert sorted(q.name for q in (tmp_path / "out").iterdir()) == [
            "exercise.reference.exr", "exercise.reference.json", "exercise.reference.png"
        ]  # fmt: skip


@pytest.mark.parametrize("closed", [">&-", "2>&-", ">&- 2>&-"])
@pytest.mark.parametrize("good", [True, False])
def test_a_closed_stream_does_not_change_the_status(tmp_path, closed, good):
    """Standard output or error closed before minirt starts (``minirt ... >&-``, a daemon's): Python
    makes the stream None, and minirt used to die of an AttributeError (at import for stderr) with exit
    1, a FAIL's status, even for a broken scene. Now what cannot be said is dropped and the status is the
    command's own: 0 and the files for a good render, 2 and no folder for a broken scene."""
    import shlex
    import sys

    scene = write_scene(tmp_path, "s", GOOD if good else GOOD.replace("distance = 2.0", 'distance = "x"'))
    cmd = f"exec {shlex.quote(sys.executable)} -m minirt render {shlex.quote(str(scene))} --out out {closed}"
    p = subprocess.run(["sh", "-c", cmd], cwd=tmp_path, timeout=120)
    assert p.returncode == (0 if good else 2)
    if good:
        assert sorted(q.name for q in (tmp_path / "out").iterdir()) == [
            "s.reference.exr",
            "s.reference.json",
            "s.reference.png",
        ]
    else:
        assert not (tmp_path / "out").exists()
