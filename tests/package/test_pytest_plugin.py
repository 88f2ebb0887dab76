"""minirt's pytest plugin in a user's own test suite (pytester): the minirt_check fixture and scene
files collected as tests pass on a bundled scene, and fail when an oracle disagrees or a scene is
wrong -- so "my scenes pass against every oracle" is a test that can be false."""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

from minirt.testing import assert_scene_passes, parse_size

pytest_plugins = ["pytester"]

ROOT = Path(__file__).resolve().parents[2]
OPTIONS = ("--minirt-backends", "embree", "--minirt-size", "16x16", "-p", "no:cacheprovider")

USER_TESTS = """
from minirt.oracles.embree import EmbreeOracle


def test_bundled_scene_passes(minirt_check):
    minirt_check("exercise")


def test_an_oracle_that_disagrees_fails(minirt_check, monkeypatch):
    real = EmbreeOracle.render

    def farther(self, scene, rules, options=None):
        r = real(self, scene, rules, options)
        r.t = r.t * 1.01  # every hit 1% farther than the reference's
        return r

    monkeypatch.setattr(EmbreeOracle, "render", farther)
    minirt_check("exercise")
"""


def test_fixture_passes_and_fails(pytester):
    pytester.makepyfile(test_user=USER_TESTS)
    r = pytester.runpytest_subprocess(*OPTIONS)
    r.assert_outcomes(passed=1, failed=1)
    plugins = next(ln for ln in r.outlines if ln.startswith("plugins:"))
    assert "minirt-" in plugins  # loaded through the pytest11 entry point, nothing configured
    # a bundled scene by its name (not where minirt is installed), the failure at the test's own line
    r.stdout.fnmatch_lines(["*exercise with embree: FAIL: geometry:*t error(s) above tolerance*"])


# As the README's example: the scenes folder among the test paths, the files to collect by pattern.
PYPROJECT = """
[tool.pytest.ini_options]
testpaths = ["tests", "scenes"]
minirt_scenes = ["scenes/*.toml"]
minirt_size = "16x16"
minirt_backends = "embree"
"""


def test_scene_files_collected_as_tests(pytester):
    """ini minirt_scenes: each matching scene file is a test; a broken one fails with its message -- and so
    do a broken symbolic link and a FIFO named like a scene, which pytest's own collection passes over."""
    pytester.makepyprojecttoml(PYPROJECT)
    scenes = pytester.mkdir("scenes")
    good = (ROOT / "scenes" / "exercise.toml").read_text()
    (scenes / "mine.toml").write_text(good)
    (scenes / "broken.toml").write_text(good.replace("radius = 0.5", "radius = -0.5", 1))
    (scenes / "gone.toml").symlink_to("deleted.toml")
    os.mkfifo(scenes / "pipe.toml")
    (pytester.path / "other.toml").write_text("not = 'a scene'")  # outside the patterns: not collected
    r = pytester.runpytest_subprocess("-p", "no:cacheprovider", "-v")
    r.assert_outcomes(passed=1, failed=3)
    r.stdout.fnmatch_lines(["*scenes/broken.toml::check FAILED*", "*scenes/mine.toml::check PASSED*"])
    r.stdout.fnmatch_lines(["*scenes/gone.toml::check FAILED*", "*scenes/pipe.toml::check FAILED*"])
    r.stdout.fnmatch_lines(["*broken.toml: shapes*radius*"])
    r.stdout.fnmatch_lines(["*gone.toml: a broken symbolic link*"])
    r.stdout.fnmatch_lines(["*pipe.toml: not a regular file*"])
    assert "Traceback" not in r.stdout.str()


BAD_INPUT_TESTS = """
def test_missing_scene(minirt_check):
    minirt_check("scenes/none.toml")


def test_unknown_backend(minirt_check):
    minirt_check("exercise", backends="nosuch")
"""


def test_fixture_bad_input_shows_no_traceback_into_minirt(pytester):
    """Bad input to the fixture fails the test at its own line with minirt's one line: no frame inside minirt."""
    pytester.makepyfile(test_user=BAD_INPUT_TESTS)
    r = pytester.runpytest_subprocess(*OPTIONS)
    r.assert_outcomes(failed=2)
    r.stdout.fnmatch_lines(["E*SceneError: scenes/none.toml: no such scene file", "test_user.py:2: SceneError"])
    r.stdout.fnmatch_lines(["E*MinirtError: --backend: unknown backend nosuch*", "test_user.py:6: MinirtError"])
    inside = [ln for ln in r.outlines if re.search(r"minirt/[\w/]*\.py:\d+", ln)]
    assert inside == [], inside


def test_assert_scene_passes_returns_the_check():
    res = assert_scene_passes("exercise", "embree", size="16x16")
    assert res.verdict == "pass" and [s.scene for s in res.scenes] == ["exercise"]


def test_skip_does_not_pass_unless_allowed():
    """A scene with no oracle to compare with (reference only) is not "passes against every oracle": bad input."""
    from minirt.errors import MinirtError

    with pytest.raises(MinirtError, match="no oracle to compare with"):
        assert_scene_passes("exercise", "reference", size=(8, 8))


@pytest.mark.parametrize(("given", "want"), [("64x48", (64, 48)), ("32", (32, 32)), ((8, 6), (8, 6)), ("", None)])
def test_parse_size(given, want):
    assert parse_size(given) == want
