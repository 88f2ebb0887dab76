"""Ctrl-C is one line: a terminal's interrupt (SIGINT to the whole foreground process group, as a terminal
sends it) in the middle of `minirt grade --class ... --workers 2` or `minirt fuzz --workers 2` stops the
run with exit status 130 and the one line "minirt: aborted" -- no worker's traceback -- and leaves nothing
running: not the embedded cluster's scheduler, nannies or worker processes. SIGTERM likewise (143).

Each command runs as a child in a session of its own (its own process group, like a shell's job); the
signal goes to that group once the run is visibly under way (pages or cache entries being written).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from support.inproc import minirt

ROOT = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.slow


def scene_copy(stem: str, dest: Path, size: int) -> Path:
    lines = (ROOT / "scenes" / f"{stem}.toml").read_text().splitlines()
    lines = [ln for ln in lines if ln.split("=")[0].strip() not in ("width", "height", "samples")]
    dest.write_text("\n".join(lines).replace("[camera]", f"[camera]\nwidth = {size}\nheight = {size}", 1) + "\n")
    return dest


@pytest.fixture(scope="module")
def klass(tmp_path_factory) -> tuple[Path, Path]:
    """A class of 40 students x 2 scenes at 32x32: one image matches, the other has its rows flipped."""
    t = tmp_path_factory.mktemp("interrupt-class")
    scenes = t / "scenes"
    scenes.mkdir()
    for stem in ("rules", "exercise"):
        scene_copy(stem, scenes / f"{stem}.toml", 32)
    r = t / "r"
    assert minirt("render", scenes / "rules.toml", "--out", r, "-q").returncode == 0
    assert minirt("render", scenes / "exercise.toml", "--out", r, "-q", "--rule", "rows=bottom-up").returncode == 0
    (flipped,) = r.glob("exercise.reference+*.png")
    for i in range(40):
        s = t / "class" / f"s{i:02d}"
        s.mkdir(parents=True)
        (s / "rules.png").write_bytes((r / "rules.reference.png").read_bytes())
        (s / "exercise.png").write_bytes(flipped.read_bytes())
    return t / "class", scenes


def descendants(pid: int) -> set[int]:
    """The processes below ``pid`` now (from /proc)."""
    children: dict[int, list[int]] = {}
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                ppid = int(Path(f"/proc/{d}/stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            children.setdefault(ppid, []).append(int(d))
    found, todo = set(), [pid]
    while todo:
        for c in children.get(todo.pop(), []):
            found.add(c)
            todo.append(c)
    return found


def alive(pids: set[int]) -> set[int]:
    left = set()
    for p in pids:
        try:
            state = Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if state != "Z":
            left.add(p)
    return left


def interrupt(args: list, started, sig: int = signal.SIGINT) -> tuple[subprocess.CompletedProcess, set[int]]:
    """Run ``minirt ARGS`` in a new session, send ``sig`` to its process group once ``started()`` is true
    (at most 240 s), and return the finished run and what was still alive of its processes 10 s later."""
    p = subprocess.Popen(
        [sys.executable, "-m", "minirt", *map(str, args)], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True, start_new_session=True, stdin=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 240
        while not started() and p.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert p.poll() is None, f"the run ended before it could be interrupted: {p.communicate()}"
        below = descendants(p.pid)
        os.killpg(p.pid, sig)
        out, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()
    deadline = time.monotonic() + 10
    while alive(below) and time.monotonic() < deadline:
        time.sleep(0.1)
    return subprocess.CompletedProcess(args, p.returncode, out, err), alive(below)


def test_ctrl_c_during_a_class_on_two_workers_is_one_line(klass, tmp_path):
    people, scenes = klass
    out = tmp_path / "out"
    run, left = interrupt(
        ["grade", "--class", people, "--scenes", scenes, "--out", out, "--workers", 2, "-q"],
        lambda: len(list((out / "pages").glob("*.html"))) >= 2,
    )
    assert run.returncode == 130, (run.returncode, run.stderr)
    assert run.stderr == "minirt: aborted\n", run.stderr
    assert left == set(), "processes left running"
    assert not (out / "grades.csv").exists()  # the class's tables are written at the end, whole or not at all


def test_sigterm_during_a_class_on_two_workers_is_one_line(klass, tmp_path):
    people, scenes = klass
    out = tmp_path / "out"
    run, left = interrupt(
        ["grade", "--class", people, "--scenes", scenes, "--out", out, "--workers", 2, "-q"],
        lambda: len(list((out / "pages").glob("*.html"))) >= 2,
        signal.SIGTERM,
    )
    assert run.returncode == 143 and run.stderr == "minirt: stopped by SIGTERM\n", run.stderr
    assert left == set()


def test_ctrl_c_during_fuzz_on_two_workers_is_one_line(tmp_path):
    out = tmp_path / "out"
    run, left = interrupt(
        ["fuzz", "--count", 60, "--size", "16x16", "--workers", 2, "-o", out, "-q"],
        lambda: any((out / "cache").glob("*.json")),
    )
    assert run.returncode == 130, (run.returncode, run.stderr)
    assert run.stderr == "minirt: aborted\n", run.stderr
    assert left == set()
    assert not (out / "fuzz.json").exists()


def test_ctrl_c_while_the_cluster_starts_is_one_line(klass, tmp_path):
    """The interrupt as the embedded cluster is still starting (its process just started): the cluster's
    processes are in a session of their own, so none of them prints anything, and none is left."""
    people, scenes = klass
    out = tmp_path / "out"
    seen: list[int] = []

    def cluster_starting() -> bool:
        seen.extend(q for q in descendants(os.getpid()) if b"minirt.jobs.cluster" in _cmdline(q))
        return bool(seen)

    run, left = interrupt(
        ["grade", "--class", people, "--scenes", scenes, "--out", out, "--workers", 2, "-q"], cluster_starting
    )
    assert run.returncode == 130 and run.stderr == "minirt: aborted\n", run.stderr
    assert left == set() and alive(set(seen)) == set()


def _cmdline(pid: int) -> bytes:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return b""


def test_sigkill_of_minirt_takes_the_cluster_with_it(klass, tmp_path):
    """SIGKILL runs no handler: the cluster's process dies with minirt (setpriv --pdeathsig KILL, or the
    end of its standard input), and its workers with their nanny."""
    people, scenes = klass
    out = tmp_path / "out"
    run, left = interrupt(
        ["grade", "--class", people, "--scenes", scenes, "--out", out, "--workers", 2, "-q"],
        lambda: len(list((out / "pages").glob("*.html"))) >= 2,
        signal.SIGKILL,
    )
    assert run.returncode == -signal.SIGKILL
    assert left == set(), "processes left running"
