"""The embedded Dask cluster (``--workers N``): a LocalCluster in a child process of its own session.

A terminal sends Ctrl-C (SIGINT) and a hang-up (SIGHUP) to its whole foreground process group. Worker
processes in minirt's own group would each get it, and each print a page of asyncio traceback while
minirt itself stops -- or, still starting, die half way. So the cluster runs the way POV-Ray does
(minirt.jobs.processes): ``python -m minirt.jobs.cluster N`` in a new session, under ``setpriv --pdeathsig
KILL``. Its scheduler, nannies and N worker processes never see the terminal's signals; minirt gets them,
stops the cluster and says one line. The cluster stops with minirt however minirt stops:

- the run ends: ``local_cluster`` closes the child's standard input, and the child closes the cluster
  within ``STOP_SECONDS``, else its process group is killed;
- the run fails or is interrupted: the child's process group is killed at once (the jobs still running
  are no longer wanted);
- minirt is killed (SIGKILL): the kernel kills the child (pdeathsig; where setpriv is missing, the closed
  pipe of its standard input tells it), and Dask's worker processes exit when their nanny is gone.

The child writes its scheduler's address (tcp on the loopback interface) as its first line of standard
output; minirt's Client connects to it. Its Dask log records come out through minirt.jobs.logs'
one-line handler; each worker's are forwarded to minirt (minirt.jobs.worker).
"""

from __future__ import annotations

import contextlib
import functools
import os
import select
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator

START_SECONDS = 120.0  # a cluster that has not started by then (a machine swapping) is an error
STOP_SECONDS = 5.0


@contextlib.contextmanager
def local_cluster(workers: int) -> Iterator[Callable[[], str]]:
    """An embedded cluster of ``workers`` processes for the block (module docstring), started at once; what
    it yields gives the scheduler's address, waiting for it (the caller imports Dask meanwhile)."""
    import shutil

    from minirt.jobs.processes import new_temporary_folder, python_env, spawn

    # The workers import the jobs' functions by name. Their $TMPDIR is a folder of minirt's own (Dask's
    # dask-scratch-space/worker-* and what the workers' renderers make there were left behind by every
    # interrupted run), removed when the cluster has stopped, or by the next run if minirt was killed.
    tmp = new_temporary_folder("minirt-dask-")
    with contextlib.ExitStack() as gone:
        gone.callback(shutil.rmtree, tmp, ignore_errors=True)
        p = spawn(
            [sys.executable, "-m", "minirt.jobs.cluster", str(workers)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, env={**python_env(), "TMPDIR": str(tmp)},
        )  # fmt: skip
        with _stopped(p, workers) as address:
            yield address


@contextlib.contextmanager
def _stopped(p: subprocess.Popen, workers: int) -> Iterator[Callable[[], str]]:
    """The cluster process ``p`` for the block, stopped after it (at once on an error or an interrupt)."""
    from minirt.errors import MinirtError

    def address() -> str:
        said = _first_line(p, START_SECONDS)
        if not said.startswith("tcp://"):
            raise MinirtError(f"--workers {workers}: the local Dask cluster did not start ({_ended(p)})")
        return said

    try:
        yield functools.cache(address)
    except BaseException:  # an error or an interrupt: the workers' jobs are no longer wanted
        _stop(p, graceful=False)
        raise
    _stop(p)


def _first_line(p: subprocess.Popen, wait: float) -> str:
    """The child's first line of output, or "" when it ends (or ``wait`` passes) before writing one."""
    assert p.stdout is not None
    fd = p.stdout.fileno()
    line = b""
    deadline = time.monotonic() + wait
    while not line.endswith(b"\n"):
        left = deadline - time.monotonic()
        if left <= 0 or not select.select([fd], [], [], left)[0]:
            return ""
        chunk = os.read(fd, 4096)
        if not chunk:
            return ""
        line += chunk
    return line.decode("utf-8", "replace").strip()


def _ended(p: subprocess.Popen) -> str:
    code = p.poll()
    return "it is still starting" if code is None else f"it ended with status {code}"


def _stop(p: subprocess.Popen, graceful: bool = True) -> None:
    """Close the child's standard input (it closes its cluster), wait a little, then kill its group; not
    ``graceful``: kill it at once (a worker killed while writing a page leaves a temporary file, removed
    by the next write to that folder: minirt.io.atomic)."""
    from minirt.jobs.processes import stop

    stop(p, STOP_SECONDS if graceful else 0)


def serve(workers: int) -> None:
    """In the child: start the cluster, say its address, keep it until standard input closes."""
    import logging

    import dask
    from distributed import LocalCluster

    from minirt.jobs.logs import route_logs

    for sig in (signal.SIGINT, signal.SIGHUP):  # its own session has no terminal; minirt decides
        signal.signal(sig, signal.SIG_IGN)
    # Standard output is the pipe minirt reads the address from, once: the processes started from here
    # (nannies, workers, renderers) write theirs to standard error instead -- a pipe nobody reads would
    # block a worker after 64 KiB, and minirt's own standard output may be JSON (--json -).
    said = os.fdopen(os.dup(1), "w")
    os.dup2(2, 1)
    route_logs()
    # Dask's nanny starts workers with MALLOC_TRIM_THRESHOLD_=65536, which also turns off glibc's dynamic
    # mmap threshold: every array over 128 KiB is then a fresh mmap, page-faulted and unmapped again. A
    # diagnosis makes thousands of 1.5 MB arrays; a class of 120 images at 256² spent 52 s in the kernel
    # with it and 12 s without (2 workers, same output). The rest of its settings (one BLAS thread) stay.
    environ = dict(dask.config.get("distributed.nanny.pre-spawn-environ", {}))
    environ.pop("MALLOC_TRIM_THRESHOLD_", None)
    with (
        dask.config.set(
            {
                "distributed.nanny.pre-spawn-environ": environ,
                # minirt.jobs.batch runs an item whose worker died again alone: Dask need not retry it
                "distributed.scheduler.allowed-failures": 0,
            }
        ),
        LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address=None,
            # Without a dashboard the scheduler still serves its health routes over HTTP, by default on
            # every interface at port 8787 (a second run warns "Port 8787 is already in use"): here a free
            # port on the loopback interface, like the scheduler itself.
            scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
            silence_logs=logging.ERROR,
            preload=["minirt.jobs.worker"],  # each worker's Dask records go to minirt, forwarded
        ) as cluster,
    ):
        with said:
            said.write(cluster.scheduler_address + "\n")
        sys.stdin.buffer.read()  # until minirt closes it, or is gone


if __name__ == "__main__":
    serve(int(sys.argv[1]))
