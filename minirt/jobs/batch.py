"""Jobs: many independent calls of one function, run here or spread over processes with dask.distributed.

``run(fn, items, workers=..., scheduler=...)`` calls ``fn(item)`` for every item and returns the results
in the items' order, whatever order they finish in -- so a command's output does not depend on how its
work was spread; ``stream`` gives them as they finish, taking the items lazily (a campaign of a million
scenes is never a list). This module is the one place that knows about processes:

- ``workers=1`` (and no scheduler): a plain loop in this process, no Dask at all -- what small runs and
  tests want (starting worker processes costs a few seconds).
- ``workers=N``: a ``dask.distributed.LocalCluster`` of N worker processes with one thread each, bound to
  the loopback interface, without the dashboard; started at the first job that is not in the cache and
  closed when the run ends, also on an error or Ctrl-C. It runs in a child process of its own session
  (minirt.jobs.cluster), so a terminal's Ctrl-C reaches minirt alone, which stops the cluster and says
  one line.
- ``scheduler="tcp://host:8786"``: the workers of a running Dask cluster (started with
  ``dask scheduler`` and ``dask worker``); they need minirt installed and the same files at the same
  paths (a shared file system). Before Dask connects, minirt reads the scheduler's greeting itself
  (``handshake``), within ``MINIRT_SCHEDULER_TIMEOUT`` seconds (default 5): a port that refuses, that
  answers with something else (a web server) or that never answers is one line, not a hang or a
  MemoryError from a "message" of 3 EiB. **A cluster is trusted**: Dask sends jobs and results as
  pickles, so its scheduler and workers can run code in this process, and they compute the results;
  use your own cluster, secured with TLS (``tls://`` and Dask's security settings) off a private network.

``fn`` must be a module-level function (workers import it by name) and should keep what it can reuse
from one item to the next in its own process (a render cache): items are handed out one at a time.

With a ``cache`` (minirt.jobs.cache) the items whose results it holds are not run again; this process alone
reads and writes it.

A call that raises -- or whose worker process dies, or whose result fails ``check(item, result)`` (what
came back from another process is checked before it is used) -- does not stop the run:
``on_error(item, message)`` makes its result instead. Dask's own log records come out as one line each,
or not at all when they repeat such an error (minirt.jobs.logs).

A worker process that dies takes with it every item it held, not only the one that killed it: Dask
cannot tell which it was, and under load an innocent item can share a dying worker more than once. So an
item whose worker died is held back and run again alone, with nothing else in flight, once the rest are
done: only an item that kills its worker when alone is reported as having died. The embedded cluster
lets Dask retry nothing itself (``allowed-failures`` 0), so a crashing item costs two worker restarts,
not four plus two.
"""

from __future__ import annotations

import contextlib
import logging
import os
from collections.abc import Callable, Iterable, Iterator, Sequence
from typing import TYPE_CHECKING, Any, TypeVar

if TYPE_CHECKING:
    from minirt.jobs.cache import Cache

T = TypeVar("T")
R = TypeVar("R")

TIMEOUT = "MINIRT_SCHEDULER_TIMEOUT"  # seconds to reach a scheduler and read its greeting (default 5)
DEFAULT_TIMEOUT = 5.0
GREETING_MAX = 1 << 16  # a Dask handshake is ~60 bytes: a longer "greeting" is not one
WINDOW = 256  # jobs handed to a cluster at a time (each worker gets the next as it finishes one)


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
    check: Callable[[T, R], None] | None = None,
) -> list[R]:
    """``[fn(item) for item in items]``, here or on Dask workers (see the module's docstring);
    ``on_done(item, result)`` is called in this process as each finishes (a progress bar; not for
    ``on_error``'s results). With a ``cache`` (minirt.jobs.cache.Cache), items whose result it holds are not
    run again, and new results are stored as they arrive (``on_error``'s are not). ``check(item, result)``
    raises ValueError for a result from a worker that cannot be used (it becomes ``on_error``'s)."""
    results: list[Any] = [None] * len(items)
    todo = []
    for k, item in enumerate(items):  # every hit first: what comes from the cache does not depend on timing
        hit = None if cache is None else cache.load(item)
        if hit is None:
            todo.append(k)
            continue
        results[k] = hit
        if on_done:
            on_done(item, hit)
    missing = (items[k] for k in todo)
    with contextlib.closing(stream(fn, missing, workers, scheduler, on_error, cache, check, load=False)) as done:
        for j, item, result, ok in done:
            results[todo[j]] = result
            if ok and on_done:
                on_done(item, result)
    return results


def stream(
    fn: Callable[[T], R],
    items: Iterable[T],
    workers: int = 1,
    scheduler: str | None = None,
    on_error: Callable[[T, str], R] | None = None,
    cache: Cache | None = None,
    check: Callable[[T, R], None] | None = None,
    window: int = WINDOW,
    load: bool = True,
) -> Iterator[tuple[int, T, R, bool]]:
    """``(index, item, result, ok)`` for every item, as each finishes (``ok``: not ``on_error``'s);
    ``items`` are taken lazily, at most ``window`` of them waiting on a cluster at a time, and a cluster is
    started only for the first item the cache does not hold (``load``: look there; new results are stored
    either way). Close the generator (``contextlib.closing``) to stop early: the cluster stops with it."""
    source = enumerate(items)
    if not load:
        cache, store = None, cache
    else:
        store = cache
    if scheduler is None and workers <= 1:
        for k, item in source:
            hit = None if cache is None else cache.load(item)
            if hit is not None:
                yield k, item, hit, True
                continue
            result, ok = _one(fn, item, on_error)
            if ok and store is not None:
                store.store(item, result)
            yield k, item, result, ok
        return
    with contextlib.ExitStack() as stack:
        client, ac, pending = None, None, {}
        suspects: list[tuple[int, Any]] = []  # items whose worker died under them
        while True:
            while len(pending) < window:
                nxt = next(source, None)
                if nxt is None:
                    break
                k, item = nxt
                hit = None if cache is None else cache.load(item)
                if hit is not None:
                    yield k, item, hit, True
                    continue
                if client is None:
                    from distributed import as_completed

                    client = stack.enter_context(_client(workers, scheduler))
                    ac = as_completed()
                f = client.submit(fn, item, pure=False)
                pending[f.key] = (k, item)
                ac.add(f)
            if not pending:
                break
            f = next(ac)
            k, item = pending.pop(f.key)
            if _died(f):  # maybe its own crash, maybe a neighbour's: decided when it runs alone
                suspects.append((k, item))
                f.release()
                continue
            yield k, item, *_settle(f, item, on_error, check, store)
        for k, item in suspects:
            f = client.submit(fn, item, pure=False)
            yield k, item, *_settle(f, item, on_error, check, store)


def _settle(f, item, on_error, check, store) -> tuple[Any, bool]:
    """A finished future's result and whether it is one (``_collect``); the future released, a result stored."""
    result, ok = _collect(f, item, on_error, check)
    f.release()
    if ok and store is not None:
        store.store(item, result)
    return result, ok


def _died(f) -> bool:
    """Whether a finished future ended with its worker process gone (Dask's KilledWorker)."""
    return f.status == "error" and type(f.exception()).__name__ == "KilledWorker"


def _collect(f, item, on_error, check) -> tuple[Any, bool]:
    """A finished future's result (checked), or ``on_error``'s for it."""
    try:
        result = f.result()
    except Exception as e:  # the call raised, or its worker died (KilledWorker)
        if on_error is None:
            raise
        return on_error(item, _message(e)), False
    if check is not None:
        try:
            check(item, result)
        except ValueError as e:
            if on_error is None:
                from minirt.errors import MinirtError

                raise MinirtError(f"a worker gave back a result minirt cannot use: {e}") from None
            return on_error(item, f"a worker gave back a result minirt cannot use: {str(e)[:300]}"), False
    return result, True


def _one(fn, item, on_error) -> tuple[Any, bool]:
    try:
        return fn(item), True
    except Exception as e:
        if on_error is None:
            raise
        return on_error(item, _message(e)), False


def _message(e: BaseException) -> str:
    name = type(e).__name__
    if name == "KilledWorker":
        return "the worker process grading it died (a crash or out of memory), also when run alone"
    text = str(e).splitlines()[0] if str(e) else ""
    return f"internal error: {name}: {text}" if text else f"internal error: {name}"


def timeout() -> float:
    """Seconds to reach a scheduler and read its greeting: ``MINIRT_SCHEDULER_TIMEOUT``, default 5."""
    from minirt.errors import MinirtError

    text = os.environ.get(TIMEOUT, "").strip()
    if not text:
        return DEFAULT_TIMEOUT
    try:
        t = float(text)
    except ValueError:
        t = float("nan")
    if not 0 < t <= 3600:
        raise MinirtError(f"{TIMEOUT}={text}: expected seconds, a number > 0 and <= 3600")
    return t


def _greeting(sock, wait: float) -> bytes:
    """What a Dask scheduler says first on a new connection, unasked: its handshake, one message of
    msgpack frames behind an 8-byte length. ValueError if what comes within ``wait`` seconds is not that."""
    import struct
    import time

    deadline = time.monotonic() + wait

    def read(n: int) -> bytes:
        got = b""
        while len(got) < n:
            sock.settimeout(max(0.01, deadline - time.monotonic()))
            try:
                chunk = sock.recv(n - len(got))
            except TimeoutError:
                raise ValueError(f"it did not greet as Dask does within {wait:g} s") from None
            if not chunk:
                raise ValueError("it closed the connection without a Dask greeting")
            got += chunk
        return got

    (length,) = struct.unpack("<Q", read(8))
    if not 16 <= length <= GREETING_MAX:
        raise ValueError("it answered, but not as a Dask scheduler does")
    return read(length)


def _is_handshake(message: bytes) -> bool:
    """Whether ``message`` is Dask's handshake: frames (a count, their lengths, their bytes) whose first is
    a msgpack map with the "python" and "pickle-protocol" entries. msgpack reads data, never code."""
    import struct

    import msgpack

    try:
        (n,) = struct.unpack_from("<Q", message)
        if not 1 <= n <= 16:
            return False
        lengths = struct.unpack_from(f"<{n}Q", message, 8)
        start = 8 + 8 * n
        if start + sum(lengths) != len(message):
            return False
        head = msgpack.unpackb(message[start : start + lengths[0]], raw=False, strict_map_key=False)
    except (struct.error, ValueError, msgpack.UnpackException, TypeError):
        return False
    return isinstance(head, dict) and "python" in head and "pickle-protocol" in head


def handshake(scheduler: str, wait: float | None = None) -> None:
    """One line (MinirtError) unless a Dask scheduler answers at a ``tcp://`` address within ``wait``
    seconds (``timeout()``): the port refuses or does not resolve, or what answers is not Dask -- a web
    server, a port that accepts and never speaks. Dask's Client would retry a refusing port until its own
    time-out, read a web server's reply as a message of exabytes (MemoryError), and wait on a silent port
    forever. An address without a scheme is tcp://, without a port Dask's 8786, as Dask reads them; other
    schemes (tls://) are left to Dask."""
    import socket
    from urllib.parse import urlsplit

    from minirt.errors import MinirtError

    wait = timeout() if wait is None else wait
    try:
        u = urlsplit(scheduler if "://" in scheduler else f"tcp://{scheduler}")
        host, port = u.hostname, u.port or 8786
    except ValueError:
        return  # Dask's own message says what is wrong with the address
    if u.scheme != "tcp" or not host:
        return
    try:
        sock = socket.create_connection((host, port), timeout=wait)
    except OSError as e:
        why = "no answer" if isinstance(e, TimeoutError) else e.strerror or type(e).__name__
        raise MinirtError(f"--scheduler {scheduler}: cannot reach a Dask scheduler there ({why})") from None
    try:
        with sock:
            message = _greeting(sock, wait)
    except (ValueError, OSError) as e:
        why = str(e) if isinstance(e, ValueError) else e.strerror or type(e).__name__
        raise MinirtError(f"--scheduler {scheduler}: not a Dask scheduler ({why}; {TIMEOUT} sets the wait)") from None
    if not _is_handshake(message):
        raise MinirtError(f"--scheduler {scheduler}: not a Dask scheduler (it answered, but not as Dask does)")


@contextlib.contextmanager
def _client(workers: int, scheduler: str | None) -> Iterator[Any]:
    from minirt.errors import MinirtError
    from minirt.jobs.logs import route_logs

    with contextlib.ExitStack() as stack:
        if scheduler is None:  # started first: the cluster's process starts while this one imports Dask
            from minirt.jobs.cluster import local_cluster

            address = stack.enter_context(local_cluster(workers))  # its own session: Ctrl-C is minirt's
        from distributed import Client

        route_logs()  # after importing distributed, which installs its handlers
        if scheduler is not None:
            wait = timeout()
            handshake(scheduler, wait)
            with _signals_held():
                try:
                    client = stack.enter_context(Client(scheduler, timeout=f"{wait}s"))
                except (OSError, TimeoutError, ValueError, MemoryError, EOFError, AssertionError) as e:
                    why = (str(e).splitlines() or [type(e).__name__])[0]
                    raise MinirtError(f"--scheduler {scheduler}: cannot reach a Dask scheduler there ({why})") from None
            yield client
            return
        where = address()  # waits for the cluster to start: Ctrl-C meanwhile stops it at once
        with _signals_held():  # a client half connected cannot be closed: Ctrl-C waits the moment it takes
            client = stack.enter_context(Client(where, timeout="30s"))
            client.run(_one_core)
            client.forward_logging("distributed", level=logging.ERROR)  # a worker's records, said here (OneLine)
        yield client


@contextlib.contextmanager
def _signals_held() -> Iterator[None]:
    """SIGINT, SIGTERM and SIGHUP wait until the block is done, then reach the handler they would have
    reached (the CLI's, which stops the run): Dask cannot close a cluster or a client interrupted half way
    through its start (an "Exception ignored in atexit callback" traceback at the exit)."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held: list[tuple[int, Any]] = []
    sigs = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
    before = {s: signal.getsignal(s) for s in sigs}
    for s in sigs:
        if before[s] not in (signal.SIG_IGN, None):
            signal.signal(s, lambda signum, frame: held.append((signum, frame)))
    try:
        yield
    finally:
        for s in sigs:
            if before[s] is not None:
                signal.signal(s, before[s])
        if held:
            signum, frame = held[0]
            handler = before[signum]
            if callable(handler):
                handler(signum, frame)  # raises (KeyboardInterrupt) inside the caller's clean-up
            else:
                signal.raise_signal(signum)


def _one_core() -> None:
    """In a local worker: Dr.Jit's thread pool to one thread. N workers on N cores then run N kernels at
    once instead of N pools of N threads contending for the same cores."""
    import drjit as dr

    dr.set_thread_count(1)
