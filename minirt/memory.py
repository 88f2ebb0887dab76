"""Memory before long work: a job that cannot fit is one clear line before it starts, never a kill.

Linux over-commits: an allocation larger than the machine rarely fails where it is made; the pages fail
later, when touched, and the kernel's OOM killer ends the process with SIGKILL -- no message, no exit
status of ours, outputs half done. So commands that hold whole images estimate what they will hold from
measured figures and compare it with the memory this process may still use: the kernel's MemAvailable,
or the control group's limit minus its use when that is smaller (a container's).

The figures, measured with ``/usr/bin/time -v minirt check SCENES --size WxH --backend B -q`` (peak
resident set, 2 cores; POV-Ray's own process is not counted, it holds its image only):

| scenes, size, backends | peak |
|---|---|
| exercise 1024², reference only | 0.80 GB |
| exercise 1024², embree | 1.78 GB |
| exercise, shadows, three_balls 1024², embree | 3.19 GB |
| exercise 1024², mitsuba (povray: the same) | 2.91 GB |
| exercise 1024², all three | 4.11 GB |
| exercise, shadows, three_balls 512², all three | 3.15 GB |

Fitted: a base of 0.4 GB; per pixel of every scene the reference's buffers kept for the report, 0.45
KB, and each oracle's render and figures, 1.4 KB (Mitsuba, POV-Ray) or 0.22 KB (Embree, geometry
only); plus, for the scene being checked, ~0.85 KB per pixel while a check runs. The estimate is
within -5 % .. +15 % of the table, so it refuses only checks that would not have fitted, or
nearly so; the stochastic check of a scene with many samples was not measured (its sample renders are
tiled, so they add little per pixel).
"""

from __future__ import annotations

from pathlib import Path

BASE_BYTES = 400 << 20  # Python, NumPy, Dr.Jit, Mitsuba and their kernels
REFERENCE_PER_PIXEL = 450  # the reference render kept for the report
ORACLE_PER_PIXEL = {"mitsuba": 1400, "povray": 1400, "embree": 220}  # each oracle's render and figures kept
CHECK_PER_PIXEL = 850  # the check running (freed afterwards)


def available() -> int | None:
    """Bytes this process may still allocate, or None when the system does not say."""
    avail = None
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                avail = int(line.split()[1]) * 1024
                break
    except (OSError, ValueError, IndexError):
        avail = None
    try:  # cgroup v2: a container's limit
        limit = Path("/sys/fs/cgroup/memory.max").read_text().strip()
        if limit != "max":
            used = int(Path("/sys/fs/cgroup/memory.current").read_text().strip())
            left = int(limit) - used
            avail = left if avail is None else min(avail, left)
    except (OSError, ValueError):
        pass
    return avail


def check_bytes(pixels: list[int], oracles: list[str], local_workers: int = 0) -> int:
    """Peak bytes on this machine of checking scenes of these pixel counts against these oracles: the
    result keeps every scene's renders (for the report), one check runs at a time here -- or one in each
    of ``local_workers`` worker processes, each with its own base and reference."""
    per_pixel = REFERENCE_PER_PIXEL + sum(ORACLE_PER_PIXEL.get(n, max(ORACLE_PER_PIXEL.values())) for n in oracles)
    kept = sum(pixels) * per_pixel
    running = max(pixels, default=0) * CHECK_PER_PIXEL if oracles else 0
    workers = local_workers * (BASE_BYTES + max(pixels, default=0) * REFERENCE_PER_PIXEL)
    return int(BASE_BYTES + kept + max(1, local_workers) * running + workers)


def gb(n: int) -> str:
    return f"{n / 2**30:.1f} GB"
