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


def test_the_next_scenes_check_begins_before_this_ones_oracles(monkeypatch):
    """``run`` begins scene i + 1's check (its reference, the certified oracle's renders started) before it
    checks scene i's oracles -- the same documents as checking each scene alone -- and an error in a check
    leaves no begun scene's renders behind."""
    files = checks.scene_files(["exercise", "matte", "three_balls"])
    events = []
    real_start, real_check = harness.start_chosen, harness.check_backend
    monkeypatch.setattr(harness, "start_chosen", lambda *a: events.append(("begin", a[2].name)) or real_start(*a))
    monkeypatch.setattr(
        harness, "check_backend", lambda *a, **k: events.append(("check", a[0].name)) or real_check(*a, **k)
    )
    result = harness.run(files, ["reference", "embree"], (16, 16))
    assert events == [("begin", "exercise"), ("begin", "matte"), ("check", "exercise"), ("begin", "three_balls"),
                      ("check", "matte"), ("check", "three_balls")]  # fmt: skip
    alone = [harness.check_scene(f, ["reference", "embree"], (16, 16)) for f in files]
    for a, b in zip(result.scenes, alone, strict=True):
        assert _timeless(a.as_dict()) == _timeless(b.as_dict())
    cancelled = []
    monkeypatch.setattr(harness._Started, "cancel", lambda self: cancelled.append(self.scene.name))

    def broken(*a, **k):
        raise RuntimeError("a check that breaks")

    monkeypatch.setattr(harness, "check_backend", broken)
    with pytest.raises(RuntimeError, match="breaks"):
        harness.run(files, ["reference", "embree"], (16, 16))
    assert cancelled == ["matte"]


def _timeless(v):
    if isinstance(v, dict):
        return {k: _timeless(x) for k, x in v.items() if k not in ("seconds", "timings")}
    if isinstance(v, list):
        return [_timeless(x) for x in v]
    return v
