"""Dask's log records, said minirt's way: one line each, or nothing when the command says it already;
and Python's warnings (NumPy's, a library's) likewise, in minirt's process and in each worker
(``warnings_as_lines``).

Dask logs through ``logging`` -- in this process (the client), in the embedded cluster's process (its
scheduler and nannies, minirt.jobs.cluster) and in every worker -- multi-line records with tracebacks
among them, in its own format. ``route_logs`` replaces its stream handlers with one ``OneLine`` handler at
ERROR and above: the record's first line, made inert (minirt.io.untrusted.terminal_text), prefixed
``minirt: dask:``. A worker's records are forwarded to this process and said here (``minirt: dask
worker:``); records that repeat what the command reports as a job's ERROR row -- a job that raised
("Compute Failed" and its traceback), whose workers died, or that could not be unpacked -- are left out.
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Callable


class OneLine(logging.Handler):
    """A Dask log record as one line on standard error, ``minirt: dask: FIRST LINE`` (``minirt: dask worker:``
    for a record a worker forwarded), made inert by minirt.io.untrusted.terminal_text -- nothing for records
    that repeat what the command reports as a job's ERROR row (REPORTED), nor anything when ``silent`` (in a
    worker process, whose records reach the terminal through minirt, forwarded)."""

    REPORTED = ("Compute Failed", "marked as failed because", "Failed to deserialize", "Error during deserialization")

    def __init__(self, silent: bool = False) -> None:
        super().__init__(logging.ERROR)
        self.silent = silent

    def emit(self, record: logging.LogRecord) -> None:
        from minirt.io.untrusted import terminal_text

        if self.silent:
            return
        try:
            text = record.getMessage().strip()
        except Exception:  # a record whose arguments do not format: its template
            text = str(record.msg).strip()
        if any(r in text for r in self.REPORTED):
            return
        first = text.splitlines()[0] if text else record.levelname.lower()
        who = "dask worker" if hasattr(record, "worker") else "dask"
        try:
            sys.stderr.write(f"minirt: {who}: {terminal_text(first, 300)}\n")
            sys.stderr.flush()
        except (OSError, ValueError):  # standard error is gone: nobody to tell
            pass


DASK_LOGGERS = ("distributed", "dask", "tornado", "bokeh")


def route_logs(silent: bool = False) -> None:
    """Every Dask (and Tornado) logger of this process says ERROR and above through one OneLine handler,
    instead of Dask's own stream handlers (multi-line, with tracebacks). Called here and, ``silent``, in
    each worker process of the embedded cluster (minirt.jobs.worker), whose records the cluster forwards
    to this process (``Client.forward_logging``)."""
    handler = OneLine(silent)
    names = {n for n in logging.root.manager.loggerDict if n.split(".")[0] in DASK_LOGGERS}
    for name in sorted({*DASK_LOGGERS, *names}):
        lg = logging.getLogger(name)
        for h in list(lg.handlers):
            if isinstance(h, logging.StreamHandler | OneLine):
                lg.removeHandler(h)
        top = name in DASK_LOGGERS
        if top:
            lg.addHandler(handler)
        lg.propagate = not top
        if top or lg.level < logging.ERROR:
            lg.setLevel(logging.ERROR)


def warnings_as_lines(say: Callable[[str], None] | None = None) -> None:
    """Every warning this process shows -- NumPy's "overflow encountered in cast", a library's -- as one
    line, ``minirt: warning: CATEGORY: message`` (made inert: minirt.io.untrusted.printable), never
    the source path and line Python prints; each text once. ``say``: how the line is written (the
    command line's console); else standard error (a worker of the embedded cluster, whose standard
    error is minirt's)."""
    import warnings

    from minirt.io.untrusted import printable

    said: set[str] = set()

    def show(message, category, filename, lineno, file=None, line=None) -> None:  # warnings.showwarning's
        text = f"{category.__name__}: {' '.join(str(message).split())}"
        if text in said:
            return
        said.add(text)
        out = printable(f"minirt: warning: {text}", 2000)  # no markup: ``say`` prints it as text
        try:
            if say is not None:
                say(out)
            else:
                sys.stderr.write(out + "\n")
                sys.stderr.flush()
        except (OSError, ValueError):  # standard error is gone: nobody to tell
            pass

    warnings.showwarning = show
