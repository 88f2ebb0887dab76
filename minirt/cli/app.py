"""The `minirt` command line: the Typer app, its commands in order, and ``main``, the one way out.

Typer (on Click) gives typed options, generated --help and usage errors with exit status 2; rich
draws progress bars and tables on stderr. Bad input is one line per problem and exit status 2,
never a traceback (set MINIRT_DEBUG=1 to see one for an unexpected internal error).

The package holds the command line's parts: minirt.cli.console (what is printed, and where),
minirt.cli.options (the shared flags and their parsing), and a module per command or family of
commands -- render (and export), probe, inventory (scenes, doctor), check (and report), sweep, grade,
fuzz -- each of which parses its flags, calls the API of its capability and prints what came back.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
from typing import Annotated

import typer

from minirt.cli import check, fuzz, grade, inventory, probe, render, sweep
from minirt.cli.console import MAX_MESSAGE, PipeClosed, err, out, own_warnings
from minirt.errors import MinirtError
from minirt.io.untrusted import terminal_text

try:  # Typer >= 0.20 raises the exceptions of the Click it vendors; older ones use Click itself
    from typer._click import exceptions as click_errors
except ImportError:  # pragma: no cover
    from click import exceptions as click_errors

app = typer.Typer(
    name="minirt",
    help="A reference ray tracer for ETH Informatik I problem 13.1, checked against Mitsuba 3, POV-Ray, Embree "
    "and Cycles.",
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    context_settings={"help_option_names": ["-h", "--help"]},
)


def _version(value: bool) -> None:
    if not value:
        return
    import importlib.metadata as md

    def v(pkg: str) -> str:
        try:
            return md.version(pkg)
        except md.PackageNotFoundError:
            return "missing"

    out.print(f"minirt {v('minirt')}", markup=False)
    out.print(f"drjit {v('drjit')}, mitsuba {v('mitsuba')}", markup=False)
    raise typer.Exit(0)


@app.callback()
def _options(
    version: Annotated[
        bool,
        typer.Option(
            "--version",
            callback=_version,
            is_eager=True,
            help="Print minirt's version and the pinned drjit and mitsuba versions, then exit.",
        ),
    ] = False,
) -> None:
    pass


# The commands, in the order --help lists them. Each module parses its flags, calls the API and prints.
app.command(help=render.RENDER_HELP)(render.render)
app.command()(probe.probe)
app.command()(inventory.scenes)
app.command()(inventory.doctor)
app.command()(render.export)
app.command()(check.check)
app.command(help=sweep.SWEEP_HELP)(sweep.sweep)
app.command()(check.report)
app.command()(grade.grade)
app.command(help=fuzz.fuzz_help())(fuzz.fuzz)


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _command_path(ctx) -> str:
    """`minirt CMD` however minirt was started (the console script or python -m minirt)."""
    names = []
    while ctx is not None and ctx.parent is not None:
        names.append(ctx.info_name)
        ctx = ctx.parent
    return " ".join(["minirt", *reversed(names)])


_stopped_by: list[int] = []  # the signal that stopped this run (Typer may turn the interrupt into a status)


def _on_signal(signum, frame) -> None:
    from minirt.jobs import processes

    _stopped_by.append(signum)
    processes.kill_all()  # the renderers first, so the threads waiting for them return at once
    raise KeyboardInterrupt  # SIGTERM and SIGHUP unwind like Ctrl-C: the same clean-up on the way out


def _stopped(signum: int) -> None:
    """Every clean-up has run on the way here (the interrupt unwound through them): say so and exit."""
    err.print("minirt: aborted" if signum == signal.SIGINT else f"minirt: stopped by {signal.Signals(signum).name}")
    sys.exit(128 + signum)


# Allocations between two collections of Python's youngest generation: Python's default is 700.
GC_YOUNG = 10_000


def _collect_less() -> None:
    """Collect Python's cyclic garbage less often: a collection of the youngest generation every GC_YOUNG
    allocations (the older generations' ratios as Python's).

    A check's process makes many short-lived containers -- modules' import-time tables, the certified
    oracle's pixels, the rule diagnosis's candidates -- so at Python's default the collector ran ~1,500
    times in a five-oracle check of the bundled scenes, nine of them over every object (0.84 s in all,
    pauses up to 0.14 s, on the threads every check waits for). At 10,000: 0.25 s; the check 0.98x the
    wall time and 0.97x the CPU (5 pairs, benchmarks/README.md), the same peak memory. Objects are still
    collected, in fewer, larger batches: a cycle holding a large array waits at most GC_YOUNG allocations."""
    import gc

    gc.set_threshold(GC_YOUNG, *gc.get_threshold()[1:])


def _normal_pages() -> None:
    """Ask Linux for normal (4 KiB) pages for this run: no transparent huge pages.

    Dr.Jit and NumPy ask for huge pages for their large buffers (madvise), and where the machine's
    memory is fragmented the kernel then compacts it on the spot, in the first touch of each buffer:
    on a 2-core VM a 200-ball 1024^2 render spent 0.4-1.3 s of system time there, and its offset-hazard
    warnings took 1.5-2.5 s instead of 0.45 s (benchmarks/README.md, issue 37). A command touches each
    buffer a few times, so huge pages' fewer TLB misses cannot win that back. PR_SET_THP_DISABLE (Linux
    3.15) applies to this process and what it starts; elsewhere NumPy's own switch (read when NumPy is
    first imported, by the command) at least keeps NumPy from asking, unless the user set it."""
    os.environ.setdefault("NUMPY_MADVISE_HUGEPAGE", "0")
    if sys.platform.startswith("linux"):
        import ctypes

        pr_set_thp_disable = 41  # <linux/prctl.h>
        with contextlib.suppress(OSError, AttributeError):
            ctypes.CDLL(None, use_errno=True).prctl(pr_set_thp_disable, 1, 0, 0, 0)


# glibc's mallopt parameters (<malloc.h>) and the values _keep_freed_memory sets: blocks up to 32 MiB (the
# largest threshold glibc takes on 64 bits) from the heap, and the heap's free top kept up to 1 GiB.
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3
MMAP_THRESHOLD, TRIM_THRESHOLD = 32 << 20, 1 << 30


def _keep_freed_memory() -> None:
    """Ask glibc to keep the memory this process frees for its next allocations, rather than give it back
    to the kernel at once.

    glibc serves a block from 128 KiB up (its threshold grows only to what was last freed) with mmap and
    unmaps it when freed, and trims the heap's free top above twice that: each new whole-image temporary
    then faults its pages in afresh. An 800² grade makes and frees ~100 MB of them a few hundred times:
    ~206,000 page faults, 0.5-0.6 s of system time. Served from the heap and kept (M_MMAP_THRESHOLD 32 MiB,
    M_TRIM_THRESHOLD 1 GiB), ~99,000 faults and 0.30-0.35 s; the peak memory the same (455 -> 461 MB), what
    is freed returned when the command ends (benchmarks/README.md, issue 50). A trim threshold alone makes
    it worse (it stops the mmap threshold's growth: 479,000 faults). Elsewhere than glibc, nothing."""
    import platform

    if platform.libc_ver()[0] != "glibc":
        return
    import ctypes

    with contextlib.suppress(OSError, AttributeError):
        libc = ctypes.CDLL(None)
        libc.mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD)
        libc.mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD)


# Commands whose process ends without the interpreter's teardown once their work is done: freeing a
# 1024^2 render's buffers one by one took 0.2-0.4 s of the whole command (the kernel frees them at once).
EXIT_AT_ONCE = frozenset({"render"})


def _exit(code: int) -> None:
    """sys.exit(code); for a command of EXIT_AT_ONCE run as the program itself (the console script or
    ``python -m minirt``, not main() called by another program, as the tests do): the streams flushed
    and the atexit handlers run (the temporary folders go), then os._exit. Every file is written and
    every thread joined by then (minirt.io.images.background_writes)."""
    main_module = sys.modules.get("__main__")
    spec = getattr(main_module, "__spec__", None)
    program = (spec is not None and spec.name == "minirt.__main__") or (
        spec is None and os.path.basename(getattr(main_module, "__file__", "") or "") == "minirt"
    )
    if program and sys.argv[1:2] and sys.argv[1] in EXIT_AT_ONCE:
        import atexit

        sys.stdout.flush()
        sys.stderr.flush()
        atexit._run_exitfuncs()
        os._exit(code)
    sys.exit(code)


def main() -> None:
    _collect_less()
    _normal_pages()
    _keep_freed_memory()
    own_warnings()
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, _on_signal)
    try:
        rv = app(standalone_mode=False)
        if _stopped_by:
            _stopped(_stopped_by[0])
        sys.stdout.flush()  # a closed pipe shows here, not as a warning at the interpreter's exit
        _exit(rv if isinstance(rv, int) else 0)
    except (PipeClosed, BrokenPipeError):
        # Nobody reads what is left to say: no message, and the status of a command killed by SIGPIPE
        # (141), not 1 (FAIL) or 2 (bad input). Writes are atomic, so every file written is whole.
        devnull = os.open(os.devnull, os.O_WRONLY)
        for fd in (1, 2):
            os.dup2(devnull, fd)  # the interpreter's last flush then has nowhere to fail
        sys.exit(128 + signal.SIGPIPE)
    except MinirtError as e:
        for line in e.lines or [str(e)]:
            err.print(f"minirt: error: {terminal_text(line, MAX_MESSAGE)}")
        sys.exit(2)
    except typer.Exit as e:
        sys.exit(e.exit_code)
    except (typer.Abort, KeyboardInterrupt):  # Click turns Ctrl-C into Abort
        _stopped(_stopped_by[0] if _stopped_by else signal.SIGINT)
    except click_errors.NoArgsIsHelpError as e:  # `minirt` or a command alone: its help
        e.show()
        sys.exit(2)
    except click_errors.UsageError as e:  # a bad option or argument: one line, like every other bad input
        err.print(f"minirt: error: {terminal_text(_one_line(e.format_message()), MAX_MESSAGE)}")
        if e.ctx is not None:
            err.print(f"try: {terminal_text(_command_path(e.ctx))} --help")
        sys.exit(2)
    except click_errors.ClickException as e:  # Click's other errors (a file it could not open): the same line
        err.print(f"minirt: error: {terminal_text(_one_line(e.format_message()), MAX_MESSAGE)}")
        sys.exit(2 if e.exit_code in (0, 1) else e.exit_code)
    except OSError as e:  # an output folder that cannot be made or written, a disk that is full: bad input
        if os.environ.get("MINIRT_DEBUG"):
            raise
        where = e.filename if e.filename is not None else "output"
        err.print(f"minirt: error: {terminal_text(where)}: {terminal_text(e.strerror or e)}")
        sys.exit(2)
    except Exception as e:
        if _stopped_by:  # the interrupt, wrapped by a library it unwound through (Dr.Jit's traced loops)
            _stopped(_stopped_by[0])
        if os.environ.get("MINIRT_DEBUG"):
            raise
        err.print(f"minirt: internal error: {type(e).__name__}: {terminal_text(e)} (set MINIRT_DEBUG=1 for details)")
        sys.exit(1)
