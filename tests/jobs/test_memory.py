"""A check this machine cannot hold is refused before any work, as one line (minirt.jobs.memory)."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
from support.inproc import minirt

from minirt.errors import MinirtError
from minirt.harness import backends
from minirt.harness import run as harness
from minirt.jobs import memory

ROOT = Path(__file__).resolve().parents[2]
EXERCISE = ROOT / "scenes" / "exercise.toml"


def test_the_estimate_follows_the_measured_peaks():
    """The table of minirt.jobs.memory's docstring: the estimate is within -5 % .. +15 % of each measured peak."""
    mp = 1024 * 1024
    measured = [  # (pixels per scene, oracles, measured peak GB)
        ([mp], [], 0.80), ([mp], ["embree"], 1.78), ([mp] * 3, ["embree"], 3.19),
        ([mp], ["mitsuba"], 2.91), ([mp], ["mitsuba", "povray", "embree"], 4.11),
        ([mp // 4] * 3, ["mitsuba", "povray", "embree"], 3.15),
    ]  # fmt: skip
    for pixels, oracles, peak in measured:
        est = backends.check_bytes(pixels, oracles) / 2**30
        assert peak * 0.95 <= est <= peak * 1.15, (pixels, oracles, est, peak)
    # local worker processes each hold a base, a reference and a running check
    assert backends.check_bytes([mp], ["embree"], local_workers=2) > backends.check_bytes([mp], ["embree"]) + 2 * 0.4e9


def test_a_check_that_cannot_fit_is_refused_before_any_work(monkeypatch):
    monkeypatch.setattr(memory, "available", lambda: 1 << 30)
    with pytest.raises(MinirtError, match=r"at 2048x2048 against 1 oracle\(s\) needs about .* GB of memory, and 1.0"):
        harness.run([EXERCISE], ["reference", "embree"], size=(2048, 2048))
    # what fits runs
    assert harness.run([EXERCISE], ["reference", "embree"], size=(16, 16)).verdict == "pass"


def test_no_figure_from_the_system_means_no_refusal(monkeypatch):
    monkeypatch.setattr(memory, "available", lambda: None)
    assert harness.run([EXERCISE], ["reference", "embree"], size=(16, 16)).verdict == "pass"


def test_the_cli_says_so_in_one_line_and_exit_2():
    """16384² against every oracle: ~1.25 TB by the estimate, beyond any machine this runs on."""
    p = minirt("check", "exercise", "--size", "16384x16384", "-q", cwd=ROOT)  # in this process: tests/support/inproc.py
    lines = p.stderr.strip().splitlines()
    assert p.returncode == 2 and len(lines) == 1, p.stderr
    assert lines[0].startswith("minirt: error: checking the scene at 16384x16384") and "--size" in lines[0]


def test_the_render_estimate_follows_the_measured_peaks():
    mp = 1024 * 1024
    measured = {("reference",): 0.98, ("mitsuba",): 0.97, ("povray",): 0.49, ("embree",): 0.54,
                ("reference", "mitsuba", "povray", "embree"): 1.50}  # fmt: skip
    for names, peak in measured.items():
        est = backends.render_bytes(mp, list(names)) / 2**30
        assert peak * 0.95 <= est <= peak * 1.10, (names, est, peak)


def test_a_render_that_cannot_fit_is_one_line_and_the_reference_alone_streams(tmp_path):
    """16384² with Mitsuba: ~155 GB by the estimate, beyond any machine this runs on; the reference
    alone passes the guard (it is written tile by tile: memory.py does not count it)."""
    from minirt.cli import render as cli
    from minirt.model.rules import resolve
    from minirt.model.scene import load_scene

    size = ["--width", "16384", "--height", "16384"]
    p = minirt("render", "exercise", *size, "--backend", "mitsuba", "--out", tmp_path, "-q", cwd=ROOT)  # inproc.py
    lines = p.stderr.strip().splitlines()
    assert p.returncode == 2 and len(lines) == 1, p.stderr
    assert lines[0].startswith("minirt: error: rendering 16384x16384 with mitsuba needs about")
    assert not list(tmp_path.iterdir())
    scene = load_scene(EXERCISE).with_overrides(width=16384, height=16384)
    rules = resolve(scene)
    cli._render_fits(["reference"], scene, rules)  # no error
    with pytest.raises(MinirtError):
        cli._render_fits(["reference", "embree"], scene, rules)


# ---------------------------------------------------------------------------------------------
# grade: one image, and a class's processes with their render caches
def _minirt_with(monkeypatch, available: int, *args) -> subprocess.CompletedProcess:
    """minirt, in this process (tests/support/inproc.py), believing ``available`` bytes are left."""
    monkeypatch.setattr(memory, "available", lambda: available)
    return minirt(*args, cwd=ROOT)


@pytest.fixture(scope="module")
def graded(tmp_path_factory):
    from support.students import small_scene, student_image

    from minirt.io.images import write_image
    from minirt.model import rules as R

    tmp = tmp_path_factory.mktemp("grade-memory")
    sc = small_scene("rules", 32, 32)
    write_image(tmp / "student.png", student_image(sc, R.resolve(sc)))
    for who in ("ann", "ben"):
        (tmp / "class" / who).mkdir(parents=True)
        write_image(tmp / "class" / who / "rules.png", student_image(sc, R.resolve(sc)))
    return tmp


def test_the_grade_estimate_follows_the_measured_peaks():
    """The figures beside GRADE_PER_PIXEL: within -10 % .. +20 % of each measured peak."""
    for side, peak in ((512, 0.98), (1024, 1.68), (1536, 3.68), (2048, 6.22)):
        est = memory.grade_bytes(side * side) / 2**30
        assert peak * 0.90 <= est <= peak * 1.20, (side, est, peak)
    assert memory.grade_bytes(1 << 20, processes=3) == 3 * memory.grade_bytes(1 << 20)


def test_a_grade_that_cannot_fit_is_one_line_and_exit_2(graded, monkeypatch):
    args = ["grade", "scenes/rules.toml", graded / "student.png", "--size", "32x32", "--out", graded / "one"]
    p = _minirt_with(monkeypatch, 100 << 20, *args)
    lines = p.stderr.strip().splitlines()
    assert p.returncode == 2 and len(lines) == 1 and "Traceback" not in p.stderr, p.stderr
    assert lines[0].startswith("minirt: error: grading ") and "(32x32) needs about 0.5 GB" in lines[0], lines[0]
    assert not (graded / "one").exists() or not list((graded / "one").iterdir())
    # the same command with the memory it needs grades (exit 0: the image follows the scene's rules)
    assert _minirt_with(monkeypatch, 64 << 30, *args).returncode == 0


def test_a_class_that_cannot_fit_is_refused_before_any_grade(graded, monkeypatch):
    args = ["grade", "--class", graded / "class", "--scenes", ROOT / "scenes", "--size", "32x32", "-q"]
    p = _minirt_with(monkeypatch, 200 << 20, *args, "--out", graded / "c1")
    lines = p.stderr.strip().splitlines()
    assert p.returncode == 2 and len(lines) == 1 and "Traceback" not in p.stderr, p.stderr
    assert lines[0].startswith("minirt: error: grading a class at ") and "--workers" in lines[0], lines[0]
    assert not (graded / "c1").exists() or not list((graded / "c1").rglob("*.png"))


def test_the_class_cache_shrinks_to_the_memory_left(monkeypatch):
    px, most = 256 * 256, 2 << 30
    base = memory.grade_bytes(px, 2)
    floor = 2 * int(memory.CACHE_MIN_BYTES * memory.CACHE_OVERHEAD)
    monkeypatch.setattr(memory, "available", lambda: None)  # the system does not say: the full budget
    assert memory.class_cache_bytes(px, 2, most, "x") == most
    monkeypatch.setattr(memory, "available", lambda: 64 << 30)  # plenty
    assert memory.class_cache_bytes(px, 2, most, "x") == most
    monkeypatch.setattr(memory, "available", lambda: base + (1 << 30))  # 1 GB over the grades: shared
    got = memory.class_cache_bytes(px, 2, most, "x")
    assert got == int((1 << 30) / (2 * memory.CACHE_OVERHEAD)) and memory.CACHE_MIN_BYTES < got < most
    monkeypatch.setattr(memory, "available", lambda: base + floor)  # just enough: the smallest cache
    assert memory.class_cache_bytes(px, 2, most, "x") == memory.CACHE_MIN_BYTES
    monkeypatch.setattr(memory, "available", lambda: base + floor - 1)  # less: refused, naming the job
    with pytest.raises(MinirtError, match=r"^a class of 2 needs about .* GB of memory, .*fewer --workers"):
        memory.class_cache_bytes(px, 2, most, "a class of 2")


def test_a_campaign_that_cannot_fit_is_refused_before_any_job(monkeypatch, tmp_path):
    """`minirt fuzz --count 1000000`: with 1 GB left (~0.4 GB kept for a million scenes' outcomes, plus
    the checks themselves) it fits and starts at once -- its first scenes made as their jobs go out, not a
    million scenes first; with 0.5 GB it is one line before any job."""
    import time

    from minirt.campaign import campaign

    c = campaign.Campaign(seed=1, families=("random",), size=(8, 8), backends=("embree",), defects=(), count=10**6)
    monkeypatch.setattr(memory, "available", lambda: 1 << 30)
    campaign.fits_in_memory(c, local_workers=0)
    t0 = time.perf_counter()
    first = [j.scene for _, j in zip(range(3), c.jobs(), strict=False)]
    assert first == ["random_1_0", "random_1_1", "random_1_2"] and time.perf_counter() - t0 < 5
    monkeypatch.setattr(memory, "available", lambda: 1 << 29)
    p = minirt("fuzz", "--count", 1_000_000, "--size", "8x8", "-b", "embree", "--workers", 1, "-o", tmp_path, "-q")
    lines = p.stderr.strip().splitlines()
    assert p.returncode == 2 and len(lines) == 1, p.stderr
    assert lines[0].startswith("minirt: error: a campaign of 1000000 scenes x 1 oracles at 8x8 needs about")
    assert "--count" in lines[0] and not (tmp_path / "cache").exists()
