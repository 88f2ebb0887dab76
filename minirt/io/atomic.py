"""Atomic writes: a file appears whole under its name, or not at all.

A file is written to a temporary name beside its destination and renamed into place, so an interrupted
or failing run never leaves a half-written output file. The temporary files of runs that were killed
(SIGKILL, a crash: no handler ran) carry the dead writer's pid and are removed by the next write to
their folder; :func:`stale` finds such leftovers, here and for minirt.jobs.processes' folders.
"""

from __future__ import annotations

import contextlib
import os
import re
import tempfile
from pathlib import Path

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


@contextlib.contextmanager
def atomic_path(path: Path):
    """Yield a temporary path beside `path` (same extension); rename it into place on success. The
    temporary file ``.STEM.tmp<pid>-XXXX.EXT`` is removed on every exit Python sees (an error, Ctrl-C,
    SIGTERM); those a killed run left in a folder are removed by this process's first write there."""
    path.parent.mkdir(parents=True, exist_ok=True)
    _sweep_once(path.parent)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.tmp{os.getpid()}-", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)  # mkstemp creates 0600; outputs get the usual permissions
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


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
