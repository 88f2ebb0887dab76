"""Bundled scenes by name, from any working folder: every command that takes SCENE accepts
`exercise` as well as a path, `minirt scenes` lists them, a path that exists wins over a name, and an
unknown name is one line naming the bundled ones (exit 2)."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
from support.inproc import minirt
from support.scenes import ball, scene_text

from minirt.io.images import read_image_u8
from minirt.model import bundled as scenes

ROOT = Path(__file__).resolve().parents[2]
NAMES = sorted(p.stem for p in (ROOT / "scenes").glob("*.toml"))

SMALL = scene_text(ball((0.0, 0.0, 4.0), 0.5), size=(8, 6), render={"max_depth": 1})


def run(cwd: Path, *args: str) -> subprocess.CompletedProcess:
    return minirt(*args, cwd=cwd)  # in this process (tests/support/inproc.py), run from the folder ``cwd``


def test_bundled_scenes_are_the_package_data():
    """The package data is the repository's scenes/ (the editable install maps the folder), with the
    sample student image beside the scenes."""
    assert scenes.names() == NAMES
    assert scenes.BUNDLED.resolve() == (ROOT / "scenes").resolve()
    assert (scenes.SAMPLES / "rules.student.png").is_file()
    assert scenes.find_scene("exercise") == scenes.BUNDLED / "exercise.toml"


def test_scenes_lists_them_from_anywhere(tmp_path):
    p = run(tmp_path, "scenes")
    assert p.returncode == 0, p.stderr
    assert [ln.split()[0] for ln in p.stdout.splitlines()] == NAMES


@pytest.mark.slow
@pytest.mark.parametrize(
    ("args", "status"),
    [
        (["render", "exercise", "--width", "8", "--height", "8", "--out", "o", "-q"], 0),
        (["check", "exercise", "-b", "embree", "--size", "8x8", "-q"], 0),
        (["probe", "exercise", "3", "3", "--width", "8", "--height", "8"], 0),
        (["export", "exercise", "--to", "povray", "--out", "e"], 0),
        (["report", "exercise", "-b", "embree", "--size", "8x8", "--out", "rep", "-q"], 0),
        (["sweep", "exercise", "-b", "embree", "--size", "8", "--repeats", "1", "--out", "sw", "-q"], 0),
        (["grade", "rules", "{sample}", "-q"], 1),  # the sample student differs from the model
    ],
    ids=lambda v: v[0] if isinstance(v, list) else None,
)
def test_every_command_takes_a_bundled_name(tmp_path, args, status):
    sample = str(scenes.SAMPLES / "rules.student.png")
    p = run(tmp_path, *(a.format(sample=sample) for a in args))
    assert p.returncode == status, p.stderr
    assert "Traceback" not in p.stderr and "minirt: error" not in p.stderr, p.stderr


def test_an_existing_path_wins_over_a_name(tmp_path):
    (tmp_path / "exercise").write_text(SMALL)  # a file called exercise: not the bundled scene
    p = run(tmp_path, "render", "exercise", "--out", "o", "-q")
    assert p.returncode == 0, p.stderr
    assert read_image_u8(tmp_path / "o" / "exercise.reference.png").shape[:2] == (6, 8)


@pytest.mark.parametrize("command", ["render", "check", "export"])
def test_an_unknown_name_is_one_line_naming_the_bundled_ones(tmp_path, command):
    extra = ["--to", "povray"] if command == "export" else []
    p = run(tmp_path, command, "exercize", *extra)
    assert p.returncode == 2
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("minirt: error: exercize: no such scene file"), p.stderr
    assert all(n in lines[0] for n in NAMES)


def test_scene_and_rules_reads_overrides_and_resolves_as_render_does():
    """The one function behind the API, the harness and the CLI: a bundled name or a path, the flags'
    overrides applied to the scene, then the profile, the scene's [model] and the --rule values, in order."""
    from minirt.model.rules import resolve
    from minirt.model.scene import load_scene

    plain = load_scene(scenes.find_scene("rules"))
    scene, rules = scenes.scene_and_rules("rules", width=12, height=10, samples=2, profile="conventional")
    assert (scene.camera.width, scene.camera.height, scene.samples, scene.profile) == (12, 10, 2, "conventional")
    assert rules == resolve(plain, "conventional")
    _, flipped = scenes.scene_and_rules(plain, rules={"clamp": True})
    assert flipped.clamp is True and resolve(plain).clamp is not True  # the override wins over the scene's model
    same, own = scenes.scene_and_rules(plain)
    assert same == plain and own == resolve(plain)
