"""What minirt's children leave, and what minirt says for its libraries.

- Blender makes a folder ``$TMPDIR/blender_XXXXXX`` when it starts and removes it only when it exits by
  itself: each Cycles render that timed out or was interrupted (Blender killed) left one behind. minirt
  gives Blender a TMPDIR of its own, ``minirt-blender-<pid>-XXXX``, removed on every exit path minirt
  controls; one a SIGKILLed minirt left is removed by the next run, as the ``minirt-cycles-*`` folders are.
- A warning from NumPy (an overflow in a cast) is minirt's own one line, never a source path.
- ``render`` says "ok" of a backend only once its files are written.

Each command is a child process (signals, $TMPDIR and RLIMIT_FSIZE are the process's).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from support.scenes import ball, scene_text

from minirt.oracles.cycles import CyclesOracle

ROOT = Path(__file__).resolve().parents[2]
HAS_BLENDER, WHY_NOT = CyclesOracle().available()
needs_blender = pytest.mark.skipif(not HAS_BLENDER, reason=WHY_NOT)
MINIRT = [sys.executable, "-m", "minirt"]


def env_with(tmpdir: Path) -> dict[str, str]:
    return {**os.environ, "TMPDIR": str(tmpdir)}


def blender_started(tmpdir: Path, timeout: float = 120.0) -> None:
    """Wait until a Blender process has made its temporary folder somewhere under ``tmpdir``."""
    deadline = time.monotonic() + timeout
    while not any(p.name.startswith("blender_") for p in tmpdir.rglob("blender_*")):
        assert time.monotonic() < deadline, "Blender did not start"
        time.sleep(0.05)


def slow_render(tmp_path: Path, tmpdir: Path) -> subprocess.Popen:
    """A Cycles render of some seconds (256x256 at 256 samples a pixel), in a child process."""
    args = ["render", "exercise", "-b", "cycles", "--samples", "256", "-o", tmp_path / "out"]
    return subprocess.Popen([*MINIRT, *map(str, args)], env=env_with(tmpdir), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)  # fmt: skip


@needs_blender
def test_a_timed_out_cycles_render_leaves_nothing_in_tmpdir(tmp_path):
    tmpdir = tmp_path / "tmp"
    tmpdir.mkdir()
    # 4,096 samples a pixel: the job goes to a Blender process already started (for its version), which
    # rendered one sample of 32x32 within the 0.1 s at times, and nothing timed out
    args = ["render", "exercise", "-b", "cycles", "--timeout", "0.1", "--samples", "4096", "--width", "32",
            "--height", "32", "-o", tmp_path / "out"]  # fmt: skip
    p = subprocess.run([*MINIRT, *map(str, args)], env=env_with(tmpdir), capture_output=True, text=True, timeout=300)
    assert "timed out after 0.1 s" in p.stderr, p.stderr
    assert sorted(q.name for q in tmpdir.iterdir()) == []


@needs_blender
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_an_interrupted_cycles_render_leaves_nothing_in_tmpdir(tmp_path, sig):
    tmpdir = tmp_path / "tmp"
    tmpdir.mkdir()
    p = slow_render(tmp_path, tmpdir)
    try:
        blender_started(tmpdir)
        time.sleep(0.5)  # Blender is rendering
        p.send_signal(sig)
        _, err = p.communicate(timeout=60)
    finally:
        p.kill()
    assert p.returncode == 128 + sig, err
    assert sorted(q.name for q in tmpdir.iterdir()) == []


@needs_blender
def test_what_a_killed_run_left_in_tmpdir_is_removed_by_the_next(tmp_path):
    tmpdir = tmp_path / "tmp"
    tmpdir.mkdir()
    p = slow_render(tmp_path, tmpdir)
    try:
        blender_started(tmpdir)
        p.send_signal(signal.SIGKILL)  # no handler runs: Blender dies with it (its parent-death signal)
        p.communicate(timeout=60)
    finally:
        p.kill()
    assert list(tmpdir.rglob("blender_*")), "the killed run left no Blender folder: nothing to sweep"
    args = ["render", "exercise", "-b", "cycles", "--width", "8", "--height", "8", "-o", tmp_path / "out"]
    q = subprocess.run([*MINIRT, *map(str, args)], env=env_with(tmpdir), capture_output=True, text=True, timeout=300)
    assert q.returncode == 0, q.stderr
    assert sorted(x.name for x in tmpdir.iterdir()) == []


def test_an_interrupted_run_on_workers_leaves_nothing_in_tmpdir(tmp_path):
    """The embedded Dask cluster (--workers 2) made $TMPDIR/dask-scratch-space/worker-*, left by every
    interrupted run: its $TMPDIR is now a folder of minirt's own, removed when the cluster stops."""
    tmpdir = tmp_path / "tmp"
    tmpdir.mkdir()
    args = ["fuzz", "--workers", "2", "-n", "40", "--out", tmp_path / "fuzz"]
    p = subprocess.Popen([*MINIRT, *map(str, args)], env=env_with(tmpdir), stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        deadline = time.monotonic() + 120
        while not any(tmpdir.rglob("worker-*")):
            assert time.monotonic() < deadline and p.poll() is None, "the cluster's workers did not start"
            time.sleep(0.1)
        time.sleep(1.0)  # the workers are working
        p.send_signal(signal.SIGINT)
        _, err = p.communicate(timeout=60)
    finally:
        p.kill()
    assert p.returncode == 130, err
    assert sorted(q.name for q in tmpdir.iterdir()) == []


# ---------------------------------------------------------------------------------------------
HUGE_BALL = scene_text(ball((0.0, 0.0, 4.0), 1e100), size=16)  # a radius at the limit scenes allow


@needs_blender
def test_numpys_warnings_are_minirts_own_lines(tmp_path):
    """Issue 51 (6): a ball of radius 1e100 with -b cycles printed NumPy's `hazards.py:428: RuntimeWarning:
    overflow encountered in cast` and the source line, twice, before minirt's own warning."""
    scene = tmp_path / "huge.toml"
    scene.write_text(HUGE_BALL)
    p = subprocess.run([*MINIRT, "render", str(scene), "-b", "cycles", "-o", str(tmp_path / "out")],
                       env=env_with(tmp_path), capture_output=True, text=True, timeout=300)  # fmt: skip
    assert "Warning:" not in p.stderr and ".py:" not in p.stderr, p.stderr
    assert "minirt: warning: huge: shapes[0].radius = 1e+100 is inf in float32" in p.stderr, p.stderr
    assert all(ln.startswith(("minirt: ", "huge ", "  ", "wrote ")) for ln in p.stderr.splitlines()), p.stderr


def test_mitsubas_log_is_minirts_warning_lines(tmp_path):
    """Mitsuba printed its own line, with colour codes and a date, for the same ball: `WARN [Sphere]
    'to_world' transform shouldn't contain non-uniform scaling!`."""
    scene = tmp_path / "huge.toml"
    scene.write_text(HUGE_BALL)
    p = subprocess.run([*MINIRT, "render", str(scene), "-b", "mitsuba", "-o", str(tmp_path / "out")],
                       capture_output=True, text=True, timeout=300)  # fmt: skip
    assert p.returncode == 0, p.stderr
    text = p.stdout + p.stderr
    assert "\x1b" not in text and " WARN " not in text, text
    assert "minirt: warning: RuntimeWarning: Mitsuba: [Sphere] 'to_world' transform shouldn't" in p.stderr, text


def test_a_worker_says_its_warnings_as_minirt_lines(tmp_path):
    """check --workers 2 of the ball of radius 1e100 with Embree: a worker printed trimesh's
    `util.py:162: RuntimeWarning: overflow encountered in multiply` and the source line. Embree's normals
    are now computed without the warning (the float32 line says it), and a worker's warnings are minirt
    lines like the command's own."""
    scene = tmp_path / "huge.toml"
    scene.write_text(HUGE_BALL)
    p = subprocess.run([*MINIRT, "check", str(scene), "-b", "embree", "--size", "16x16", "--workers", "2", "-q"],
                       capture_output=True, text=True, timeout=300)  # fmt: skip
    assert p.returncode in (0, 1), p.stderr
    assert "Warning:" not in p.stderr and ".py:" not in p.stderr, p.stderr
    assert "minirt: warning: huge: shapes[0].radius = 1e+100 is inf in float32 (embree)" in p.stderr, p.stderr


def test_a_leftover_warning_is_one_minirt_line():
    """Any warning minirt does not say itself reaches the user as one ``minirt: warning:`` line: no path,
    no source line."""
    code = (
        "import sys, warnings\n"
        "from minirt.cli import console\n"
        "console.own_warnings()\n"
        "import numpy as np\n"
        "np.float32(np.float64(1e300))\n"
        "warnings.warn('a library says\\nsomething', DeprecationWarning)\n"
        "warnings.warn('a library says\\nsomething', UserWarning)\n"
    )
    p = subprocess.run([sys.executable, "-W", "always", "-c", code], capture_output=True, text=True, timeout=60)
    lines = p.stderr.splitlines()
    assert lines == [
        "minirt: warning: RuntimeWarning: overflow encountered in cast",
        "minirt: warning: DeprecationWarning: a library says something",
        "minirt: warning: UserWarning: a library says something",
    ], p.stderr
    # A worker's (minirt.jobs.worker): the same lines on its standard error, which is minirt's.
    worker = code.replace("from minirt.cli import console\nconsole.own_warnings()", "from minirt.jobs import logs\n"
                          "logs.warnings_as_lines()")  # fmt: skip
    assert worker != code
    p = subprocess.run([sys.executable, "-W", "always", "-c", worker], capture_output=True, text=True, timeout=60)
    assert p.stderr.splitlines() == lines, p.stderr


# ---------------------------------------------------------------------------------------------
def test_render_says_ok_only_once_the_exr_is_written(tmp_path):
    """Issue 51 (7): `render` printed "ok -> ...exr" before it reported that the EXR could not be written.
    A 256x256 render's PNG fits under the limit, its EXR (~1 MB) does not."""
    code = (
        "import resource, sys\n"
        "resource.setrlimit(resource.RLIMIT_FSIZE, (200_000, 200_000))\n"
        "sys.argv[0] = 'minirt'\n"
        "from minirt.cli.app import main\n"
        "main()\n"
    )
    out = tmp_path / "out"
    p = subprocess.run([sys.executable, "-c", code, "render", "exercise", "-o", str(out)], capture_output=True,
                       text=True, timeout=300, env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1"})  # fmt: skip
    assert p.returncode == 2, p.stderr
    assert " ok " not in p.stderr, p.stderr
    assert p.stderr.splitlines()[-1].startswith(f"minirt: error: {out / 'exercise.reference.exr'}"), p.stderr
    assert not (out / "exercise.reference.exr").exists()
