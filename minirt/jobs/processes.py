"""Child processes and temporary folders that do not outlive minirt.

A renderer run as a subprocess (POV-Ray) must stop when minirt stops, however it stops:

- Ctrl-C, SIGTERM, SIGHUP: the CLI's handler calls :func:`kill_all`, which kills every live child's
  process group at once (the threads waiting for them then return), and the interrupt unwinds through
  the ``with`` blocks that remove temporary files and folders.
- SIGKILL of minirt (or a crash): no handler runs, so each child is started through util-linux's
  ``setpriv --pdeathsig KILL`` -- the kernel kills it when the thread that started it dies. Where
  setpriv is missing the child still has its own process group and a time-out.
- The temporary folders such runs leave are named ``PREFIX<pid>-...``; the next :func:`temporary_folder`
  (or :func:`new_temporary_folder`) of the same prefix removes those whose process is gone. A child that
  makes temporary folders of its own (Blender's ``blender_XXXXXX``, left behind whenever it is killed) is
  given a $TMPDIR inside such a folder, so what it leaves goes with it.

Each child runs in a new session (its own process group), so a terminal's Ctrl-C reaches minirt only,
and minirt decides: kill the children, clean up, exit 130.
"""

from __future__ import annotations

import contextlib
import os
import queue
import re
import shutil
import signal
import subprocess
import tempfile
import threading
from collections.abc import Iterator
from concurrent.futures import Future
from pathlib import Path
from typing import Any

from minirt.io.atomic import stale

_live: set[subprocess.Popen] = set()
_lock = threading.Lock()


def _pdeathsig_prefix() -> list[str]:
    exe = shutil.which("setpriv")
    return [exe, "--pdeathsig", "KILL", "--"] if exe else []


def run(cmd: list[str], cwd: Path | str | None = None, timeout: float | None = None) -> subprocess.CompletedProcess:
    """``subprocess.run(cmd, capture_output=True)`` for a renderer: text decoded as UTF-8 with bad bytes
    replaced (a renderer's garbage is a message, not a UnicodeDecodeError), no standard input, and the
    child killed -- with its process group -- on a time-out, an interrupt or minirt's death."""
    p = subprocess.Popen(
        [*_pdeathsig_prefix(), *cmd], cwd=cwd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
        stderr=subprocess.PIPE, start_new_session=True,
    )  # fmt: skip
    with _lock:
        _live.add(p)
    try:
        try:
            out, err = p.communicate(timeout=timeout)
        except BaseException:  # the time-out, Ctrl-C, SIGTERM: the child goes first
            kill(p)
            p.communicate()
            raise
    finally:
        with _lock:
            _live.discard(p)
    text = (out or b"").decode("utf-8", "replace"), (err or b"").decode("utf-8", "replace")
    return subprocess.CompletedProcess(cmd, p.returncode, *text)


def python_env() -> dict[str, str]:
    """The environment of a child Python process that imports minirt's modules by name (the embedded
    cluster's, the certified oracle's workers): this one's, with this process's module path, as Python's
    own process pools give their workers."""
    import sys

    return {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p and os.path.isdir(p))}


def spawn(cmd: list[str], **popen: Any) -> subprocess.Popen:
    """A long-lived child (the embedded Dask cluster, minirt.jobs.cluster; the certified oracle's workers;
    Blender) started as renderers are: in a session of its own (a terminal's signals reach minirt, not it)
    and killed by the kernel if minirt is. The caller stops it; ``popen``: subprocess.Popen's other arguments.

    The kernel's parent-death signal follows the *thread* that started a child, not its process: a child
    started from a passing thread (a check's lanes, one pool a scene) was killed when that thread ended,
    and a check of the bundled scenes started the certified oracle's two workers seven times over (~0.5
    CPU-s each). So a child started from any thread but the main one is started by ``_keeper``, a thread
    that lives as long as minirt's process."""
    if threading.current_thread() is threading.main_thread():
        return _popen(cmd, popen)
    f: Future = Future()
    _keeper().put((cmd, popen, f))
    return f.result()


def _popen(cmd: list[str], popen: dict[str, Any]) -> subprocess.Popen:
    return subprocess.Popen([*_pdeathsig_prefix(), *cmd], start_new_session=True, **popen)


_requests: queue.Queue | None = None


def _keeper() -> queue.Queue:
    """The queue of the thread that starts ``spawn``'s children for other threads (started on first use;
    a daemon: it ends with the process, and its children with it)."""
    global _requests
    with _lock:
        if _requests is None:
            _requests = queue.Queue()
            threading.Thread(target=_keep, args=(_requests,), name="minirt-keeper", daemon=True).start()
        return _requests


def _keep(requests: queue.Queue) -> None:
    while True:
        cmd, popen, f = requests.get()
        try:
            f.set_result(_popen(cmd, popen))
        except BaseException as e:  # OSError: no such program; handed to the caller
            f.set_exception(e)


def track(p: subprocess.Popen) -> None:
    """Count a ``spawn``ed child among those ``kill_all`` kills (a signal stops minirt: it goes first)."""
    with _lock:
        _live.add(p)


def untrack(p: subprocess.Popen) -> None:
    with _lock:
        _live.discard(p)


def kill(p: subprocess.Popen) -> None:
    """Kill a child and its process group at once."""
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(p.pid, signal.SIGKILL)


def stop(p: subprocess.Popen, wait: float = 2.0) -> None:
    """End a ``spawn``ed child that serves until its standard input closes (the embedded cluster, the
    certified oracle's workers, Blender): its input closed, ``wait`` seconds for it to exit, else its
    process group killed; then whatever it left in its group killed too, its output closed, and it no
    longer counted by ``kill_all``."""
    with contextlib.suppress(OSError):
        if p.stdin:
            p.stdin.close()
    try:
        p.wait(timeout=wait)
    except subprocess.TimeoutExpired:
        kill(p)
        p.wait()
    finally:
        kill(p)  # what it left in its group, if anything
        untrack(p)
        with contextlib.suppress(OSError):
            if p.stdout:
                p.stdout.close()


def kill_all() -> None:
    """Kill every live child (from a signal handler: no waiting here)."""
    for p in list(_live):
        kill(p)


@contextlib.contextmanager
def temporary_folder(prefix: str) -> Iterator[Path]:
    """A temporary folder ``PREFIX<pid>-XXXX`` removed on every exit path Python sees; those of killed
    runs (SIGKILL, a crash) are removed by the next call."""
    tmp = new_temporary_folder(prefix)
    try:
        yield tmp
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def new_temporary_folder(prefix: str) -> Path:
    """A new folder ``$TMPDIR/PREFIX<pid>-XXXX`` that the caller removes (``temporary_folder`` does, on
    leaving its block; a child's own $TMPDIR, once the child has ended: minirt.oracles.cycles.run); first
    the folders of the same prefix whose run is gone (SIGKILL, a crash: nobody removed them) are removed."""
    base = Path(tempfile.gettempdir())
    for q in stale(base, re.compile(re.escape(prefix) + r"(\d+)-")):
        shutil.rmtree(q, ignore_errors=True)
    return Path(tempfile.mkdtemp(prefix=f"{prefix}{os.getpid()}-"))
