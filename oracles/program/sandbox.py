"""Running untrusted code: bubblewrap, resource limits and a wall clock.

Every compile and every run of a student's program goes through ``run``. Inside bubblewrap (Debian's
``bubblewrap``, the sandbox Flatpak and many autograders use): no network (``--unshare-all``: new network,
PID, IPC, UTS and cgroup namespaces), the system visible read-only, a private empty
``/tmp``, one writable folder -- the run's own -- and ``--die-with-parent`` (if minirt dies, so does the
sandbox). Run as root, the program runs as the ``nobody`` user (util-linux's ``setpriv``) keeping one capability,
to read files whatever their mode: the kernel counts processes per user, and root's are never limited, so
a fork bomb would not be held otherwise. The system's folders (/usr, /etc without its secrets, ...) and
the program's own files are all it sees of the machine, read-only.
Inside, util-linux's ``prlimit`` sets the limits before the program starts: CPU seconds, address space,
file size, processes, open files (``Limits``). Outside, a wall clock: at the limit the sandbox's whole
process group is killed (its PID namespace dies with it). Standard output and error go to files in the
run's folder, so a program that prints a gigabyte meets the file-size limit, not minirt's memory.

Without bubblewrap (not installed, or user namespaces disabled) ``available`` says why in one line; the
caller refuses unless the user asked for ``sandbox=False`` (``--no-sandbox``), which keeps the limits and
the wall clock but not the isolation.
"""

from __future__ import annotations

import functools
import os
import shutil
import signal
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from minirt.jobs import processes

NOBODY = 65534
TAIL_BYTES = 4000  # of a program's standard error (and output) kept for its message and the page


@dataclass(frozen=True)
class Limits:
    """What one run may use. ``wall``: seconds of wall clock before its process group is killed; ``cpu``:
    CPU seconds (RLIMIT_CPU, whole seconds, at least 1; SIGXCPU, then SIGKILL a second later); ``memory``:
    bytes of address space (RLIMIT_AS: a program that asks for more gets an allocation failure, not the
    machine's memory); ``file_size``: the largest file it may write (RLIMIT_FSIZE; output and error are
    files too); ``processes``: processes and threads of its user at once (RLIMIT_NPROC); ``open_files``:
    descriptors (RLIMIT_NOFILE)."""

    wall: float = 60.0
    cpu: float = 60.0
    memory: int = 4 << 30
    file_size: int = 256 << 20
    processes: int = 64
    open_files: int = 256

    def prlimit(self) -> list[str]:
        return [
            "prlimit",
            # soft limit: SIGXCPU, which the run's reason names; the hard one a second later: SIGKILL for a
            # program that ignores it (equal limits sent SIGKILL alone, a death with no reason to give)
            f"--cpu={max(1, int(self.cpu + 0.999))}:{max(1, int(self.cpu + 0.999)) + 1}",
            f"--as={self.memory}",
            f"--fsize={self.file_size}",
            f"--nproc={self.processes}",
            f"--nofile={self.open_files}",
            "--",
        ]


@dataclass
class Outcome:
    """How a run ended: its exit status (negative: the signal that killed it), whether the wall clock
    ran out, its CPU seconds (user + system of the whole tree) and the tails of its output and error."""

    returncode: int
    timed_out: bool
    cpu_seconds: float
    stdout: str
    stderr: str
    sandboxed: bool = False

    @property
    def ok(self) -> bool:
        return self.returncode == 0 and not self.timed_out

    def reason(self, what: str, limits: Limits) -> str:
        """One line: why the run failed (empty when it did not)."""
        if self.timed_out:
            return f"{what} did not finish in {limits.wall:g} s (killed)"
        if self.returncode == 0:
            return ""
        if self.returncode < 0:
            sig = signal.Signals(-self.returncode).name
            return f"{what} was killed by {sig}{SIGNAL_WORDS.get(sig, '')}{last_line(self.stderr)}"
        if self.sandboxed and 128 < self.returncode <= 128 + 64:
            try:
                sig = signal.Signals(self.returncode - 128).name
            except ValueError:
                sig = ""
            if sig:  # bubblewrap passes a death by signal on as 128 + the signal
                why = f" (the sandbox's code for a death by {sig}{SIGNAL_WORDS.get(sig, '')})"
                return f"{what} failed with exit status {self.returncode}{why}{last_line(self.stderr)}"
        return f"{what} failed with exit status {self.returncode}{last_line(self.stderr)}"


SIGNAL_WORDS = {
    "SIGXCPU": ": its CPU seconds used up",
    "SIGXFSZ": ": it wrote more than its file-size limit, to a file or its output",
    "SIGKILL": ", killed",
    "SIGSEGV": ", a segmentation fault",
    "SIGABRT": ", aborted",
    "SIGFPE": ", an arithmetic exception",
}


def last_line(text: str) -> str:
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    return f": {lines[-1][:200]}" if lines else ""


@functools.cache
def available() -> tuple[bool, str]:
    """(usable, why not): can bubblewrap start a sandbox here? Tried once per process."""
    exe = shutil.which("bwrap")
    if exe is None:
        return False, "bubblewrap (bwrap) is not installed (Debian: apt-get install bubblewrap)"
    with tempfile.TemporaryDirectory() as tmp:
        return _probe(Path(tmp))


def _probe(folder: Path) -> tuple[bool, str]:
    probe = command(["true"], folder, Limits(wall=30.0, cpu=5.0), True)
    try:
        p = subprocess.run(probe, capture_output=True, timeout=30, check=False)
    except (OSError, subprocess.TimeoutExpired) as e:
        return False, f"bubblewrap cannot start a sandbox here ({e})"
    if p.returncode != 0:
        why = " ".join(p.stderr.decode("utf-8", "replace").split())[:200]
        return False, f"bubblewrap cannot start a sandbox here (no user namespaces?): {why}"
    return True, ""


SYSTEM = ("/usr", "/bin", "/sbin", "/lib", "/lib32", "/lib64", "/libx32", "/etc", "/opt")
MASKED = ("/etc/shadow", "/etc/gshadow", "/etc/shadow-", "/etc/gshadow-", "/etc/sudoers", "/etc/ssh")


def share_with_sandbox(folder: Path) -> None:
    """Let the sandbox's user write in ``folder`` (as root it runs as ``nobody``)."""
    if os.geteuid() == 0:
        os.chown(folder, NOBODY, NOBODY)
    folder.chmod(0o700)


def environment(folder: Path) -> dict[str, str]:
    """The program's whole environment: nothing of minirt's but the search path and the locale, its home
    its own folder, numerical libraries on one thread each (a thread is a process to RLIMIT_NPROC)."""
    keep = {k: os.environ[k] for k in ("PATH", "LANG", "LC_ALL") if k in os.environ}
    one = {k: "1" for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}
    return {**keep, **one, "HOME": str(folder), "TMPDIR": "/tmp", "PYTHONDONTWRITEBYTECODE": "1"}


def _binds(folder: Path, visible: list[Path]) -> list[str]:
    """The sandbox's file system: the system's folders and ``visible`` read-only (the secrets in /etc
    masked), a private /tmp, ``folder`` writable. Later mounts go over earlier ones: /tmp first."""
    out: list[str] = []
    for p in SYSTEM:
        if os.path.lexists(p):
            out += ["--ro-bind", p, p] if not os.path.islink(p) else ["--symlink", os.readlink(p), p]
    out += ["--dev", "/dev", "--proc", "/proc", "--tmpfs", "/tmp"]
    for p in sorted({str(v) for v in visible}):
        if os.path.isdir(p):
            out += ["--ro-bind", p, p]
    for p in MASKED:
        if os.path.isfile(p):
            out += ["--ro-bind", "/dev/null", p]
        elif os.path.isdir(p):
            out += ["--tmpfs", p]
    return [*out, "--bind", str(folder), str(folder)]


def command(cmd: list[str], folder: Path, limits: Limits, sandbox: bool, visible: list[Path] = ()) -> list[str]:
    """The full command line that runs ``cmd`` in ``folder`` under ``limits`` (in bubblewrap if ``sandbox``,
    with ``visible`` read-only beside the system's folders)."""
    inner = [*limits.prlimit(), *cmd]
    if not sandbox:
        return inner
    box = ["bwrap", *_binds(folder, list(visible)), "--chdir", str(folder), "--die-with-parent", "--new-session"]
    box += ["--unshare-ipc", "--unshare-pid", "--unshare-net", "--unshare-uts", "--unshare-cgroup-try"]
    if os.geteuid() != 0:
        return [*box, "--unshare-user", "--cap-drop", "ALL", "--", *inner]
    # root: no user namespace (nobody's uid must be the kernel's own for RLIMIT_NPROC to count), and
    # inside, nobody with one capability, reading files whatever their mode (the program's own, under
    # a folder only root may enter); the file system it sees is read-only but for its folder
    caps = ["--cap-add", "CAP_SETUID,CAP_SETGID,CAP_SETPCAP,CAP_DAC_READ_SEARCH"]
    drop = [
        "setpriv", f"--reuid={NOBODY}", f"--regid={NOBODY}", "--clear-groups", "--inh-caps=-all,+dac_read_search",
        "--ambient-caps=+dac_read_search", "--bounding-set=-all,+dac_read_search", "--",
    ]  # fmt: skip
    return [*box, *caps, "--", *drop, *inner]


def run(cmd: list[str], folder: Path, limits: Limits, sandbox: bool = True, visible: list[Path] = ()) -> Outcome:
    """Run ``cmd`` in ``folder`` (its working and only writable folder) under ``limits``; never raises for
    the program's failure. Its output and error are written to folder/.stdout and .stderr."""
    out_path, err_path = folder / ".stdout", folder / ".stderr"
    with open(out_path, "wb") as out, open(err_path, "wb") as err:
        if os.geteuid() == 0 and sandbox:
            os.chown(out_path, NOBODY, NOBODY)
            os.chown(err_path, NOBODY, NOBODY)
        full = command(cmd, folder, limits, sandbox, visible)
        p = processes.spawn(full, cwd=folder, stdin=subprocess.DEVNULL, stdout=out, stderr=err, env=environment(folder))
        processes.track(p)
        try:
            status, cpu, timed_out = _wait(p, limits.wall)
        finally:
            processes.kill(p)  # the whole group, whatever it left behind
            processes.untrack(p)
    return Outcome(status, timed_out, cpu, _tail(out_path), _tail(err_path), sandbox)


def _wait(p: subprocess.Popen, wall: float) -> tuple[int, float, bool]:
    """(exit status, CPU seconds of the child's whole tree, whether the wall clock ran out): os.wait4 gives
    the child's own resource use, which os.times would mix with every other child minirt has."""
    deadline = time.monotonic() + wall
    timed_out = False
    delay = 0.002
    while True:
        pid, status, usage = os.wait4(p.pid, os.WNOHANG)
        if pid:
            break
        if time.monotonic() >= deadline:
            timed_out = True
            processes.kill(p)
            pid, status, usage = os.wait4(p.pid, 0)
            break
        time.sleep(delay)
        delay = min(0.05, delay * 1.5)
    p.returncode = os.waitstatus_to_exitcode(status)
    return p.returncode, usage.ru_utime + usage.ru_stime, timed_out


def _tail(path: Path) -> str:
    try:
        with open(path, "rb") as f:
            f.seek(max(0, path.stat().st_size - TAIL_BYTES))
            return f.read().decode("utf-8", "replace")
    except OSError:
        return ""
