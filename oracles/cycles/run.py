"""Running Blender: which Python has ``bpy``, its version, one job in a child process, its EXRs read back.

Cycles runs in a child process, never in minirt's own: ``bpy`` 5.0.1 requires NumPy < 2 while minirt's
OpenImageIO 3.2 and colour-science 0.4.7 require NumPy >= 2, so ``bpy`` cannot even be installed beside
them (pip downgrades NumPy and breaks both); and it bundles its own OpenImageIO, USD and OpenEXR, which
would share one process with minirt's. So Blender lives in a Python environment of its own (the set-up's
``.venv/blender``; see ``blender_python``). Being a process of its own also lets a check run it beside the
other backends.

A render is a job handed to ``PYTHON inside_blender.py --serve`` (``run_job``): a Blender process that
serves jobs one after another, each from a fresh empty file (``read_factory_settings``), so its passes hold
a new process's pixels (tested; the EXRs' headers hold the date and the render time either way).
Importing ``bpy`` costs ~0.55 CPU-s, the price of every render when each had a process of its own (a check
of the bundled scenes runs eight). The processes are started as renderers are (minirt.jobs.processes: a
session of their own, killed with minirt), kept idle between jobs (~300 MB resident each), one per render
running at once, and end when minirt closes their input at its exit. A job that fails leaves its process
serving; one that times out, crashes or exits takes it with it (the next job starts another), with the
one-line reason a one-job process gave.
"""

from __future__ import annotations

import atexit
import contextlib
import functools
import json
import os
import queue
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from minirt.jobs import processes

SCRIPT = Path(__file__).with_name("inside_blender.py")
BPY_VERSION = "5.0.1"  # the version the conventions and tolerances were measured with (module docstring)
ENV = "MINIRT_BLENDER_PYTHON"
INSTALL_HINT = (
    f"Blender's Python module is not installed: python3 -m venv .venv/blender && .venv/blender/bin/pip install "
    f"bpy=={BPY_VERSION} (about 1 GB), or set {ENV} to a Python that has bpy {BPY_VERSION}"
)
TMP_PREFIX = "minirt-blender-"  # Blender's own $TMPDIR (_Blender), $TMPDIR/minirt-blender-<minirt's pid>-XXXX
MARK = "minirt-cycles "  # the child's line of JSON on standard output starts with this


class CyclesError(Exception):
    """Blender failed; the message is one line."""


def blender_python() -> Path | None:
    """The Python to run Blender with: $MINIRT_BLENDER_PYTHON if set; else the set-up's environment
    ``blender`` inside minirt's own (``sys.prefix``/blender: .venv/blender, README: Set-up); else minirt's
    own Python when ``bpy`` is importable there (a Blender-bundled Python, or an environment with NumPy < 2)."""
    given = os.environ.get(ENV)
    if given:
        return Path(given)
    for sub in ("bin/python", "Scripts/python.exe"):
        p = Path(sys.prefix) / "blender" / sub
        if p.is_file():
            return p
    import importlib.util

    return Path(sys.executable) if importlib.util.find_spec("bpy") is not None else None


def _one_line(text: str) -> str:
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    errors = [ln for ln in lines if "Error" in ln or "error" in ln]
    return " ".join((errors[-1] if errors else lines[-1] if lines else "no output").split())[:300]


@functools.lru_cache(maxsize=8)
def _version(exe: str, mtime_ns: int, size: int) -> str | RuntimeError:
    """Blender's version string, once per process and executable, asked of a new Blender process that then
    serves this process's first render (importing bpy costs ~0.45 s: once, not for the question and again
    for the render); a failure is cached too (returned, not raised)."""
    try:
        blender = _Blender(exe)
    except CyclesError as e:
        return RuntimeError(str(e))
    try:
        said = blender.ask("--version", 120)
    except CyclesError as e:
        why = str(e).removeprefix("Blender failed: ")
        return RuntimeError(f"'{exe}' did not import bpy in 120 s" if "timed out" in why else
                            f"'{exe}' cannot import bpy: {why}")  # fmt: skip
    if "blender" not in said:
        blender.close()
        return RuntimeError(f"'{exe}' cannot import bpy: it answered {_one_line(json.dumps(said))}")
    if blender.p.returncode is None:
        with _lock:
            _idle.append(blender)
    return str(said["blender"])


def version() -> str:
    """Blender's version ("5.0.1"), or raises with a one-line reason (not installed, not runnable)."""
    exe = blender_python()
    if exe is None:
        raise FileNotFoundError(INSTALL_HINT)
    try:
        st = os.stat(exe)
    except OSError as e:
        raise FileNotFoundError(f"{ENV} or .venv/blender names {exe}, which cannot be read: {e.strerror}") from None
    v = _version(str(exe), st.st_mtime_ns, st.st_size)
    if isinstance(v, Exception):
        raise v
    if v != BPY_VERSION:
        raise RuntimeError(f"bpy {BPY_VERSION} is required, {exe} has Blender {v}")
    return v


def _said(stdout: str) -> dict[str, Any] | None:
    for line in reversed(stdout.splitlines()):
        if line.startswith(MARK):
            try:
                return json.loads(line[len(MARK) :])
            except ValueError:
                return None
    return None


def run_job(job: dict[str, Any], folder: Path, timeout: float) -> dict[str, Any]:
    """Run one job in Blender (``folder``: where its files go) on an idle Blender process, or a new one;
    Blender's own report (version, timings) plus the wall time. Raises CyclesError with one line when
    Blender fails, crashes or times out."""
    exe = blender_python()
    if exe is None:
        raise FileNotFoundError(INSTALL_HINT)
    path = folder / "job.json"
    try:
        path.write_text(json.dumps(job), encoding="utf-8")
    except OSError as e:  # a full disk: the error names the file (a write's own error names none)
        raise OSError(e.errno, e.strerror, str(path)) from None
    t0 = time.perf_counter()
    with _lock:
        blender = next((b for b in reversed(_idle) if b.exe == str(exe)), None)
        if blender is not None:
            _idle.remove(blender)
    if blender is None or blender.p.poll() is not None:  # none idle, or it died idle (killed from outside)
        if blender is not None:
            blender.close()
        blender = _Blender(str(exe))
    try:
        said = blender.ask(path, timeout)
    finally:  # kept after a job's own failure; gone after a time-out, a crash or an exit
        if blender.p.returncode is None:
            with _lock:
                _idle.append(blender)
    return {**said, "wall": time.perf_counter() - t0}


ZSTD_FRAME = b"\x28\xb5\x2f\xfd"  # a zstd frame's magic number: Blender 5 compresses its files so
ZSTD_SEEK_TABLE_END = b"\xb1\xea\x92\x8f"  # the seekable format's last 4 bytes (Blender's compressed files)
BLEND_END = b"ENDB"  # the code of an uncompressed .blend's last block (its header: at most 32 bytes)


def whole_blend(path: Path) -> bool:
    """Does the .blend Blender saved end as one does? Blender can lose the error of its last write (a
    file-size limit, which fails writes as a full disk does, cut a 660 KB file at 614,400 bytes, and
    Blender said it saved), so the end is looked at: a compressed file ends with its seek table's magic
    number, an uncompressed one with its ENDB block."""
    with open(path, "rb") as f:
        head = f.read(len(ZSTD_FRAME))
        f.seek(0, os.SEEK_END)
        f.seek(max(0, f.tell() - 32))
        tail = f.read()
    if head == ZSTD_FRAME:
        return tail.endswith(ZSTD_SEEK_TABLE_END)
    return head == b"BLEN" and BLEND_END in tail


DONE = "minirt-cycles-done"  # the line after each job's answer: the process serves the next one
_idle: list[_Blender] = []
_lock = threading.Lock()


_every: set[_Blender] = set()  # every Blender process not yet closed, idle or not


@atexit.register
def _close_all() -> None:
    """At minirt's exit, the Blender processes end (their input closed), their $TMPDIR removed: the idle
    ones, and one an interrupt caught in the middle of a job or of the version question."""
    with _lock:
        left = list(_every)
    for b in left:
        b.close()


class _Blender:
    """One ``inside_blender.py --serve`` process: job paths in, a line of JSON and ``DONE`` out per job."""

    def __init__(self, exe: str):
        self.exe = exe
        # Blender's standard error, read back when a job fails; open as long as the process lives (close())
        self.err = tempfile.TemporaryFile()  # noqa: SIM115
        # Blender's $TMPDIR: a folder of minirt's own (it makes blender_XXXXXX there when it starts and
        # removes it only when it exits by itself: every time-out or interrupt, which kills it, left one),
        # removed when this process is closed, or by the next run if minirt was killed (processes).
        self.tmp = processes.new_temporary_folder(TMP_PREFIX)
        try:
            self.p = processes.spawn([exe, str(SCRIPT), "--serve"], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=self.err, env={**os.environ, "TMPDIR": str(self.tmp)})  # fmt: skip
        except OSError as e:
            self.err.close()
            shutil.rmtree(self.tmp, ignore_errors=True)
            raise CyclesError(f"cannot run '{exe}': {e.strerror or e}") from None
        processes.track(self.p)
        with _lock:
            _every.add(self)
        self.told = 0  # the bytes of its standard error that earlier jobs' messages covered
        self.lines: queue.Queue = queue.Queue()
        threading.Thread(target=self._read, daemon=True, name="minirt-blender-out").start()

    def _read(self) -> None:
        with contextlib.suppress(ValueError, OSError):  # its output closed by close() (processes.stop)
            for raw in self.p.stdout:
                self.lines.put(raw.decode("utf-8", "replace").rstrip("\n"))
        self.lines.put(None)

    def ask(self, path: Path | str, timeout: float) -> dict[str, Any]:
        """Its answer to a job file's path (or to "--version")."""
        start = self.told  # what it wrote to standard error since its last job (or its start) is this job's
        try:
            self.p.stdin.write(f"{path}\n".encode())
            self.p.stdin.flush()
        except OSError:
            pass  # it has exited: what it said tells why (below)
        deadline = time.monotonic() + timeout
        out: list[str] = []
        said = None
        while True:
            try:
                line = self.lines.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                self.close(kill=True)
                raise CyclesError(f"Blender timed out after {timeout:g} s") from None
            if line is None or line == DONE:
                break
            out.append(line)
            said = _said(line) or said
        if line == DONE:
            self.told = os.fstat(self.err.fileno()).st_size
            if said is None or "failed" in said:
                raise CyclesError(f"Blender failed: {_one_line(said['failed'] if said else self._text(start, out))}")
            return said
        code = self.p.wait()  # it ended: a process of one job, a crash, or a failure it could not report
        text = self._text(start, out)
        self.close()
        if code < 0:
            raise CyclesError(f"Blender crashed (signal {-code}): {_one_line(text)}")
        if code != 0 or said is None:
            raise CyclesError(f"Blender failed: {_one_line(text)}")
        return said

    def _text(self, start: int, out: list[str]) -> str:
        self.err.seek(start)
        return self.err.read().decode("utf-8", "replace") + "\n".join(out)

    def close(self, kill: bool = False) -> None:
        """End the process (its input closed: it exits; ``kill``, or if it does not within 2 s: killed)."""
        with _lock:
            if self in _idle:
                _idle.remove(self)
            _every.discard(self)
        if kill:
            processes.kill(self.p)
        processes.stop(self.p)
        self.err.close()
        shutil.rmtree(self.tmp, ignore_errors=True)  # what Blender left in its $TMPDIR (killed: blender_XXXXXX)


def read_exr(path: Path, width: int, height: int, canvas: tuple[int, int] | None = None) -> dict[str, np.ndarray]:
    """Every channel of a multilayer EXR Blender wrote (one part per pass), by name without the view
    layer's prefix ("Position.X", "Combined.R", ...), float32 (H, W), top row first. ``canvas``: the size
    Blender rendered, when larger than the image (its top-left corner: minirt.oracles.cycles.scene.canvas)."""
    cw, ch = canvas or (width, height)
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise CyclesError(f"Blender wrote no readable {path.name} ({' '.join(oiio.geterror().split())[:200]})")
    out: dict[str, np.ndarray] = {}
    try:
        part = 0
        while inp.seek_subimage(part, 0):
            spec = inp.spec()
            if (spec.width, spec.height) != (cw, ch):
                raise CyclesError(f"Blender wrote {path.name} at {spec.width}x{spec.height}, not {cw}x{ch}")
            data = inp.read_image(part, 0, 0, spec.nchannels, oiio.FLOAT)
            if data is None:
                raise CyclesError(f"Blender wrote a truncated {path.name} ({' '.join(inp.geterror().split())[:200]})")
            a = np.asarray(data).reshape(ch, cw, spec.nchannels)[:height, :width]
            for c, name in enumerate(spec.channelnames):
                out[name.split(".", 1)[1] if name.count(".") >= 2 else name] = a[..., c]
            part += 1
    finally:
        inp.close()
    return out
