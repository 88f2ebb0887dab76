"""`minirt grade` on hostile images, as the issue found them (tests/io/test_images_hostile.py is the
reader's side): a FIFO, a device or a folder as the image, a header claiming 100000x100000 pixels,
RGBA with alpha 128 and 0, garbled files -- each exit status 2 and one `minirt: error:` line within
seconds (or the grade the image deserves), never a traceback or an internal error; SIGTERM, SIGINT and
SIGHUP in the middle of a grade stop it at once; `--size` errors name `--size`.

A child process where only a process shows it (a FIFO nobody writes to: the command must end by itself);
the rest in this process (tests/support/inproc.py).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from support.hostile_images import claiming_png, garbled, write_unassociated
from support.inproc import minirt

from minirt.io.images import read_image_u8

ROOT = Path(__file__).resolve().parents[2]
SCENE = ROOT / "scenes" / "rules.toml"
SAMPLE = ROOT / "scenes" / "samples" / "rules.student.png"  # 256x256, differs from the scene's rules


def one_error_line(p: subprocess.CompletedProcess) -> str:
    assert p.returncode == 2, (p.returncode, p.stdout, p.stderr)
    assert "Traceback" not in p.stderr + p.stdout and "internal error" not in p.stderr
    lines = p.stderr.splitlines()
    assert len(lines) == 1, p.stderr
    assert lines[0].startswith("minirt: error: "), lines[0]
    return lines[0]


# ---------------------------------------------------------------------------------------------
def _not_files(tmp: Path) -> dict[str, tuple[Path, str]]:
    fifo = tmp / "fifo.png"
    os.mkfifo(fifo)
    (tmp / "zero.png").symlink_to("/dev/zero")
    (tmp / "folder.png").mkdir()
    return {
        "fifo": (fifo, "not a regular file (a FIFO); an image must be a file"),
        "device": (tmp / "zero.png", "not a regular file (a character device); an image must be a file"),
        "folder": (tmp / "folder.png", "is a folder, expected an image file"),
    }


@pytest.mark.parametrize("case", ["fifo", "device", "folder"])
def test_a_file_that_is_no_file_ends_by_itself_in_one_line(tmp_path, case):
    """The issue's FIFO hung for ever, deaf to SIGTERM, SIGINT and SIGHUP: now the command ends by itself,
    at once (a child process, killed after 60 s should it hang)."""
    image, words = _not_files(tmp_path)[case]
    t0 = time.monotonic()
    p = subprocess.run(
        [sys.executable, "-m", "minirt", "grade", str(SCENE), str(image)],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
    )
    elapsed = time.monotonic() - t0
    assert one_error_line(p) == f"minirt: error: {image}: {words}"
    assert elapsed < 20, f"{elapsed:.1f} s"  # Python and minirt's imports: about a second when idle


def test_a_header_claiming_100000_squared_is_one_line_not_a_memory_error(tmp_path):
    bomb = tmp_path / "bomb.png"
    bomb.write_bytes(claiming_png(100_000, 100_000))
    t0 = time.monotonic()
    line = one_error_line(minirt("grade", SCENE, bomb))
    assert time.monotonic() - t0 < 5
    assert line.startswith(f"minirt: error: {bomb}: the image says it is 100000x100000, larger than any scene"), line


def test_a_header_of_another_size_is_refused_before_decoding(tmp_path):
    """Within the largest scene but not the scene's size: the size message, from the header alone (a 16384 x
    12000 image would take seconds and 590 MB to decode as float)."""
    claim = tmp_path / "claim.png"
    claim.write_bytes(claiming_png(16384, 12000))
    t0 = time.monotonic()
    line = one_error_line(minirt("grade", SCENE, claim, "--size", "48x48"))
    assert time.monotonic() - t0 < 5
    assert f"{claim}: the image is 16384x12000, the scene {SCENE} is 48x48" in line, line
    assert "grade with --size 16384x12000" in line, line


def test_probe_checks_the_header_too_and_names_its_own_options(tmp_path):
    claim = tmp_path / "claim.png"
    claim.write_bytes(claiming_png(16384, 12000))
    line = one_error_line(minirt("probe", SCENE, "1", "1", "--image", claim, "--width", "48", "--height", "48"))
    assert "probe with --width 16384 --height 12000" in line and "--size" not in line, line


@pytest.fixture(scope="module")
def match_png(tmp_path_factory) -> Path:
    """The scene's model as given at 48x48 (the reference's PNG): graded `match`."""
    out = tmp_path_factory.mktemp("match")
    p = minirt("render", SCENE, "--width", "48", "--height", "48", "--out", out)
    assert p.returncode == 0, p.stderr
    return out / "rules.reference.png"


@pytest.mark.parametrize("alpha", [128, 0])
def test_rgba_is_graded_as_the_image_without_alpha(tmp_path, match_png, alpha):
    """The issue: alpha 128 was graded DIFFERS and alpha 0 got a nonsense diagnosis (`pixel_shift=0,-1`)."""
    rgb = read_image_u8(match_png)
    rgba = tmp_path / "rgba.png"
    write_unassociated(rgba, np.concatenate([rgb, np.full((*rgb.shape[:2], 1), alpha, np.uint8)], axis=-1))
    plain = minirt("grade", SCENE, match_png, "--size", "48x48")
    with_alpha = minirt("grade", SCENE, rgba, "--size", "48x48")
    assert plain.returncode == 0 and plain.stderr.startswith("MATCH rules:"), plain.stderr
    assert (with_alpha.returncode, with_alpha.stderr) == (plain.returncode, plain.stderr)


# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("sig", "status", "last"),
    [
        (signal.SIGTERM, 143, "minirt: stopped by SIGTERM"),
        (signal.SIGINT, 130, "minirt: aborted"),
        (signal.SIGHUP, 129, "minirt: stopped by SIGHUP"),
    ],
)
def test_a_signal_stops_a_grade_at_once(monkeypatch, sig, status, last):
    """A signal 0.1 s into the diagnosis of a 256x256 image (seconds of work): the command stops within a
    second with 128+N and one line, its diagnosis unfinished."""
    from minirt.grading import grade as grading

    real = grading.dg.diagnose
    sent: list[float] = []
    finished: list[bool] = []

    def diagnose(*args, **kw):
        def send() -> None:
            sent.append(time.monotonic())
            os.kill(os.getpid(), sig)

        threading.Timer(0.1, send).start()
        d = real(*args, **kw)
        finished.append(True)
        return d

    monkeypatch.setattr(grading.dg, "diagnose", diagnose)
    p = minirt("grade", SCENE, SAMPLE, "--size", "256x256", "-q")
    done = time.monotonic()
    assert sent, "the grade ended before the signal was sent"
    assert (p.returncode, p.stderr.splitlines()[-1:]) == (status, [last]), p.stderr
    assert not finished and done - sent[0] < 1.0, f"stopped {done - sent[0]:.2f} s after the signal"


# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("args", "line"),
    [
        (["grade", "rules", "x.png", "--size", "100000x5"], "--size 100000x5: the width must be between 1 and 16384"),
        (["grade", "rules", "x.png", "--size", "64x0"], "--size 64x0: the height must be between 1 and 16384"),
        (["check", "rules", "--size", "20000"], "--size 20000: the width must be between 1 and 16384"),
    ],
)
def test_size_errors_name_size(tmp_path, args, line):
    """They named --width, an option the user had not given."""
    assert one_error_line(minirt(*args, cwd=tmp_path)) == f"minirt: error: {line}"


# ---------------------------------------------------------------------------------------------
@settings(max_examples=40, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(case=garbled(least=1))  # each a change: what decodes costs a diagnosis (~0.3 s)
def test_garbled_images_are_graded_or_one_line(tmp_path, case):
    """Through the whole command (an 8x6 scene): a verdict (0 or 1) for what decodes, else exit 2 and one
    line -- never an internal error (exit 1 with a traceback's last line) or a NumPy warning."""
    ext, data = case
    image = tmp_path / f"student{ext}"
    image.write_bytes(data)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a warning would be an internal error: it shows as one here
        p = minirt("grade", SCENE, image, "--size", "8x6", "-q")
    assert "internal error" not in p.stderr and "Traceback" not in p.stderr, p.stderr
    if p.returncode == 2:
        one_error_line(p)
    else:
        assert p.returncode in (0, 1) and p.stderr.startswith(("MATCH rules:", "DIFFERS rules:")), p.stderr


def test_a_signal_wrapped_by_a_library_still_stops_with_its_status(monkeypatch):
    """A signal that lands while Dr.Jit traces a loop reaches the command as Dr.Jit's RuntimeError ("dr.while_loop():
    encountered an exception"), not as the interrupt: it is still the signal's stop (128+N, one line), not an
    internal error (seen once in a loaded run of the test above: exit 1)."""
    from minirt.cli import app
    from minirt.grading import grade as grading

    def diagnose(*args, **kw):
        app._stopped_by.append(signal.SIGHUP)  # what the handler records before it raises
        raise RuntimeError("dr.while_loop(): encountered an exception (see above).")

    monkeypatch.setattr(grading.dg, "diagnose", diagnose)
    p = minirt("grade", SCENE, SAMPLE, "--size", "256x256", "-q")
    assert (p.returncode, p.stderr.splitlines()[-1:]) == (129, ["minirt: stopped by SIGHUP"]), p.stderr
