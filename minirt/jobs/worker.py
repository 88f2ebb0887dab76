"""Set-up of each worker process of minirt's embedded Dask cluster: imported there by Dask as a worker
*preload* (minirt.jobs.batch starts the LocalCluster with ``preload=["minirt.jobs.worker"]``), before the
worker takes any job. Never imported by minirt itself: importing it makes the process ignore Ctrl-C.

- **Interrupts are the parent's.** The cluster's processes run in a session of their own
  (minirt.jobs.cluster), out of reach of the terminal's Ctrl-C and hang-up; a worker also ignores SIGINT
  and SIGHUP sent to it some other way (to the cluster's process group), which would make it print a page
  of asyncio traceback. minirt decides, and stops the cluster. SIGTERM and SIGKILL still end a worker at
  once: the nanny uses them.
- **Logs go through minirt.** The worker prints none of Dask's records itself (a job's "Compute Failed"
  with its traceback, a heartbeat lost while the cluster stops): those at ERROR and above are forwarded to
  minirt (``Client.forward_logging``), which says each in one line, or not at all when the job's ERROR
  row says it (minirt.jobs.logs.route_logs). A Python warning is one ``minirt: warning:`` line
  (minirt.jobs.logs.warnings_as_lines), never a source path.
"""

from __future__ import annotations

import signal


def ignore_interrupts() -> None:
    """This process ignores SIGINT and SIGHUP (a worker: its parent decides)."""
    for sig in (signal.SIGINT, signal.SIGHUP):
        signal.signal(sig, signal.SIG_IGN)


def dask_setup(worker) -> None:
    """Called by Dask in the worker process once the module is imported."""
    from minirt.jobs.logs import route_logs, warnings_as_lines

    ignore_interrupts()
    route_logs(silent=True)
    warnings_as_lines()  # a job's NumPy warning: one minirt line, as in minirt's own process


ignore_interrupts()  # at import: the earliest point of a worker process at which Dask runs minirt's code
