"""Running POV-Ray: its command line, its process (killed with minirt, timed out when hung), its
output files, its errors and timings, its version.

One render is one or two processes side by side (PovrayOracle._render): an EXR animation whose
frame_number selects the pass (float colour, geometry frames, +UA for the hit mask) and, unless
antialiased, the 8-bit PNG of the colour frames (+FN8 File_Gamma=1.0: POV-Ray's own, exact rounding).
Each pays POV-Ray's ~0.65 s start-up once. ``-D`` (no display), ``+Q9`` (full quality), ``-A`` (one ray
per pixel) or ``+A0.0 +R{R}`` (antialiasing, R up to MAX_ANTIALIAS); the mesh camera renders one extra
first row, dropped when read back.
"""

from __future__ import annotations

import functools
import re
import shutil
import subprocess
import time
from pathlib import Path

from minirt.jobs import processes
from minirt.model.scene import Scene

NAME = "povray"
INSTALL_HINT = "povray not found on PATH; install: sudo apt-get install povray"
MAX_ANTIALIAS = 9  # POV-Ray accepts Antialias_Depth 1..9
_PARSE_ERR = re.compile(r"^File '[^']*' line (\d+):\s*(.*)$")
_TIME = re.compile(r"^\s*(Parse|Bounding|Trace|Photon|Radiosity) Time:.*\(([\d.]+) seconds\)")


def command(
    scene: Scene,
    n_frames: int,
    first: int,
    last: int,
    kind: str,
    stem: str = "out",
    threads: int | None = None,
    antialias: int | None = None,
    mesh_camera: bool = False,
) -> list[str]:
    """The povray command line: frames first..last of an n_frames animation; kind "exr" or "png8".

    ``antialias`` R (1..MAX_ANTIALIAS): ``+A0.0 +R{R}`` -- threshold 0, so every pixel is supersampled
    with POV-Ray's own jittered sub-pixel grid of depth R (method 1, default jitter); None: ``-A``."""
    w, h = scene.camera.width, scene.camera.height
    if mesh_camera:
        h += 1  # POV-Ray gives row j the mesh camera's triangles of row j - 1: the first row is dropped
    aa = ["-A"] if antialias is None else ["+A0.0", f"+R{int(antialias)}"]
    cmd = ["povray", "-D", *aa, "+Q9", f"+W{w}", f"+H{h}"]
    if kind == "exr":
        cmd += ["+FE", "+UA", f"+O{stem}.exr"]
    else:
        cmd += ["+FN8", "File_Gamma=1.0", f"+O{stem}.png"]
    if n_frames > 1:  # an animation: frame_number selects the pass; outputs are numbered stem1, stem2, ...
        cmd += ["+KFI1", f"+KFF{n_frames}", f"+SF{first}", f"+EF{last}"]
    if threads:
        cmd.append(f"+WT{int(threads)}")
    cmd.append("+Iscene.pov")
    return cmd


class PovrayError(Exception):
    """POV-Ray failed; the message is one line."""


def parse_error(stderr: str) -> str:
    """One line from POV-Ray's output saying what went wrong (its parse error with the line number)."""
    lines = stderr.splitlines()
    for i, ln in enumerate(lines):
        m = _PARSE_ERR.match(ln.strip())
        if m and "error" in ln.lower():
            msg = m.group(2)
            for cont in lines[i + 1 :]:  # POV-Ray wraps messages at 80 columns
                c = cont.strip()
                if not c or c.startswith(("Fatal", "Render failed", "File '")):
                    break
                msg += " " + c
            return f"POV-Ray: scene.pov line {m.group(1)}: {msg}"
    for ln in reversed(lines):
        c = ln.strip()
        if re.search(r"error|failed|cannot|unable", c, re.I) and "user configuration file" not in c:
            return f"POV-Ray: {c}"
    tail = [ln.strip() for ln in lines if ln.strip()]
    return f"POV-Ray: {tail[-1]}" if tail else "POV-Ray failed without a message"


def _timings(stderr: str) -> dict[str, float]:
    out: dict[str, float] = {}
    for ln in stderr.splitlines():
        m = _TIME.match(ln)
        if m:
            key = m.group(1).lower()
            out[key] = out.get(key, 0.0) + float(m.group(2))
    return out


def default_timeout(scene: Scene, frames: int, samples: int = 1) -> float:
    """Seconds one POV-Ray pass may take before it counts as hung: 30 s of start-up and parsing, plus
    10 us per pixel, frame and sample. Measured: three_balls at 1024x1024, 4 frames, 1 sample, traces
    4.2 M pixel-frames in 3.2 s (about 0.75 us each, 2 cores), so this allows a machine or a scene 13x
    slower; a 16384x16384 render gets about 3 hours. The render option "timeout" overrides it."""
    return 30.0 + 1e-5 * scene.camera.width * scene.camera.height * frames * max(1, samples)


# POV-Ray 3.7's front end gives up when its worker threads have not started within its own fixed wait
# (vfeInitializeTimedOut, "Timed out waiting for worker thread startup"): a start-up race a loaded machine
# loses now and then (1 of 5,000 campaign jobs at a load average of 6), before any scene is read or pixel
# traced. Such a pass is run again, up to STARTUP_RETRIES more times; any other failure is the verdict.
STARTUP_TIMEOUT = "Timed out waiting for worker thread startup"
STARTUP_RETRIES = 3


def run_povray(cmd: list[str], cwd: Path, timeout: float) -> tuple[str, dict[str, float]]:
    """Run one POV-Ray command (``command``) in ``cwd`` within ``timeout`` seconds: its output and its
    timings. A start-up that timed out is tried again (``STARTUP_RETRIES``); any other failure raises
    PovrayError with its reason."""
    for attempt in range(STARTUP_RETRIES):
        try:
            return _run_once(cmd, cwd, timeout)
        except PovrayError as e:
            if STARTUP_TIMEOUT not in str(e):
                raise
            time.sleep(0.1 * (attempt + 1))
    return _run_once(cmd, cwd, timeout)  # the last try: whatever it says is the verdict


def _run_once(cmd: list[str], cwd: Path, timeout: float) -> tuple[str, dict[str, float]]:
    exe = shutil.which(cmd[0])
    if exe is None:
        raise FileNotFoundError(INSTALL_HINT)
    t0 = time.perf_counter()
    try:
        p = processes.run([exe, *cmd[1:]], cwd=cwd, timeout=timeout)  # dies with minirt (see processes)
    except subprocess.TimeoutExpired:
        raise PovrayError(f"POV-Ray timed out after {timeout:g} s") from None
    wall = time.perf_counter() - t0
    if p.returncode < 0:
        raise PovrayError(f"POV-Ray crashed (signal {-p.returncode}): {parse_error(p.stderr + p.stdout)}")
    if p.returncode != 0:
        raise PovrayError(parse_error(p.stderr + p.stdout))
    tm = _timings(p.stderr + p.stdout)
    inside = tm.get("parse", 0.0) + tm.get("bounding", 0.0) + tm.get("trace", 0.0)
    return p.stderr, {"wall": wall, **tm, "setup": max(wall - inside, 0.0)}


@functools.lru_cache(maxsize=8)
def povray_version(exe: str, mtime_ns: int, size: int) -> str | RuntimeError:
    """``povray --version`` of one executable, once per process (each call is a ~0.6 s start-up, and a
    check asks for every scene and pass); keyed by the file's path, time and size, so another povray
    on PATH is asked again. A failure is cached too (returned, not raised): a --version that hangs costs
    its time-out once per run, not once per scene."""
    try:  # a --version that hangs is a broken install: 10 s is 15x POV-Ray's own start-up
        p = processes.run([exe, "--version"], timeout=10)
    except subprocess.TimeoutExpired:
        return RuntimeError(f"'{exe} --version' did not answer in 10 s")
    except OSError as e:
        return RuntimeError(f"cannot run '{exe} --version': {e.strerror or e}")
    m = re.search(r"POV-Ray\s+(\d+(?:\.\d+)+)", p.stdout + p.stderr)
    if not m:
        said = " ".join((p.stdout + p.stderr).split())[:80]
        return RuntimeError(f"'{exe} --version' does not say it is POV-Ray (it said: {said!r})")
    return f"POV-Ray {m.group(1)}"


def frame_files(cwd: Path, stem: str, ext: str) -> dict[int, Path]:
    """The files POV-Ray wrote in ``cwd`` for the frames of one run, by frame number: ``stem<N>.<ext>``
    (a single frame, not numbered, is frame 1)."""
    out = {}
    for p in cwd.glob(f"{stem}*.{ext}"):
        num = p.name[len(stem) : -len(ext) - 1] or "1"  # a single frame is not numbered
        if num.isdigit():
            out[int(num)] = p
    return out
