"""A check parses each scene file once: ``read_all`` reports bad input first and its scenes serve the run
and the hazard warnings (a 10,000-ball file takes ~0.4 s to parse; it was parsed three times)."""

from __future__ import annotations

import pytest

from minirt.errors import SceneError
from minirt.harness import checks
from minirt.harness import run as harness
from minirt.model import scene as scene_module


def test_the_scenes_read_first_serve_the_whole_check(monkeypatch):
    files = checks.scene_files(["exercise", "three_balls"])
    scenes = checks.read_all(files)
    assert [s.name for s in scenes] == ["exercise", "three_balls"]
    calls = []
    real = scene_module.load_scene

    def counted(path, *a, **k):
        calls.append(path)
        return real(path, *a, **k)

    monkeypatch.setattr(harness, "load_scene", counted)
    monkeypatch.setattr(scene_module, "load_scene", counted)
    result = checks.run_checks(files, ["reference"], (8, 8), scenes=scenes)
    checks.hazard_warnings(result, ["reference"], (8, 8), scenes)
    assert calls == []
    # without them, each file is parsed where it is needed (the Python API's path): the test can fail
    checks.hazard_warnings(result, ["reference"], (8, 8))
    assert len(calls) == 2


def test_bad_input_is_still_told_first(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[camera]\nwidth = 'x'\n")
    with pytest.raises(SceneError, match=r"bad\.toml"):
        checks.read_all([bad])
