"""minirt.jobs.batch: results in the items' order however the work is spread (here, on local Dask worker
processes, or on a running cluster's workers), and a failing or crashing call is one result, not the end
of the run."""

from __future__ import annotations

import os
import socket
import time
import warnings

import pytest

from minirt.errors import MinirtError
from minirt.jobs import batch as jobs


def slow_square(x: int) -> int:
    time.sleep(0.02 * (5 - x % 5))  # later items finish first
    return x * x


def fails_on_three(x: int) -> int:
    if x == 3:
        raise ValueError("three is not allowed")
    return x


def dies_on_two(x: int) -> int:
    if x == 2:
        os._exit(1)  # the worker process vanishes, as in a segfault
    return x


def pid(_: int) -> int:
    time.sleep(0.2)
    return os.getpid()


def test_inline_in_order_with_progress():
    seen = []
    got = jobs.run(slow_square, range(6), workers=1, on_done=lambda item, r: seen.append(item))
    assert got == [0, 1, 4, 9, 16, 25] and seen == list(range(6))


def test_inline_error_is_a_result():
    got = jobs.run(fails_on_three, range(5), on_error=lambda item, msg: f"error {item}: {msg}")
    assert got == [0, 1, 2, "error 3: internal error: ValueError: three is not allowed", 4]
    with pytest.raises(ValueError):
        jobs.run(fails_on_three, range(5))


def test_default_workers():
    assert jobs.default_workers(0) == 1 and jobs.default_workers(15) == 1
    assert jobs.default_workers(10_000) == jobs.cores()


@pytest.mark.slow
def test_local_workers_in_order_errors_and_crashes():
    """Two worker processes: the same results in the same order as a loop here; the work really ran in
    other processes; a call that raises and a call whose process dies are each one error result."""
    got = jobs.run(slow_square, list(range(12)), workers=2)
    assert got == [x * x for x in range(12)]
    pids = jobs.run(pid, list(range(6)), workers=2)
    assert os.getpid() not in pids and len(set(pids)) == 2
    done = []
    got = jobs.run(
        fails_on_three,
        list(range(5)),
        workers=2,
        on_done=lambda item, r: done.append(item),
        on_error=lambda item, msg: msg,
    )
    assert got[:3] == [0, 1, 2] and got[4] == 4 and "three is not allowed" in got[3]
    assert sorted(done) == [0, 1, 2, 4]
    got = jobs.run(dies_on_two, list(range(4)), workers=2, on_error=lambda item, msg: msg)
    assert got[0] == 0 and got[1] == 1 and got[3] == 3 and "died" in got[2]


def test_a_busy_dashboard_port_is_not_touched():
    """A local cluster serves its scheduler's HTTP routes on a free loopback port, not on 8787 of every
    interface: with 8787 taken (here, or by whoever has it) it neither warns nor moves elsewhere."""
    busy = socket.socket()
    try:
        busy.bind(("", 8787))
        busy.listen()
    except OSError:
        pass  # someone else holds it: as busy as it gets
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            assert jobs.run(slow_square, [1, 2], workers=2) == [1, 4]
    finally:
        busy.close()
    assert [str(w.message) for w in caught if "8787" in str(w.message)] == []


@pytest.mark.slow
def test_running_cluster_by_address():
    """--scheduler ADDRESS: a cluster someone started (here a local one on the loopback interface)."""
    from distributed import LocalCluster

    with LocalCluster(
        n_workers=1, processes=False, protocol="tcp", host="127.0.0.1", dashboard_address=None
    ) as cluster:
        assert jobs.run(slow_square, list(range(5)), scheduler=cluster.scheduler_address) == [0, 1, 4, 9, 16]


def test_unreachable_scheduler_is_one_line():
    with pytest.raises(MinirtError, match=r"--scheduler tcp://127.0.0.1:9: cannot reach a Dask scheduler"):
        jobs.run(slow_square, [1], scheduler="tcp://127.0.0.1:9")
