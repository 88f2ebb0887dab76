"""A graded image is untrusted (minirt.io.images.read_student_image): whatever the file is or holds, reading
it gives the colours or one MinirtError line naming the file, at once -- never a hang, a traceback or a
decode the header did not pay for.

Files that are not files (a FIFO, a device, a folder) are refused before anything opens them; a header
that claims more pixels than any scene (a 1-bit PNG of 100000x100000, 1.2 MB on disk) is refused before a
pixel is decoded; alpha is ignored: colours read as stored, whatever the alpha (OpenImageIO multiplies
them by it unless told not to); hypothesis truncates and garbles small images of every supported type.
What the command line makes of these (exit status 2 and one line, a FIFO with no writer, signals) is
tests/cli/test_grade_hostile.py.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest
from hypothesis import HealthCheck, given, settings
from support.hostile_images import (
    FORMATS,
    PIXELS,
    H,
    W,
    claiming_png,
    garbled,
    stored_rgba,
    valid_bytes,
    write_unassociated,
)

from minirt.errors import MinirtError
from minirt.io.images import MAX_CHANNELS, exr_channels, read_student_image, write_image
from minirt.model.result import RenderResult
from minirt.model.scene import LIMITS


def one_line_error(call, path: Path) -> str:
    with pytest.raises(MinirtError) as e:
        call()
    text = str(e.value)
    assert "\n" not in text and text.startswith(f"{path}: "), text
    return text


# ---------------------------------------------------------------------------------------------
def test_a_folder_is_refused(tmp_path):
    (tmp_path / "folder.png").mkdir()
    line = one_line_error(lambda: read_student_image(tmp_path / "folder.png"), tmp_path / "folder.png")
    assert line.endswith("is a folder, expected an image file"), line


def test_a_fifo_is_refused_without_waiting_for_a_writer(tmp_path):
    fifo = tmp_path / "student.png"
    os.mkfifo(fifo)
    # Should the reader open the FIFO and wait for a writer (holding the GIL: no thread here can help), a
    # writer in another process opens and closes it, as often as it takes (OpenImageIO tries reader after
    # reader), so the read returns and the test fails on its time instead of hanging.
    writer = subprocess.Popen(["sh", "-c", 'while :; do : > "$0"; done', str(fifo)])
    t0 = time.monotonic()
    try:
        line = one_line_error(lambda: read_student_image(fifo), fifo)
    finally:
        elapsed = time.monotonic() - t0
        writer.kill()
        writer.wait()
    assert elapsed < 1.0, f"waited {elapsed:.1f} s on a FIFO"
    assert line == f"{fifo}: not a regular file (a FIFO); an image must be a file"


def test_the_file_checked_is_the_file_decoded(tmp_path, monkeypatch):
    """A file swapped for a FIFO between the check and the decode (a student's folder being written to while
    it is graded): the decode reads the regular file that was opened and checked, not the FIFO now under
    its name, and leaves no temporary folder behind."""

    import minirt.io.images as images

    path = tmp_path / "student.png"
    write_image(path, PIXELS)
    real = images._open_regular
    writers = []

    def open_then_swap(p: Path) -> int:
        fd = real(p)
        p.unlink()
        os.mkfifo(p)
        writers.append(subprocess.Popen(["sh", "-c", 'while :; do : > "$0"; done', str(p)]))  # as for the FIFO
        return fd

    monkeypatch.setattr(images, "_open_regular", open_then_swap)
    try:
        colour, _ = read_student_image(path)
    finally:
        for w in writers:
            w.kill()
            w.wait()
    assert writers
    np.testing.assert_array_equal(colour, PIXELS)
    assert os.listdir(images._pinning_folder()) == []  # the link went with the read


def test_the_pinning_folder_goes_with_its_process_and_a_killed_one_s_with_the_next(tmp_path):
    """Each process links the files it reads from one temporary folder, removed when it exits; the folder
    of a run that was killed (SIGKILL: no exit handler ran) is removed by the next process that reads."""
    import tempfile

    dead = subprocess.Popen(["true"])
    dead.wait()
    stale = Path(tempfile.mkdtemp(prefix=f"minirt-image-{dead.pid}-"))
    (stale / "5.png").symlink_to("/proc/self/fd/5")
    write_image(tmp_path / "a.png", PIXELS)
    code = "import sys; import minirt.io.images as m; m.read_student_image(sys.argv[1]); print(m._pinning_folder())"
    p = subprocess.run([sys.executable, "-c", code, str(tmp_path / "a.png")], capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    own = Path(p.stdout.strip())
    assert own.name.startswith("minirt-image-") and not own.exists() and not stale.exists()


@pytest.mark.parametrize("name", ["zero.png", "null.tga"])
def test_a_device_is_refused_without_being_read(tmp_path, name):
    """/dev/zero behind an image's name would be read for ever; /dev/null would be empty."""
    link = tmp_path / name
    link.symlink_to("/dev/zero" if name.startswith("zero") else "/dev/null")
    t0 = time.monotonic()
    line = one_line_error(lambda: read_student_image(link), link)
    assert time.monotonic() - t0 < 1.0
    assert line == f"{link}: not a regular file (a character device); an image must be a file"


def test_a_header_claiming_100000_squared_is_refused_before_decoding(tmp_path):
    """The issue's zlib bomb: 10^10 one-bit pixels (10 GB as the 8-bit levels minirt reads) in 1.2 MB;
    decoded first, it was `internal error: MemoryError` (or the kernel's OOM killer)."""
    bomb = tmp_path / "bomb.png"
    bomb.write_bytes(claiming_png(100_000, 100_000))
    assert 1_100_000 < bomb.stat().st_size < 1_300_000
    t0 = time.monotonic()
    line = one_line_error(lambda: read_student_image(bomb), bomb)
    assert time.monotonic() - t0 < 2.0
    most = f"{LIMITS['width'][1]}x{LIMITS['height'][1]}"
    assert line == f"{bomb}: the image says it is 100000x100000, larger than any scene ({most})"


def test_the_header_is_checked_before_any_pixel_is_decoded(tmp_path, monkeypatch):
    """``before_decoding`` sees the header's claim and can refuse it: nothing is decoded after it raises
    (the grader's check against the scene and the memory, minirt.grading.grade.load_target)."""
    claim = tmp_path / "claim.png"
    claim.write_bytes(claiming_png(16384, 12000))
    seen = []

    def refuse(header) -> None:
        seen.append((header.width, header.height, header.channels, header.is_float, header.reader))
        raise MinirtError(f"{header.path}: refused")

    import minirt.io.images as images

    decoded = []
    monkeypatch.setattr(images, "_decode", lambda *a: decoded.append(a))
    with pytest.raises(MinirtError, match="refused"):
        read_student_image(claim, refuse)
    assert seen == [(16384, 12000, 1, False, "png")] and decoded == []


def test_too_many_channels_are_refused(tmp_path):
    path = tmp_path / "wide.tif"
    write_image(path, np.zeros((2, 2, MAX_CHANNELS + 1), np.float32))
    line = one_line_error(lambda: read_student_image(path), path)
    assert line == f"{path}: the image says it has {MAX_CHANNELS + 1} channels, more than {MAX_CHANNELS}"


# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("ext", [".png", ".tif", ".tga"])
@pytest.mark.parametrize("alpha", [255, 128, 1, 0])
def test_alpha_is_ignored_colours_read_as_stored(tmp_path, ext, alpha):
    """An RGBA file reads as the RGB file of the same colours, whatever its alpha: OpenImageIO alone
    multiplies the colour by alpha (128: half as bright, graded DIFFERS; 0: black)."""
    rgba = np.concatenate([PIXELS, np.full((H, W, 1), alpha, np.uint8)], axis=-1)
    path = tmp_path / f"rgba{ext}"
    write_unassociated(path, rgba)
    assert (stored_rgba(path) == rgba).all()  # the file holds these colours, as the student's tracer wrote them
    colour, is_float = read_student_image(path)
    assert not is_float and colour.dtype == np.uint8
    np.testing.assert_array_equal(colour, PIXELS)


def test_grey_with_alpha_reads_as_grey(tmp_path):
    grey = PIXELS[..., :1]
    path = tmp_path / "ya.png"
    write_unassociated(path, np.concatenate([grey, np.zeros_like(grey)], axis=-1))
    colour, _ = read_student_image(path)
    np.testing.assert_array_equal(colour, np.repeat(grey, 3, axis=-1))


def test_a_large_image_is_decoded_in_blocks_the_same(tmp_path, monkeypatch):
    """Decoding by blocks of rows (so a signal is handled between them) gives the whole image, for an
    interlaced PNG too (whose reader needs every pass) and an EXR whose data window starts below 0."""
    import minirt.io.images as images

    rng = np.random.default_rng(7)
    a = rng.integers(0, 256, (37, 53, 3), dtype=np.uint8)
    spec = oiio.ImageSpec(53, 37, 3, oiio.UINT8)
    spec.attribute("png:interlace", 1)
    out = oiio.ImageOutput.create(str(tmp_path / "i.png"))
    assert out.open(str(tmp_path / "i.png"), spec) and out.write_image(a) and out.close()
    f = rng.random((10, 20, 3)).astype(np.float32)
    spec = oiio.ImageSpec(20, 10, 3, oiio.FLOAT)
    spec.x, spec.y = 3, 5
    out = oiio.ImageOutput.create(str(tmp_path / "w.exr"))
    assert out.open(str(tmp_path / "w.exr"), spec) and out.write_image(f) and out.close()
    monkeypatch.setattr(images, "_BLOCK_BYTES", 53 * 3 * 4 * 5)  # 5 rows of the PNG at a time
    np.testing.assert_array_equal(read_student_image(tmp_path / "i.png")[0], a)
    np.testing.assert_array_equal(read_student_image(tmp_path / "w.exr")[0], f)


def test_colours_beyond_float32_are_stored_without_a_numpy_warning():
    """A scene may hold 1e308; the EXR stores float32, so it is inf there, quietly: NumPy's
    'RuntimeWarning: overflow encountered in cast' was printed raw by `minirt render`."""
    colour = np.full((2, 2, 3), 1e308)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        data, names = exr_channels(RenderResult(backend="reference", width=2, height=2, color=colour))
    assert names == ["R", "G", "B"] and np.isinf(data).all()


# ---------------------------------------------------------------------------------------------
def check_read(path: Path) -> None:
    """The colours, of the file's size and type, or one MinirtError line naming the file -- nothing else."""
    try:
        colour, is_float = read_student_image(path)
    except MinirtError as e:
        assert "\n" not in str(e) and str(e).startswith(f"{path}: "), str(e)
        return
    assert colour.ndim == 3 and colour.shape[-1] == 3 and min(colour.shape) >= 1
    assert colour.dtype == (np.float32 if is_float else np.uint8)
    if is_float:
        assert np.isfinite(colour).all()


@settings(
    max_examples=500, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(case=garbled())
def test_garbled_images_read_or_fail_in_one_line(tmp_path, case):
    ext, data = case
    path = tmp_path / f"student{ext}"
    path.write_bytes(data)
    t0 = time.monotonic()
    check_read(path)
    assert time.monotonic() - t0 < 2.0


@pytest.mark.parametrize("ext", sorted(FORMATS))
def test_every_truncation_reads_or_fails_in_one_line(tmp_path, ext):
    """Every prefix of a small image of each type (hypothesis samples them; this is all of them)."""
    data = valid_bytes(ext)
    path = tmp_path / f"cut{ext}"
    failed = 0
    for n in range(0, len(data), max(1, len(data) // 200)):
        path.write_bytes(data[:n])
        try:
            read_student_image(path)
        except MinirtError as e:
            failed += 1
            assert "\n" not in str(e) and str(e).startswith(f"{path}: "), (n, str(e))
    assert failed > 0


def test_a_message_quoting_the_file_s_bytes_is_one_line(tmp_path):
    """OpenEXR quotes a garbled attribute type's bytes in its message; not UTF-8, OpenImageIO's binding
    raised UnicodeDecodeError reading it (an internal error; hypothesis found it)."""
    path = tmp_path / "bytes.exr"
    path.write_bytes(valid_bytes(".exr").replace(b"chlist", b"chl\x80st", 1))
    line = one_line_error(lambda: read_student_image(path), path)
    assert line == f"{path}: cannot read image: a reader's message that is not text (a garbled header?)"
