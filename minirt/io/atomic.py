"""Atomic writes: a file appears whole under its name, or not at all.

Every file minirt produces -- renders, JSON, JUnit, pages and their pictures, exports, caches -- is
written through :func:`atomic_path` (or :func:`write_text` / :func:`write_bytes`, which use it): to a
temporary name in the destination's own folder, flushed to the disk (fsync), then renamed into place.
So an interrupted or failing run (a full disk, Ctrl-C) never leaves a half-written output file: what
was there before stays. The rename replaces the destination's directory entry itself: a symlink (or a
FIFO, a socket) planted under the output's name is replaced by the file, never written through, so
its target is untouched. An error names the output file, never the temporary one. A device named as
the output (``--json /dev/null``, ``/dev/stdout``: :func:`is_device`) is written into, never replaced.

The temporary files of runs that were killed (SIGKILL, a crash: no handler ran) carry the dead writer's
pid and are removed by the next write to their folder; :func:`stale` finds such leftovers, here and for
minirt.jobs.processes' folders.
"""

from __future__ import annotations

import contextlib
import functools
import os
import re
import stat
import tempfile
from pathlib import Path

from minirt.errors import MinirtError

TEMP_FILE = re.compile(r"\..*\.tmp(\d+)-")  # atomic_path's temporary files; the group is the writer's pid
_swept: set[Path] = set()


def _sweep_once(folder: Path) -> None:
    """Remove the temporary files of killed runs from ``folder``, once per folder and process (a class
    of students writes thousands of files into one folder: one listing, not one per file)."""
    key = folder.resolve()
    if key not in _swept:
        _swept.add(key)
        for q in stale(folder, TEMP_FILE):
            q.unlink(missing_ok=True)


@functools.cache
def _umask() -> int:
    """This process's umask, read without setting it (os.umask sets it: another thread creating a file
    at that moment would get a world-writable one): Linux's /proc, else the set-and-restore."""
    with contextlib.suppress(OSError, ValueError):
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _named(e: OSError, tmp: str, path: Path) -> OSError:
    """``e`` naming the output file where it named the temporary one (or nothing): a user is told of
    the file they asked for."""
    if e.filename in (None, tmp) or e.filename2 == str(path):
        return type(e)(e.errno, e.strerror or str(e), str(path))
    return e


@contextlib.contextmanager
def atomic_path(path: Path, mode: int | None = None):
    """Yield a temporary path beside `path` (same extension); on success flush it to the disk and rename
    it into place (replacing a symlink at `path`, never writing through it). ``mode``: the file's
    permission bits exactly (a script's 0o755), set on the temporary file before the rename; else the
    usual 0o666 less the umask. The temporary file ``.STEM.tmp<pid>-XXXX.EXT`` is removed on every exit
    Python sees (an error, Ctrl-C, SIGTERM); those a killed run left in a folder are removed by this
    process's first write there. An OSError (a full disk) names `path`, not the temporary file."""
    path = Path(path)
    if is_device(path):  # /dev/null, /dev/stdout: a stream, written into as it is, never replaced
        yield path
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    _sweep_once(path.parent)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.tmp{os.getpid()}-", suffix=path.suffix, dir=path.parent)
    except OSError as e:  # the folder cannot take a new file (read-only, full): said of the output
        raise _named(e, e.filename, path) from None
    try:
        try:
            os.fchmod(fd, mode if mode is not None else 0o666 & ~_umask())  # mkstemp's is 0600
        finally:
            os.close(fd)
        yield Path(tmp)
        _flush(tmp)
        os.replace(tmp, path)
    except OSError as e:
        raise _named(e, tmp, path) from None
    except MinirtError as e:  # a library's or a child's message (OpenEXR, Blender) naming the temporary file
        if tmp not in str(e):
            raise
        raise MinirtError(*(line.replace(tmp, str(path)) for line in e.lines)) from None
    finally:
        if os.path.lexists(tmp):
            os.unlink(tmp)


DEVICE_FOLDERS = ("/dev/", "/proc/")  # where a name is a device or a process's stream, not a file


def is_device(path: Path) -> bool:
    """Does ``path`` name a device or a stream -- ``/dev/null``, ``/dev/stdout``, ``/proc/self/fd/1`` --
    rather than a file? A name given in /dev or /proc that is there and not a regular file. Such a
    destination is written into, never replaced: the rename would replace the device node itself (as
    root: /dev/null became a plain file). Only a name the user gives counts: a symlink in an output
    folder is replaced whatever it points to (a device included), never written through."""
    name = os.path.abspath(path)
    if not name.startswith(DEVICE_FOLDERS):
        return False
    try:
        return not stat.S_ISREG(os.lstat(name).st_mode)
    except OSError:
        return False


def _flush(tmp: str) -> None:
    """The temporary file's bytes on the disk before its name points at them: a crash of the machine
    right after the rename leaves the old file or the new one, not an empty one."""
    fd = os.open(tmp, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_bytes(path: Path, data: bytes, mode: int | None = None) -> Path:
    """``data`` as the file ``path``, atomically (``atomic_path``); returns ``path``."""
    with atomic_path(path, mode) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def write_text(path: Path, text: str, mode: int | None = None) -> Path:
    """``text`` as UTF-8 in the file ``path``, atomically (``atomic_path``); returns ``path``."""
    return write_bytes(path, text.encode("utf-8"), mode)


def write_all(files: dict[Path, str | bytes], modes: dict[Path, int] | None = None) -> list[Path]:
    """Files that belong together (an export: a scene and the script that renders it), each written as
    ``atomic_path`` writes one (text as UTF-8; ``modes``: as its ``mode``), and none renamed into place
    before every one is whole on the disk: a full disk leaves every one as it was. Returns the paths."""
    with contextlib.ExitStack() as stack:
        for path, data in files.items():
            tmp = stack.enter_context(atomic_path(path, (modes or {}).get(path)))
            tmp.write_bytes(data if isinstance(data, bytes) else data.encode("utf-8"))
    return list(files)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process: alive, and not ours to sweep
        return True
    return True


def stale(folder: Path, pattern: re.Pattern[str]) -> list[Path]:
    """Entries of ``folder`` whose name ``pattern`` matches, its first group being the pid of the run
    that made it, where that process is gone (and this user owns the entry)."""
    found = []
    with contextlib.suppress(OSError):
        for q in folder.iterdir():
            m = pattern.match(q.name)
            with contextlib.suppress(OSError):
                if m and q.lstat().st_uid == os.getuid() and not _alive(int(m.group(1))):
                    found.append(q)
    return found
