"""Image and sidecar I/O. All images go through OpenImageIO; every write is atomic (minirt.io.atomic)."""

from __future__ import annotations

import atexit
import contextlib
import os
import re
import shutil
import stat
import tempfile
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import OpenImageIO as oiio

from minirt.errors import MinirtError
from minirt.io.atomic import atomic_path, stale
from minirt.model.result import TERMS, Planes, RenderResult


def write_image(path: str | Path, pixels: np.ndarray, channels: list[str] | None = None) -> None:
    """Write an (H, W, C) or (H, W) array. uint8/uint16 stay integer; floats are stored as float32."""
    path = Path(path)
    a = np.ascontiguousarray(pixels if pixels.ndim == 3 else pixels[..., None])
    h, w, c = a.shape
    if a.dtype == np.uint8:
        fmt = oiio.UINT8
    elif a.dtype == np.uint16:
        fmt = oiio.UINT16
    else:
        a, fmt = a.astype(np.float32, copy=False), oiio.FLOAT
    spec = _spec(w, h, c, fmt, path, channels)
    with atomic_path(path) as tmp:
        out = oiio.ImageOutput.create(str(tmp))
        if out is None:
            raise MinirtError(f"{path}: cannot write image: {oiio.geterror()}")
        why = finished(out, tmp, written(out.open(str(tmp), spec) and out.write_image(a), out))
        if why:
            raise MinirtError(f"{path}: cannot write image: {why}")


def written(ok: bool, out: Any) -> str | None:
    """None when an OpenImageIO write succeeded, else why not (one line). OpenImageIO's PNG writer
    records a short write -- a full disk -- as an error but still returns True: its error flag decides.
    (Not other formats': the TIFF writer flags its Exif directory as failed in a whole, readable file;
    ``finished`` reads every image's end back.)"""
    if ok and not (out.has_error and out.format_name() == "png"):
        return None
    lines = out.geterror().splitlines()
    return " ".join(lines[0].split()) if lines else "unknown error"


def finished(out: Any, tmp: Path, why: str | None = None) -> str | None:
    """Close ``out``, an OpenImageIO output writing the file ``tmp`` (``why``: an earlier write's
    failure); None when the whole image reached the file, else why not (one line)."""
    why = written(out.close(), out) or why
    return why or _whole(tmp)


PNG_END = b"\x00\x00\x00\x00IEND\xaeB`\x82"  # a PNG's last chunk: IEND, empty, its CRC
CUT_SHORT = "the file was cut short: fewer bytes reached the disk than the image has (a full disk?)"


def _whole(tmp: Path) -> str | None:
    """OpenImageIO loses the error of the writes it makes at close (the last buffer): a PNG or an EXR
    cut short at a full disk's end still "succeeds" (measured with OpenImageIO 3.2 under RLIMIT_FSIZE:
    an 8,192-byte prefix of a 10 KB PNG, no error). So a PNG must end with its IEND chunk (it is written
    in order, never sought back into); an EXR's first and last rows must read back (each a chunk of its
    own; the offsets table is read on opening). A few bytes or two chunks read: no decoding of the image."""
    if tmp.suffix.lower() == ".png":
        with open(tmp, "rb") as f:
            f.seek(0, os.SEEK_END)
            f.seek(max(0, f.tell() - len(PNG_END)))
            return None if f.read() == PNG_END else CUT_SHORT
    inp = oiio.ImageInput.open(str(tmp))
    if inp is None:
        return CUT_SHORT
    try:
        s = inp.spec()
        ok = inp.read_scanline(s.y, 0) is not None and inp.read_scanline(s.y + s.height - 1, 0) is not None
    finally:
        inp.close()
    return None if ok else CUT_SHORT


def _spec(w: int, h: int, c: int, fmt: Any, path: Path, channels: list[str] | None = None) -> Any:
    spec = oiio.ImageSpec(w, h, c, fmt)
    if channels:
        spec.channelnames = tuple(channels)
    # A fixed timestamp: OpenImageIO otherwise stamps the write time, and the same render must give
    # bit-identical files.
    spec.attribute("DateTime", "2000:01:01 00:00:00")
    if path.suffix.lower() == ".exr":
        spec.attribute("compression", "zip")
    return spec


def write_tiles(tiles, width: int, height: int, out_dir: str | Path, stem: str, timings: bool = False):
    """Write a render that arrives as tiles of whole rows ((first row, RenderResult) from top to bottom,
    as ``Tracer.tiles`` gives them) to `stem.png`, `stem.exr` and `stem.json`, each tile's scanlines as
    it comes: the image is never whole in memory. The same files as ``write_result`` of the assembled
    image (tested), for the exercise's default output rules. Returns (paths, the last tile's result)."""
    out_dir = Path(out_dir)
    paths = {"png": out_dir / f"{stem}.png", "exr": out_dir / f"{stem}.exr", "json": out_dir / f"{stem}.json"}
    last = None
    with contextlib.ExitStack() as stack:
        outs = {}
        for key in ("png", "exr"):
            tmp = stack.enter_context(atomic_path(paths[key]))
            outs[key] = (tmp, None)

        def abandon(exc_type, exc, tb) -> bool:  # an error or Ctrl-C mid-image: close before the unlink,
            if exc_type is not None:  # quietly (libpng complains about an image without its rows)
                with _quiet_stderr():
                    for _, out in outs.values():
                        if out is not None:
                            out.close()
            return False

        stack.push(abandon)

        def opened(key: str, channels: int, fmt: Any, names: list[str] | None) -> Any:
            tmp, out = outs[key]
            if out is None:
                out = oiio.ImageOutput.create(str(tmp))
                if out is None or not out.open(str(tmp), _spec(width, height, channels, fmt, tmp, names)):
                    why = oiio.geterror() if out is None else out.geterror()
                    raise MinirtError(f"{paths[key]}: cannot write image: {why}")
                outs[key] = (tmp, out)
            return out

        buf = None  # the EXR's rows, converted a block at a time (write_exr): no whole-tile float32 copy
        for y0, tile in tiles:
            c8 = np.ascontiguousarray(tile.color8())
            png = opened("png", c8.shape[-1], oiio.UINT8, None)
            why = written(png.write_scanlines(y0, y0 + tile.height, 0, c8), png)
            if why:
                raise MinirtError(f"{paths['png']}: cannot write image: {why}")
            blocks, names = _exr_layout(tile)
            exr = opened("exr", len(names), oiio.FLOAT, names)
            if buf is None:
                buf = np.empty((min(EXR_BLOCK_ROWS, height), width, len(names)), np.float32)
            _write_rows(exr, paths["exr"], blocks, y0, tile.height, buf)
            last = tile
        for key, (_, out) in outs.items():
            why = "no rows" if out is None else finished(out, outs[key][0])
            if why:
                raise MinirtError(f"{paths[key]}: cannot write image: {why}")
    assert last is not None
    meta = dict(last.meta)
    write_json(
        paths["json"], sidecar(RenderResult(backend=last.backend, width=width, height=height, meta=meta), timings)
    )
    return paths, last


def read_image(path: str | Path) -> tuple[np.ndarray, list[str]]:
    """Read any image as float32 (H, W, C) with its channel names."""
    return _read(path, oiio.FLOAT)


def read_image_u8(path: str | Path) -> np.ndarray:
    """Read an 8-bit image's integer values (H, W, C) exactly."""
    return _read(path, oiio.UINT8)[0]


def _read(path: str | Path, fmt) -> tuple[np.ndarray, list[str]]:
    """The pixels as ``fmt`` and the channel names, or one line saying why there are none (a truncated or
    corrupt file reads as None or as fewer values than its header promises; libpng's own complaint is
    silenced)."""
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise MinirtError(f"{path}: cannot read image: {_error(oiio)}")
    try:
        spec = inp.spec()
        with _quiet_stderr():
            data = inp.read_image(0, 0, 0, spec.nchannels, fmt)
        a = None if data is None else np.asarray(data)
        if a is None or a.size != spec.height * spec.width * spec.nchannels:
            why = " ".join((_error(inp) or "").split())[:200] or "fewer pixels than its header says"
            raise MinirtError(f"{path}: truncated or corrupt image ({why})")
        return a.reshape(spec.height, spec.width, spec.nchannels), list(spec.channelnames)
    finally:
        inp.close()


def _exr_layout(result: RenderResult) -> tuple[list[Callable[[slice], np.ndarray]], list[str]]:
    """The EXR's channels: their names, and per block of channels (a vector is one block, 3x faster to
    convert than plane by plane) a function giving its rows (a slice) as an (n, W, k) array -- a view of
    the buffer where there is one, so a block of rows is converted without a whole-image copy."""
    blocks: list[Callable[[slice], np.ndarray]] = []
    names: list[str] = []

    def add(prefix: str, a: np.ndarray | None, comps: str = "RGB") -> None:
        if a is None:
            return
        a = np.asarray(a)
        if a.ndim == 2:
            names.append(prefix)
            blocks.append(lambda rows: a[rows, :, None])
        else:
            names.extend(f"{prefix}.{comp}" if prefix else comp for comp in comps)
            blocks.append(lambda rows: a[rows, :, : len(comps)])

    def vector(prefix: str, name: str, comps: str = "RGB") -> None:
        # A vector as the result holds it (RenderResult.held): three arrays of their own (Planes) are
        # converted each into its channel, never stacked (a stack of a block's rows first took 3x longer:
        # 200 balls at 1024^2, 60 against 20 ms for the eight vectors).
        v = result.held(name)
        if not isinstance(v, Planes):
            add(prefix, v, comps)
            return
        names.extend(f"{prefix}.{comp}" if prefix else comp for comp in comps)
        blocks.extend((lambda rows, c=c: c[rows, :, None]) for c in v)

    vector("", "color")
    if result.hit is not None:
        hit, ids, t = result.hit, result.shape_id, result.t
        names.append("hit")
        blocks.append(lambda rows: hit[rows, :, None])
        names.append("id")  # exact in float64, then rounded once like every channel
        blocks.append(lambda rows: ids[rows, :, None].astype(np.float64))
        names.append("t")  # 0 on a miss: EXR readers choke on inf
        blocks.append(lambda rows: np.where(hit[rows], t[rows], 0.0)[..., None])
        vector("P", "position", "XYZ")
        vector("N", "normal", "XYZ")
    for term in TERMS:
        vector(term, term)
    for key in sorted(result.aux):
        add(f"aux.{key}", result.aux[key], "XYZ")
    return blocks, names


def _fill(blocks: list[Callable[[slice], np.ndarray]], rows: slice, out: np.ndarray) -> np.ndarray:
    """The rows' channels converted straight into ``out`` ((n, W, channels) float32), block by block."""
    i = 0
    with np.errstate(over="ignore"):  # a value beyond float32 (a colour of 1e308) is stored as inf, quietly:
        for block in blocks:  # the scene allows it, and NumPy's RuntimeWarning is no message for a user
            a = block(rows)
            out[..., i : i + a.shape[-1]] = a
            i += a.shape[-1]
    return out


def exr_channels(result: RenderResult) -> tuple[np.ndarray, list[str]]:
    """All of a result's buffers as one multi-channel float32 image (the EXR layout, which stores
    float32): each buffer converted straight into its channel, one pass, no float64 stack in between
    -- the same values (one rounding from float64 either way) in a third of the time and memory
    (2048^2: 2.2 s -> 0.4 s; the stack and its conversion were most of a large render's time)."""
    blocks, names = _exr_layout(result)
    h, w = blocks[0](slice(None)).shape[:2]
    return _fill(blocks, slice(0, h), np.empty((h, w, len(names)), np.float32)), names


# Rows of the EXR converted and handed to OpenImageIO at a time: a multiple of the 16-row blocks its zip
# compression works in (each handed over whole, compressed on OpenEXR's threads), and small enough (64 rows
# of a 1024-wide render's 27 channels: 7 MB) to stay in the caches and to be the only float32 copy there is.
EXR_BLOCK_ROWS = 64


def write_exr(path: str | Path, result: RenderResult, stop: threading.Event | None = None) -> None:
    """Write a result's buffers as `path`, an EXR (``exr_channels``' layout), a block of rows at a time
    (``EXR_BLOCK_ROWS``): the same file as ``write_image(path, *exr_channels(result))`` without the
    whole-image float32 copy. ``stop``: when set, the write is abandoned between blocks (no file)."""
    path = Path(path)
    blocks, names = _exr_layout(result)
    h, w = blocks[0](slice(None)).shape[:2]
    buf = np.empty((min(EXR_BLOCK_ROWS, h), w, len(names)), np.float32)
    with atomic_path(path) as tmp:
        out = oiio.ImageOutput.create(str(tmp))
        if out is None or not out.open(str(tmp), _spec(w, h, len(names), oiio.FLOAT, path, names)):
            raise MinirtError(f"{path}: cannot write image: {oiio.geterror() if out is None else out.geterror()}")
        try:
            _write_rows(out, path, blocks, 0, h, buf, stop)
        except BaseException:
            out.close()  # before the temporary file goes (OpenEXR says nothing of the missing rows; and no
            raise  # _quiet_stderr here: this may run on the background writer, and fd 2 is the process's)
        why = finished(out, tmp)
        if why:
            raise MinirtError(f"{path}: cannot write image: {why}")


def _write_rows(out: Any, path: Path, blocks, y0: int, height: int, buf: np.ndarray, stop=None) -> None:
    """Rows 0 .. height of ``blocks`` (``_exr_layout``) to the open image ``out`` at rows y0 .., converted
    into ``buf`` a block of its rows at a time; ``stop``: as ``write_exr``'s."""
    for y in range(0, height, len(buf)):
        if stop is not None and stop.is_set():
            raise _Abandoned(path)
        n = min(len(buf), height - y)
        why = written(out.write_scanlines(y0 + y, y0 + y + n, 0, _fill(blocks, slice(y, y + n), buf[:n])), out)
        if why:
            raise MinirtError(f"{path}: cannot write image: {why}")


class _Abandoned(Exception):
    """A background write given up because the run is stopping (its file is not made)."""


def write_result(
    result: RenderResult, out_dir: str | Path, stem: str, timings: bool = False, rules: Any = None
) -> dict[str, Path]:
    """Write `stem.png` (the 8-bit bitmap, written as ``rules``' output rules say: encoding, gamma,
    layout; minirt.model.bitmap), `stem.exr` (every buffer, in the scene's layout) and `stem.json` (metadata;
    with ``timings`` also the run's timings, which makes it differ from run to run).

    Inside ``background_writes()`` the paths are returned at once and the files written by a thread of
    their own, while the caller goes on (the hazard warnings, the next backend)."""
    out_dir = Path(out_dir)
    paths: dict[str, Path] = {}
    color = result.held("color")  # not stacked when it is Planes (RenderResult): the files take its components
    if color is not None:
        paths["png"] = out_dir / f"{stem}.png"
    if result.hit is not None or color is not None:
        paths["exr"] = out_dir / f"{stem}.exr"
    paths["json"] = out_dir / f"{stem}.json"
    doc = sidecar(result, timings)  # now: the caller may add to the metadata once this returns
    if _writer is None:
        _write_files(result, paths, doc, rules)
    else:
        _writer.submit(result, paths, doc, rules)
    return paths


def _write_files(
    result: RenderResult,
    paths: dict[str, Path],
    doc: dict[str, Any],
    rules: Any,
    stop: threading.Event | None = None,
    files: tuple[str, ...] = ("png", "exr", "json"),
) -> None:
    """Write ``files`` of a result (those ``paths`` has)."""
    from minirt.model import bitmap

    if "png" in files and "png" in paths:
        plain = rules is None or bitmap.is_default(rules)
        write_image(paths["png"], result.color8() if plain else bitmap.bitmap(result.color, rules))
    if "exr" in files and "exr" in paths:
        write_exr(paths["exr"], result, stop)
    if "json" in files:
        write_json(paths["json"], doc)


class _Writer:
    """The threads of ``background_writes``: two, one result's EXR (the longest) on one while its PNG and
    JSON go on the other, results in the order given."""

    def __init__(self) -> None:
        from concurrent.futures import ThreadPoolExecutor

        self.pool = ThreadPoolExecutor(max_workers=2, thread_name_prefix="minirt-writes")
        self.stop = threading.Event()
        self.futures: list[Any] = []

    def submit(self, result: RenderResult, paths: dict[str, Path], doc: dict[str, Any], rules: Any) -> None:
        for files in (("exr",), ("png", "json")):
            self.futures.append(self.pool.submit(_write_files, result, paths, doc, rules, self.stop, files))

    def finish(self, failed: bool) -> None:
        if failed:  # an error or Ctrl-C in the caller: what is not written yet is not written
            self.stop.set()
        self.pool.shutdown(wait=True, cancel_futures=failed)
        if failed:  # the caller's error is the one to report
            return
        for f in self.futures:
            if f.exception() is not None:
                raise f.exception()


_writer: _Writer | None = None


@contextlib.contextmanager
def background_writes() -> Iterator[None]:
    """Inside the block, ``write_result`` hands its files to two threads and returns at once; leaving the
    block waits for every file and raises the first write's error. The files' encoding and compression
    (OpenImageIO, zlib) run outside Python's lock, so a render's files are written while the command
    goes on: the offset-hazard warnings of a 200-ball 1024^2 render take as long as its EXR
    (benchmarks/README.md). An error or Ctrl-C in the block abandons the writes not yet done (no file
    appears half-written: each is atomic)."""
    global _writer
    if _writer is not None:  # nested: the outer block waits
        yield
        return
    _writer = _Writer()
    failed = True
    try:
        yield
        failed = False
    finally:
        writer, _writer = _writer, None
        writer.finish(failed)


def sidecar(result: RenderResult, timings: bool = False) -> dict[str, Any]:
    """The metadata a render leaves beside its images. Without ``timings`` none (anywhere in the tree),
    so the same command writes the same bytes; timings stay in ``result.meta`` for check, report and
    sweep either way."""
    return {
        "backend": result.backend,
        "status": result.status,
        "reason": result.reason,
        "width": result.width,
        "height": result.height,
        **(result.meta if timings else _without_timings(result.meta)),
    }


def _without_timings(v: Any) -> Any:
    if isinstance(v, dict):
        return {k: _without_timings(x) for k, x in v.items() if k != "timings"}
    if isinstance(v, list):
        return [_without_timings(x) for x in v]
    return v


def write_json(path: str | Path, data: Any) -> None:
    """Write a JSON document: strict, versioned, atomic (minirt.io.jsonout, the one place that does)."""
    from minirt.io import jsonout

    jsonout.write_json(path, data)


# Formats a graded image may come in (OpenImageIO reads each; the extension picks the reader).
STUDENT_EXTENSIONS = (".png", ".bmp", ".ppm", ".pgm", ".pnm", ".pfm", ".tga", ".tif", ".tiff", ".exr")

# The most channels a graded image may have: minirt's own EXR has 27, a student's image 1 to 4. Only the
# first three are decoded, but a reader holds a whole scanline of every channel at once.
MAX_CHANNELS = 256

# Rows decoded per read: a block of about 16 MiB, so a signal is handled between blocks (a C reader holds
# Python's signal handlers off until it returns) and a large image never needs a second copy.
_BLOCK_BYTES = 16 << 20


@dataclass(frozen=True)
class ImageHeader:
    """What an image file says about itself before any pixel is decoded."""

    path: Path
    width: int
    height: int
    channels: int
    is_float: bool  # float or 16-bit: decoded as float32; else 8-bit levels
    reader: str  # OpenImageIO's name for the format ("png", "openexr", ...)
    sixteen_bit: bool = False  # 16-bit integers (is_float too; read_student_image: maybe 8-bit levels)


def read_student_image(
    path: str | Path,
    before_decoding: Callable[[ImageHeader], None] | None = None,
    notes: list[str] | None = None,
    nonfinite: bool = False,
) -> tuple[np.ndarray, bool]:
    """An image another tracer wrote, as (rows, columns, 3): uint8 levels for 8-bit files, float32
    for float and 16-bit files (the bool says which). Grey images are repeated into R, G and B; an
    alpha channel is ignored: colours are read as stored (OpenImageIO would otherwise multiply them by
    alpha), and alpha itself is never decoded. A 16-bit file whose every value is a multiple of 257 holds
    an 8-bit image (level k stored as 257 k, k/255 exactly: the usual widening) and is read as those 8-bit
    levels, a sentence saying so appended to ``notes`` (a grade's notes).

    The file is untrusted: it must be a regular file (a FIFO, a device or a socket is refused without
    being opened, so nothing blocks), it is opened once, without blocking, and decoded from that open
    file; its header's size is checked against the largest scene (``minirt.model.scene.LIMITS``) and
    ``MAX_CHANNELS``, then by ``before_decoding`` (the grader's check against the scene and the memory),
    before a pixel is decoded. Any problem is one MinirtError line naming the file; so is a float image
    holding NaN or infinite values, unless ``nonfinite`` (a program's hard case counts such pixels)."""
    path = Path(path)
    fd = _open_regular(path)
    try:
        if path.suffix.lower() not in STUDENT_EXTENSIONS:
            raise MinirtError(
                f"{path}: unsupported image type {path.suffix or '(none)'} (use {', '.join(STUDENT_EXTENSIONS)})"
            )
        with _opened_name(fd, path.suffix) as opened, _quiet_stderr():  # libpng and friends print their own
            colour, is_float, held = _read_student_image(path, opened, before_decoding, nonfinite)  # complaint; ours
            if held and notes is not None:
                notes.append(
                    "the image is 16-bit, every value a multiple of 257: the 8-bit image it holds (level k stored "
                    "as 257 k) is graded as 8-bit levels"
                )
            return colour, is_float
    finally:
        os.close(fd)


def _held_levels(colour: np.ndarray) -> np.ndarray | None:
    """The 8-bit levels a 16-bit image (as OpenImageIO's floats v/65535) holds when every value v is a
    multiple of 257, else None. v is recovered exactly: float32 v/65535 is within 2^-24 relative of it,
    far less than the 0.5/65535 that rounding v*65535 to an integer allows."""
    v = np.rint(colour * np.float32(65535)).astype(np.uint32)
    if np.any(v % 257):
        return None
    return (v // 257).astype(np.uint8)


_KINDS = {stat.S_IFIFO: "a FIFO", stat.S_IFCHR: "a character device", stat.S_IFBLK: "a block device"}


def _file_kind(mode: int) -> str:
    return _KINDS.get(stat.S_IFMT(mode), "a socket" if stat.S_ISSOCK(mode) else "not a file")


def _open_regular(path: Path) -> int:
    """A read-only descriptor of ``path``, a regular file, or one MinirtError line. Whatever else it is
    is refused from ``stat`` before any open (opening a FIFO waits for a writer; a device may do
    anything on open); the open itself does not block (O_NONBLOCK), and its ``fstat`` is checked
    again: a file swapped for a FIFO in between is refused, not waited on."""
    try:
        st = path.stat()
    except FileNotFoundError:
        raise MinirtError(f"{path}: no such image file") from None
    except OSError as e:
        raise MinirtError(f"{path}: cannot read: {e.strerror or e}") from None
    if stat.S_ISDIR(st.st_mode):
        raise MinirtError(f"{path}: is a folder, expected an image file")
    if not stat.S_ISREG(st.st_mode):
        raise MinirtError(f"{path}: not a regular file ({_file_kind(st.st_mode)}); an image must be a file")
    flags = os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOCTTY", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(path, flags)
    except OSError as e:
        raise MinirtError(f"{path}: cannot read: {e.strerror or e}") from None
    st = os.fstat(fd)
    if not stat.S_ISREG(st.st_mode):
        os.close(fd)
        raise MinirtError(f"{path}: not a regular file ({_file_kind(st.st_mode)}); an image must be a file")
    return fd


_PINNED = "minirt-image-"  # the temporary folder of _opened_name: PREFIX<pid>-XXXX, one per process
_pin_folder: dict[int, str] = {}  # pid -> this process's folder (a forked child makes its own)


@contextlib.contextmanager
def _opened_name(fd: int, suffix: str) -> Iterator[str | None]:
    """A name, ending in ``suffix``, that opens the very file behind ``fd``, so the reader decodes the file
    that was checked, not whatever the path names a moment later: on Linux a link to /proc/self/fd/N in
    this process's private temporary folder (the suffix picks the reader and its error messages, as for
    the path itself); None where there is no /proc. The link goes when the read ends, the folder when
    the process does; the folders of killed runs are removed by the next process that reads an image.
    (One folder per process, not per read: removing a folder costs milliseconds, a link microseconds.)"""
    proc = f"/proc/self/fd/{fd}"
    if not os.path.exists(proc):
        yield None
        return
    name = os.path.join(_pinning_folder(), f"{fd}{suffix.lower()}")  # an open fd's number is unique
    os.symlink(proc, name)
    try:
        yield name
    finally:
        with contextlib.suppress(OSError):
            os.unlink(name)


def _pinning_folder() -> str:
    pid = os.getpid()
    if pid not in _pin_folder:
        for q in stale(Path(tempfile.gettempdir()), re.compile(re.escape(_PINNED) + r"(\d+)-")):
            shutil.rmtree(q, ignore_errors=True)
        _pin_folder[pid] = tempfile.mkdtemp(prefix=f"{_PINNED}{pid}-")
        atexit.register(_remove_pinning_folder, pid)
    return _pin_folder[pid]


def _remove_pinning_folder(pid: int) -> None:
    if os.getpid() == pid:  # not a forked child's exit: the folder is its parent's
        shutil.rmtree(_pin_folder.pop(pid, ""), ignore_errors=True)


def _read_student_image(
    path: Path, opened: str | None, before_decoding: Callable[[ImageHeader], None] | None, nonfinite: bool = False
) -> tuple[np.ndarray, bool, bool]:
    """(colour, is_float, whether a 16-bit file's 8-bit levels were read: ``_held_levels``)."""
    _error(oiio)  # a stale error of an earlier read must not be taken for this file's
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)  # colours as stored: not multiplied by alpha on read
    inp = oiio.ImageInput.open(opened or str(path), config)
    if inp is None:
        raise MinirtError(f"{path}: cannot read image: {_one_line(_error(oiio), opened, path)}")
    try:
        header = _header(path, inp)
        if before_decoding is not None:
            before_decoding(header)
        a = _decode(path, inp, header, opened)
    finally:
        inp.close()
    if err := _error(oiio):  # a reader that filled in what a truncated file lacked says so here
        raise MinirtError(f"{path}: cannot read image: {_one_line(err, opened, path)}")
    colour = a if a.shape[-1] == 3 else np.repeat(a, 3, axis=-1)
    if header.is_float and not nonfinite and not np.isfinite(colour).all():
        raise MinirtError(f"{path}: the image holds NaN or infinite values")
    levels = _held_levels(colour) if header.sixteen_bit else None
    return (colour, header.is_float, False) if levels is None else (levels, False, True)


def _header(path: Path, inp: Any) -> ImageHeader:
    """The header, checked: a flat image of 1 to ``MAX_CHANNELS`` channels, no side over the largest
    scene's."""
    from minirt.model.scene import LIMITS

    spec = inp.spec()
    w, h, c = spec.width, spec.height, spec.nchannels
    if w < 1 or h < 1 or c < 1:
        raise MinirtError(f"{path}: empty image")
    if spec.deep or spec.depth > 1:
        raise MinirtError(f"{path}: a {'deep' if spec.deep else 'volume'} image; expected a flat picture")
    most = LIMITS["width"][1], LIMITS["height"][1]
    if w > most[0] or h > most[1]:
        raise MinirtError(f"{path}: the image says it is {w}x{h}, larger than any scene ({most[0]}x{most[1]})")
    if c > MAX_CHANNELS:
        raise MinirtError(f"{path}: the image says it has {c} channels, more than {MAX_CHANNELS}")
    is_float = spec.format.basetype in (oiio.FLOAT, oiio.HALF, oiio.DOUBLE) or spec.format.size() > 1
    return ImageHeader(path, w, h, c, is_float, inp.format_name(), spec.format.basetype == oiio.UINT16)


def _decode(path: Path, inp: Any, header: ImageHeader, opened: str | None) -> np.ndarray:
    """The first three channels (grey: the first), block by block of rows into one array."""
    w, h = header.width, header.height
    channels = 3 if header.channels >= 3 else 1
    dtype, fmt = (np.float32, oiio.FLOAT) if header.is_float else (np.uint8, oiio.UINT8)
    out = np.empty((h, w, channels), dtype)
    y0 = inp.spec().y  # an EXR's data window may start elsewhere than row 0
    rows = max(1, _BLOCK_BYTES // (w * header.channels * 4))
    for top in range(0, h, rows):
        n = min(rows, h - top)
        data = inp.read_scanlines(0, 0, y0 + top, y0 + top + n, 0, 0, channels, fmt)
        if data is None or inp.has_error:
            raise MinirtError(f"{path}: cannot read image: {_one_line(_error(inp), opened, path)}")
        block = np.asarray(data)
        if block.size != n * w * channels:
            raise MinirtError(f"{path}: the file is truncated (rows {top} to {top + n} of {h} hold too few values)")
        out[top : top + n] = block.reshape(n, w, channels)
    return out


@contextlib.contextmanager
def _quiet_stderr():
    """Silence what C libraries write to file descriptor 2 (Python's own stderr is untouched)."""
    try:
        sys_err = os.dup(2)
    except OSError:
        yield
        return
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 2)
            yield
    finally:
        os.dup2(sys_err, 2)
        os.close(sys_err)


def _error(source: Any) -> str:
    """``source.geterror()`` (OpenImageIO, or an ImageInput), whose message quotes the file's own bytes
    (a garbled header's text) and is then not always UTF-8, which the binding cannot decode."""
    try:
        return source.geterror()
    except UnicodeDecodeError:
        return "a reader's message that is not text (a garbled header?)"


def _one_line(text: str, opened: str | None = None, path: Path | None = None) -> str:
    """A reader's message on one line, the file named by its path (not /proc/self/fd/N)."""
    if opened:
        text = str(text).replace(opened, str(path))
    return " ".join(str(text).split())[:300] or "unknown error"
