"""minirt.jobs.batch: results in the items' order however the work is spread (here, on local Dask worker
processes, or on a running cluster's workers), and a failing or crashing call is one result, not the end
of the run."""

from __future__ import annotations

import contextlib
import http.server
import os
import socket
import struct
import threading
import time
import warnings

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

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


def chatty(x: int) -> int:
    print("x" * 100_000, flush=True)  # more than a pipe holds
    return x


def square_where(x: int) -> tuple[int, int]:
    """slow_square's result (later items finish first, 0.05-0.25 s each) and the process that computed it."""
    time.sleep(0.05 * (5 - x % 5))
    return x * x, os.getpid()


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
def test_local_workers_in_order_errors_and_crashes(capfd):
    """Two worker processes: the same results in the same order as a loop here; the work really ran in
    other processes; a call that raises, a call whose process dies and a result that fails the check are
    each one error result -- and nothing of Dask's reaches the terminal (no "Compute Failed", no traceback)."""
    # one cluster for the order and the processes: 12 items of 0.05-0.25 s (1.95 s in all) keep both
    # workers busy, as 6 items of 0.2 s did on a cluster of their own (each start costs seconds of CPU)
    got = jobs.run(square_where, list(range(12)), workers=2)
    assert [square for square, _ in got] == [x * x for x in range(12)]
    pids = [p for _, p in got]
    assert os.getpid() not in pids and len(set(pids)) == 2
    done = []
    got = jobs.run(
        fails_on_three,
        list(range(5)),
        workers=2,
        on_done=lambda item, r: done.append(item),
        on_error=lambda item, msg: msg,
        check=lambda item, r: None if r != 4 else (_ for _ in ()).throw(ValueError("four is not a result")),
    )
    assert got[:3] == [0, 1, 2] and "three is not allowed" in got[3]
    assert got[4] == "a worker gave back a result minirt cannot use: four is not a result"
    assert sorted(done) == [0, 1, 2]
    # A call whose process dies is one error result, the others are theirs. Items sharing the dying worker
    # (queued behind it, or done but not yet reported) are run again alone: however the scheduler spread
    # them, the one that kills its worker is the only one that died. (16 items prove what 4 did, on one
    # cluster instead of two.)
    got = jobs.run(dies_on_two, list(range(16)), workers=2, on_error=lambda item, msg: msg)
    assert [g for k, g in enumerate(got) if k != 2] == [k for k in range(16) if k != 2]
    assert got[2] == "the worker process grading it died (a crash or out of memory), also when run alone"
    said = capfd.readouterr()
    assert "Compute Failed" not in said.err and "Traceback" not in said.err, said.err


@pytest.mark.slow
def test_what_workers_print_goes_to_standard_error(capfd):
    """A worker writing to its standard output neither blocks (the cluster's process reads the address from
    a pipe) nor lands in minirt's standard output, which may be JSON (--json -)."""
    assert jobs.run(chatty, list(range(4)), workers=2) == [0, 1, 2, 3]
    said = capfd.readouterr()
    assert "xxx" not in said.out and said.err.count("x" * 100_000) == 4


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
        n_workers=1, processes=False, protocol="tcp", host="127.0.0.1", dashboard_address=None,
        scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
    ) as cluster:  # fmt: skip
        assert jobs.run(slow_square, list(range(5)), scheduler=cluster.scheduler_address) == [0, 1, 4, 9, 16]


def test_unreachable_scheduler_is_one_line():
    with pytest.raises(MinirtError, match=r"--scheduler tcp://127.0.0.1:9: cannot reach a Dask scheduler"):
        jobs.run(slow_square, [1], scheduler="tcp://127.0.0.1:9")


# ---- clusters that are not there ----------------------------------------------------------------


@contextlib.contextmanager
def server(kind: str):
    """A loopback port that is not a Dask scheduler: a web server, a port that accepts and never says a
    word, one that says garbage, one that claims a message of 3 EiB. Stops with the block."""
    if kind == "http":
        httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), http.server.SimpleHTTPRequestHandler)
        t = threading.Thread(target=httpd.serve_forever, daemon=True)
        t.start()
        try:
            yield f"tcp://127.0.0.1:{httpd.server_address[1]}"
        finally:
            httpd.shutdown()
            httpd.server_close()
        return
    said = {"silent": b"", "garbage": b"SSH-2.0-OpenSSH_9.6\r\n", "huge": struct.pack("<Q", 3 << 60) + bytes(64)}[kind]
    listener = socket.create_server(("127.0.0.1", 0))
    stop = threading.Event()

    def serve():
        listener.settimeout(0.1)
        conns = []
        while not stop.is_set():
            try:
                c, _ = listener.accept()
            except TimeoutError:
                continue
            conns.append(c)
            if said:
                c.sendall(said)
        for c in conns:
            c.close()

    t = threading.Thread(target=serve, daemon=True)
    t.start()
    try:
        yield f"tcp://127.0.0.1:{listener.getsockname()[1]}"
    finally:
        stop.set()
        t.join()
        listener.close()


@pytest.mark.parametrize("kind", ["http", "silent", "garbage", "huge", "silent, no scheme"])
def test_something_that_is_not_a_scheduler_is_one_line_within_seconds(kind, monkeypatch):
    monkeypatch.setenv(jobs.TIMEOUT, "2")
    with server(kind.split(",")[0]) as address:
        if "no scheme" in kind:
            address = address.removeprefix("tcp://")  # Dask reads it as tcp://
        t0 = time.monotonic()
        with pytest.raises(MinirtError, match=rf"--scheduler {address}: not a Dask scheduler") as e:
            jobs.run(slow_square, [1], scheduler=address)
        assert time.monotonic() - t0 < 10
    assert "\n" not in str(e.value)


def test_the_cli_says_so_in_one_line_and_exit_2(tmp_path):
    """`minirt grade --class` and `minirt check` on a web server's port: one line, exit 2, at once."""
    from support.inproc import minirt

    with server("http") as address:
        t0 = time.monotonic()
        p = minirt("check", "exercise", "--size", "8x8", "-b", "embree", "-q", "--scheduler", address)
        assert time.monotonic() - t0 < 30
    assert p.returncode == 2 and "Traceback" not in p.stderr, p.stderr
    (line,) = p.stderr.splitlines()
    assert line.startswith(f"minirt: error: --scheduler {address}: not a Dask scheduler"), line


def test_a_bad_timeout_is_one_line(monkeypatch):
    monkeypatch.setenv(jobs.TIMEOUT, "soon")
    with pytest.raises(MinirtError, match=r"MINIRT_SCHEDULER_TIMEOUT=soon: expected seconds"):
        jobs.run(slow_square, [1], scheduler="tcp://127.0.0.1:9")


@settings(max_examples=200, deadline=None, derandomize=True)
@given(st.binary(max_size=300))
def test_any_greeting_is_read_as_dask_or_refused(said):
    """Whatever a port says first (here through a socket pair), the greeting reader gives the bytes of one
    message or ValueError, and the handshake test says yes or no: never another exception, never a wait
    past its time-out, never a read of more than the message's length (capped)."""
    a, b = socket.socketpair()
    with a, b:
        b.sendall(said)
        b.shutdown(socket.SHUT_WR)
        try:
            message = jobs._greeting(a, 0.5)
        except ValueError:
            return
        assert isinstance(jobs._is_handshake(message), bool)


def test_a_real_greeting_is_dask():
    """The bytes a Dask 2024+ scheduler sends first (its handshake), taken from a running one."""
    import msgpack

    head = msgpack.packb({"compression": None, "python": [3, 11, 7], "pickle-protocol": 5})
    message = struct.pack("<QQ", 1, len(head)) + head
    a, b = socket.socketpair()
    with a, b:
        b.sendall(struct.pack("<Q", len(message)) + message)
        assert jobs._is_handshake(jobs._greeting(a, 1.0))


# ---- what comes back from a worker ---------------------------------------------------------------


def test_a_result_is_checked_before_it_is_used():
    """A finished job's result (as a future gives it) that fails the caller's check is on_error's row,
    with the reason in one line; without on_error it is one line for the user."""

    class Done:
        def __init__(self, value):
            self.value = value

        def result(self):
            return self.value

    def must_be_int(item, result):
        if not isinstance(result, int):
            raise ValueError(f"{type(result).__name__}, not int")

    assert jobs._collect(Done(4), 2, None, must_be_int) == (4, True)
    got = jobs._collect(Done("four"), 2, lambda item, msg: f"error {item}: {msg}", must_be_int)
    assert got == ("error 2: a worker gave back a result minirt cannot use: str, not int", False)
    with pytest.raises(MinirtError, match="cannot use: str, not int"):
        jobs._collect(Done("four"), 2, None, must_be_int)


def test_a_child_started_from_a_passing_thread_outlives_the_thread_not_minirt():
    """The kernel's parent-death signal follows the thread that started a child: ``processes.spawn`` from
    a thread that then ends (a check's lane) must not take the child with it -- yet a SIGKILL of minirt
    still does."""
    import shutil
    import signal
    import subprocess
    import sys
    import textwrap

    from minirt.jobs import processes

    if shutil.which("setpriv") is None:  # no parent-death signal at all here: nothing to keep alive
        pytest.skip("setpriv is not installed")
    box: list = []
    # the thread ends once setpriv has set the signal and become `sleep` (before that, no signal is set)
    t = threading.Thread(target=lambda: (box.append(processes.spawn(["sleep", "30"])), _became(box[0].pid, "sleep")))
    t.start()
    t.join()
    time.sleep(0.5)
    try:
        assert box[0].poll() is None, "killed when the thread that asked for it ended"
    finally:
        processes.kill(box[0])
        box[0].wait()
    code = textwrap.dedent("""
        import os, sys, threading, time
        from minirt.jobs import processes
        box = []
        t = threading.Thread(target=lambda: box.append(processes.spawn(["sleep", "30"])))
        t.start(); t.join()
        for _ in range(300):  # until setpriv has set the signal and become `sleep`
            try:
                if open(f"/proc/{box[0].pid}/comm").read().strip() == "sleep":
                    break
            except OSError:
                pass
            time.sleep(0.01)
        print(box[0].pid, flush=True)
        time.sleep(60)
    """)
    p = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    child = int(p.stdout.readline())
    os.kill(p.pid, signal.SIGKILL)
    p.wait()
    for _ in range(50):
        if not _alive(child):
            break
        time.sleep(0.1)
    assert not _alive(child), "left running after minirt's SIGKILL"


def _became(pid: int, name: str) -> None:
    """Wait (up to 3 s) until process ``pid`` runs ``name`` (setpriv has done its work and exec'd it)."""
    from pathlib import Path

    for _ in range(300):
        try:
            if Path(f"/proc/{pid}/comm").read_text().strip() == name:
                return
        except OSError:
            pass
        time.sleep(0.01)


def _alive(pid: int) -> bool:
    from pathlib import Path

    try:
        state = Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0]
    except OSError:
        return False
    return state != "Z"
