"""What the command line says, and where: the two consoles, progress bars, warnings and --json output.
A library's warning that minirt does not word itself is one ``minirt: warning:`` line (``own_warnings``).

rich draws tables and progress bars on stderr (``err``); results go to stdout (``out``). Messages built
from untrusted parts (a file name, a scene key) pass through minirt.io.untrusted.terminal_text first. A
reader that goes away (``minirt check ... | head -1``) raises PipeClosed, which ``minirt.cli.app.main``
turns into the status of a process killed by SIGPIPE.
"""

from __future__ import annotations

import os
import sys
from contextlib import contextmanager
from typing import Any

from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from minirt.io.untrusted import terminal_text


def _closed_streams_to_devnull() -> None:
    """A standard stream whose descriptor was closed before minirt started (``minirt ... >&-``, a
    daemon's): Python leaves sys.stdout or sys.stderr None, and minirt died of an AttributeError --
    at import for stderr, at its first message for stdout -- with exit 1, a FAIL's status, even for a
    broken scene. What cannot be said goes to /dev/null; the exit status still tells (0, 1, 2)."""
    for name in ("stdout", "stderr"):
        if getattr(sys, name) is None:
            setattr(sys, name, open(os.devnull, "w"))  # noqa: SIM115 -- the process's stream until exit


_closed_streams_to_devnull()  # before the consoles below ask stderr whether it is a terminal
# Tables in logs and pipes get room to breathe; a terminal keeps its own width.
err = Console(stderr=True, highlight=False, emoji=False, soft_wrap=True, width=None if sys.stderr.isatty() else 160)
out = Console(highlight=False, emoji=False, soft_wrap=True)


class PipeClosed(Exception):
    """The reader of standard output (or error) went away: ``minirt check ... | head -1``."""


def _pipe_closed() -> None:
    """Console.on_broken_pipe: Rich's own exits 1, which reads as a FAIL verdict; ``main`` exits as a
    process killed by SIGPIPE would, once the clean-ups on the way out have run."""
    raise PipeClosed


out.on_broken_pipe = err.on_broken_pipe = _pipe_closed
MAX_MESSAGE = 2000  # characters of one message line built from untrusted parts (a file name, a key)


@contextmanager
def progress_bar(enabled: bool = True):
    """A progress bar on stderr, only on a terminal (pipes and CI logs get none)."""
    if not enabled or not err.is_terminal:
        yield None
        return
    with Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total}"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=err,
        transient=True,
    ) as p:
        yield p


def class_progress(bar, local: bool, busy: str, row_text):
    """The (on_start, on_done) callbacks of a class run on ``bar`` (None: no bar): the task made when the run
    knows its size, named "``busy`` (N processes)" when it runs on N > 1 local processes (``local``), and each
    finished row said by ``row_text(row)`` (untrusted parts made safe for the terminal)."""
    task = None

    def start(total: int, processes: int) -> None:
        nonlocal task
        label = f"{busy} ({processes} processes)" if local and processes > 1 else "grading"
        task = bar.add_task(label, total=total) if bar else None

    def done(job, row) -> None:
        if bar:
            bar.update(task, description=terminal_text(row_text(row)))
            bar.advance(task)

    return start, done


def warn(scene_name: str, line: str) -> None:
    """A warning: one line on stderr, ``minirt: warning: SCENE: ...`` (as errors are ``minirt: error: ...``)."""
    err.print(terminal_text(f"minirt: warning: {scene_name}: {line}", MAX_MESSAGE))


def own_warnings() -> None:
    """A warning from NumPy or another library that minirt does not say in its own words reaches the user
    as one line, ``minirt: warning: CATEGORY: message`` -- never the library's source path and line
    (``hazards.py:428: RuntimeWarning: overflow encountered in cast`` and the code). Each text once
    (minirt.jobs.logs.warnings_as_lines; the embedded cluster's workers say theirs the same way)."""
    import warnings

    def first(message, category, filename, lineno, file=None, line=None) -> None:
        # the hook is made when a warning first shows: `minirt --help` imports nothing of minirt.jobs
        from minirt.jobs.logs import warnings_as_lines

        warnings_as_lines(lambda text: err.print(text, markup=False))
        warnings.showwarning(message, category, filename, lineno, file, line)

    warnings.showwarning = first


def emit_json(dest: str, data: dict[str, Any]) -> None:
    """Every command's --json: strict JSON with schema_version, to the file or (``-``) to standard output,
    which then holds nothing else (messages go to standard error)."""
    from minirt.io import jsonout

    try:
        jsonout.emit_json(dest, data)
    except BrokenPipeError:  # Click would exit 1 (a FAIL verdict's status) on it: see _pipe_closed
        raise PipeClosed from None
