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
