"""Jobs: many independent calls of one function, run here or spread over processes with dask.distributed.

``run(fn, items, workers=..., scheduler=...)`` calls ``fn(item)`` for every item and returns the results
in the items' order, whatever order they finish in -- so a command's output does not depend on how its
work was spread. It is the one place that knows about processes:

- ``workers=1`` (and no scheduler): a plain loop in this process, no Dask at all -- what small runs and
  tests want (starting worker processes costs a few seconds).
- ``workers=N``: a ``dask.distributed.LocalCluster`` of N worker processes with one thread each, bound to
  the loopback interface, without the dashboard; closed when the run ends, also on an error or Ctrl-C.
- ``scheduler="tcp://host:8786"``: the workers of a running Dask cluster (started with
  ``dask scheduler`` and ``dask worker``); they need minirt installed and the same files at the same
  paths (a shared file system).

``fn`` must be a module-level function (workers import it by name) and should keep what it can reuse
from one item to the next in its own process (a render cache): items are handed out one at a time.

With a ``cache`` (minirt.jobs.cache) the items whose results it holds are not run again; this process alone
reads and writes it.

A call that raises -- or whose worker process dies, which Dask reports after retrying the item on other
workers -- does not stop the run: ``on_error(item, message)`` makes its result instead.
"""

from __future__ import annotations

import contextlib
import logging
import os
from collections.abc import Callable, Iterator, Sequence
from typing import TYPE_CHECKING, Any, TypeVar

if TYPE_CHECKING:
    from minirt.jobs.cache import Cache

T = TypeVar("T")
R = TypeVar("R")


def cores() -> int:
    """Processors this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def default_workers(n_items: int, per_worker: int = 16) -> int:
    """One process per core, but none that would get fewer than ``per_worker`` items: below that the
    seconds a worker takes to start (Python, Dr.Jit) outweigh what it saves."""
    return max(1, min(cores(), n_items // per_worker))


def pool(workers: int | None, scheduler: str | None, default: int, spelled: str = "workers and scheduler") -> int:
    """The worker count of a ``workers``/``scheduler`` pair (``default`` when neither is given); both
    given is an error (``spelled``: how the caller names the two): a cluster has its own workers."""
    if workers is not None and scheduler is not None:
        from minirt.errors import MinirtError

        raise MinirtError(f"{spelled}: give one (the cluster has its own workers)")
    return default if workers is None else workers


def run(
    fn: Callable[[T], R],
    items: Sequence[T],
    workers: int = 1,
    scheduler: str | None = None,
    on_done: Callable[[T, R], None] | None = None,
    on_error: Callable[[T, str], R] | None = None,
    cache: Cache | None = None,
) -> list[R]:
    """``[fn(item) for item in items]``, here or on Dask workers (see the module's docstring);
    ``on_done(item, result)`` is called in this process as each finishes (a progress bar). With a
    ``cache`` (minirt.jobs.cache.Cache), items whose result it holds are not run again, and new results are
    stored as they arrive (``on_error``'s are not)."""
    if cache is not None:
        return _cached_run(fn, items, workers, scheduler, on_done, on_error, cache)
    if scheduler is None and workers <= 1:
        return [_one(fn, item, on_done, on_error) for item in items]
    with _client(workers, scheduler) as client:
        from distributed import as_completed

        futures = client.map(fn, list(items), pure=False)
        index = {f.key: k for k, f in enumerate(futures)}
        results: list[Any] = [None] * len(items)
        for f in as_completed(futures):
            k = index[f.key]
            try:
                results[k] = f.result()
            except Exception as e:  # the call raised, or its worker died (KilledWorker)
                if on_error is None:
                    raise
                results[k] = on_error(items[k], _message(e))
            else:
                if on_done:
                    on_done(items[k], results[k])
            f.release()
        return results


def _cached_run(fn, items, workers, scheduler, on_done, on_error, cache: Cache) -> list[Any]:
    results: list[Any] = [None] * len(items)
    missing = []
    for k, item in enumerate(items):
        hit = cache.load(item)
        if hit is None:
            missing.append(k)
            continue
        results[k] = hit
        if on_done:
            on_done(item, hit)

    def done(item, result) -> None:
        cache.store(item, result)
        if on_done:
            on_done(item, result)

    got = run(fn, [items[k] for k in missing], workers, scheduler, done, on_error)
    for k, result in zip(missing, got, strict=True):
        results[k] = result
    return results


def _one(fn, item, on_done, on_error):
    try:
        result = fn(item)
    except Exception as e:
        if on_error is None:
            raise
        return on_error(item, _message(e))
    if on_done:
        on_done(item, result)
    return result


def _message(e: BaseException) -> str:
    name = type(e).__name__
    if name == "KilledWorker":
        return "the worker process grading it died (a crash or out of memory), also when retried"
    text = str(e).splitlines()[0] if str(e) else ""
    return f"internal error: {name}: {text}" if text else f"internal error: {name}"


def _reachable(scheduler: str) -> None:
    """A tcp:// address whose port refuses or does not resolve is one line at once: Dask's Client retries
    such an address until its 10 s time-out (a mistyped port cost every command 10 s)."""
    import socket
    from urllib.parse import urlsplit

    from minirt.errors import MinirtError

    try:
        u = urlsplit(scheduler)
        host, port = u.hostname, u.port
    except ValueError:
        return  # Dask's own message says what is wrong with the address
    if u.scheme != "tcp" or host is None or port is None:
        return
    try:
        socket.create_connection((host, port), timeout=10).close()
    except OSError as e:
        why = e.strerror or type(e).__name__
        raise MinirtError(f"--scheduler {scheduler}: cannot reach a Dask scheduler there ({why})") from None


@contextlib.contextmanager
def _client(workers: int, scheduler: str | None) -> Iterator[Any]:
    import dask
    from distributed import Client, LocalCluster

    # Dask logs cluster start-up, shutdown and retries at INFO/WARNING; the command reports what matters
    for name in ("distributed", "dask"):
        logging.getLogger(name).setLevel(logging.ERROR)
    if scheduler is not None:
        _reachable(scheduler)
        try:
            client = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError, ValueError) as e:
            from minirt.errors import MinirtError

            raise MinirtError(f"--scheduler {scheduler}: cannot reach a Dask scheduler there ({e})") from None
        with client:
            yield client
        return
    # Dask's nanny starts workers with MALLOC_TRIM_THRESHOLD_=65536, which also turns off glibc's dynamic
    # mmap threshold: every array over 128 KiB is then a fresh mmap, page-faulted and unmapped again. A
    # diagnosis makes thousands of 1.5 MB arrays; a class of 120 images at 256² spent 52 s in the kernel
    # with it and 12 s without (2 workers, same output). The rest of its settings (one BLAS thread) stay.
    environ = dict(dask.config.get("distributed.nanny.pre-spawn-environ", {}))
    environ.pop("MALLOC_TRIM_THRESHOLD_", None)
    with (
        dask.config.set({"distributed.nanny.pre-spawn-environ": environ}),
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
        ) as cluster,
        Client(cluster) as client,
    ):
        client.run(_one_core)
        yield client


def _one_core() -> None:
    """In a local worker: Dr.Jit's thread pool to one thread. N workers on N cores then run N kernels at
    once instead of N pools of N threads contending for the same cores."""
    import drjit as dr

    dr.set_thread_count(1)
