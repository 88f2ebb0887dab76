"""A check this machine cannot hold is refused before any work, as one line (minirt.memory)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from minirt import harness, memory
from minirt.errors import MinirtError

ROOT = Path(__file__).resolve().parent.parent
EXERCISE = ROOT / "scenes" / "exercise.toml"


def test_the_estimate_follows_the_measured_peaks():
    """The table of minirt.memory's docstring: the estimate is within -5 % .. +15 % of each measured peak."""
    mp = 1024 * 1024
    measured = [  # (pixels per scene, oracles, measured peak GB)
        ([mp], [], 0.80), ([mp], ["embree"], 1.78), ([mp] * 3, ["embree"], 3.19),
        ([mp], ["mitsuba"], 2.91), ([mp], ["mitsuba", "povray", "embree"], 4.11),
        ([mp // 4] * 3, ["mitsuba", "povray", "embree"], 3.15),
    ]  # fmt: skip
    for pixels, oracles, peak in measured:
        est = memory.check_bytes(pixels, oracles) / 2**30
        assert peak * 0.95 <= est <= peak * 1.15, (pixels, oracles, est, peak)
    # local worker processes each hold a base, a reference and a running check
    assert memory.check_bytes([mp], ["embree"], local_workers=2) > memory.check_bytes([mp], ["embree"]) + 2 * 0.4e9


def test_a_check_that_cannot_fit_is_refused_before_any_work(monkeypatch):
    monkeypatch.setattr(memory, "available", lambda: 1 << 30)
    with pytest.raises(MinirtError, match=r"at 2048x2048 against 1 oracle\(s\) needs about .* GB of memory, and 1.0"):
        harness.run([EXERCISE], ["reference", "embree"], size=(2048, 2048))
    # what fits runs
    assert harness.run([EXERCISE], ["reference", "embree"], size=(16, 16)).verdict == "pass"


def test_no_figure_from_the_system_means_no_refusal(monkeypatch):
    monkeypatch.setattr(memory, "available", lambda: None)
    assert harness.run([EXERCISE], ["reference"], size=(16, 16)).verdict == "pass"


def test_the_cli_says_so_in_one_line_and_exit_2():
    """16384² against every oracle: ~1.25 TB by the estimate, beyond any machine this runs on."""
    p = subprocess.run(
        [sys.executable, "-m", "minirt", "check", "exercise", "--size", "16384x16384", "-q"],
        capture_output=True, text=True, cwd=ROOT, timeout=120,
    )  # fmt: skip
    lines = p.stderr.strip().splitlines()
    assert p.returncode == 2 and len(lines) == 1, p.stderr
    assert lines[0].startswith("minirt: error: checking the scene at 16384x16384") and "--size" in lines[0]


def test_the_render_estimate_follows_the_measured_peaks():
    mp = 1024 * 1024
    measured = {("reference",): 0.98, ("mitsuba",): 0.97, ("povray",): 0.49, ("embree",): 0.54,
                ("reference", "mitsuba", "povray", "embree"): 1.50}  # fmt: skip
    for names, peak in measured.items():
        est = memory.render_bytes(mp, list(names)) / 2**30
        assert peak * 0.95 <= est <= peak * 1.10, (names, est, peak)


def test_a_render_that_cannot_fit_is_one_line_and_the_reference_alone_streams(tmp_path):
    """16384² with Mitsuba: ~155 GB by the estimate, beyond any machine this runs on; the reference
    alone passes the guard (it is written tile by tile: memory.py does not count it)."""
    from minirt import cli
    from minirt.rules import resolve
    from minirt.scene import load_scene

    p = subprocess.run(
        [sys.executable, "-m", "minirt", "render", "exercise", "--width", "16384", "--height", "16384",
         "--backend", "mitsuba", "--out", str(tmp_path), "-q"],
        capture_output=True, text=True, cwd=ROOT, timeout=120,
    )  # fmt: skip
    lines = p.stderr.strip().splitlines()
    assert p.returncode == 2 and len(lines) == 1, p.stderr
    assert lines[0].startswith("minirt: error: rendering 16384x16384 with mitsuba needs about")
    assert not list(tmp_path.iterdir())
    rules = resolve(load_scene(EXERCISE))
    cli._render_fits(["reference"], 16384, 16384, rules)  # no error
    with pytest.raises(MinirtError):
        cli._render_fits(["reference", "embree"], 16384, 16384, rules)
