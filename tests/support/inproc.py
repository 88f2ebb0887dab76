"""`minirt ARGS` run in the test's own process, returned as a subprocess run would return it.

A `python -m minirt` child costs half a second to a second before it does anything (Python, NumPy,
Typer, Dr.Jit and the oracles' modules imported again, uncached); most command-line tests only check an
exit status and a message. ``minirt(*args)`` calls the same entry point (minirt.cli.app.main: the same
error handling and exit statuses) with sys.argv, the working folder, stdout and stderr swapped for the
call, and gives a subprocess.CompletedProcess with the text of both streams.

Tests about the process itself (signals, a child's environment or PATH, worker processes, the
console script) keep spawning it.
"""

from __future__ import annotations

import contextlib
import io
import os
import signal
import subprocess
import sys
from pathlib import Path

_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


class _Stream(io.TextIOWrapper):
    """A text stream with a binary buffer beneath, like sys.stdout (some writers use .buffer)."""

    def __init__(self) -> None:
        super().__init__(io.BytesIO(), encoding="utf-8", errors="replace", write_through=True)

    def isatty(self) -> bool:
        return False

    def text(self) -> str:
        self.flush()
        data = self.buffer.getvalue().decode("utf-8", errors="replace")  # type: ignore[attr-defined]
        return data.replace("\r\n", "\n").replace("\r", "\n")  # as subprocess.run(text=True) reads it


def minirt(*args: object, cwd: str | Path | None = None) -> subprocess.CompletedProcess:
    """Run ``minirt *args`` here (see the module's docstring); never raises for the command's failure."""
    from minirt.cli import app as cli

    argv = ["minirt", *map(str, args)]
    out, err = _Stream(), _Stream()
    handlers = {s: signal.getsignal(s) for s in _SIGNALS}
    saved_argv = sys.argv
    code: int = 0
    try:
        sys.argv = argv
        with contextlib.chdir(cwd or os.getcwd()), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                cli.main()
            except SystemExit as e:
                code = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
    finally:
        sys.argv = saved_argv
        for s, h in handlers.items():
            signal.signal(s, h)
        cli._stopped_by.clear()
    return subprocess.CompletedProcess(argv, code, out.text(), err.text())
