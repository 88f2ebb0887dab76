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
tiled, so they add little per pixel). Renders and grades have their own figures, beside their
estimates below.
"""

from __future__ import annotations

from pathlib import Path

BASE_BYTES = 400 << 20  # Python, NumPy, Dr.Jit, Mitsuba and their kernels
CHECK_PER_PIXEL = 850  # the check running (freed afterwards)
# What each backend keeps per pixel is the backend's own figure (minirt.model.backend: check_kept,
# render_kept, render_running), measured as said here; callers pass those figures in.


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


def check_bytes(pixels: list[int], reference_kept: int, oracles_kept: list[int], local_workers: int = 0) -> int:
    """Peak bytes on this machine of checking scenes of these pixel counts against oracles that keep
    ``oracles_kept`` bytes a pixel each (the reference ``reference_kept``): the result keeps every scene's
    renders (for the report), one check runs at a time here -- or one in each of ``local_workers`` worker
    processes, each with its own base and reference."""
    per_pixel = reference_kept + sum(oracles_kept)
    kept = sum(pixels) * per_pixel
    running = max(pixels, default=0) * CHECK_PER_PIXEL if oracles_kept else 0
    workers = local_workers * (BASE_BYTES + max(pixels, default=0) * reference_kept)
    return int(BASE_BYTES + kept + max(1, local_workers) * running + workers)


# Renders (``minirt render --width 1024 --height 1024 --backend B``, exercise, peak resident set: the
# reference 0.98 GB, Mitsuba 0.97, POV-Ray 0.49, Embree 0.54, all four 1.50): each backend's result is
# kept (for the contact sheet and the files), per pixel its render_kept, and one render runs at a time,
# its render_running (Dr.Jit's and Mitsuba's working buffers; POV-Ray's are in its own process). Fitted
# within -5 % .. +10 %. A reference image alone larger than a tile is written tile by tile (not counted).


def render_bytes(pixels: int, kept: list[int], running: list[int]) -> int:
    """Peak bytes of rendering an image of ``pixels`` with backends that keep ``kept`` and run with
    ``running`` bytes a pixel each, one after the other."""
    return int(BASE_BYTES + pixels * (sum(kept) + max(running, default=0)))


# Grades (``/usr/bin/time -v minirt grade scenes/rules.toml IMAGE --size NxN -q``, IMAGE a render with two
# wrong rules, peak resident set): 512² 0.98 GB, 1024² 1.68 GB, 1536² 3.68 GB, 2048² 6.22 GB (the page,
# --out, adds nothing measurable). The diagnosis holds the target, the scene's one-step renders and its
# search path's renders; its render cache is bounded (diagnose.VariantCache), the renders it is comparing
# are not. Fitted: a base and GRADE_PER_PIXEL, within -8 % .. +17 % of those four peaks.
GRADE_BASE_BYTES = 550 << 20
GRADE_PER_PIXEL = 1450


# A class: each process also keeps one render cache for every image it grades, and fills it. Measured:
# 15 students x 6 scenes at 256², one process, cache bound 2 GB: peak 2.85 GB, against 0.63 GB for one
# of those images alone -- the cache costs ~1.1 times its bound (its arrays' bookkeeping and NumPy's
# temporaries are not counted in it). CACHE_OVERHEAD is that factor, rounded up.
CACHE_OVERHEAD = 1.2
CACHE_MIN_BYTES = 256 << 20


def grade_bytes(pixels: int, processes: int = 1) -> int:
    """Peak bytes of grading an image of ``pixels`` -- in each of ``processes`` at once (a class)."""
    return int(processes * (GRADE_BASE_BYTES + pixels * GRADE_PER_PIXEL))


def class_cache_bytes(pixels: int, processes: int, most: int, what: str) -> int:
    """The render cache each of ``processes`` grading a class (largest image ``pixels``) may keep: ``most``,
    or what the memory left after the grades themselves allows (at least CACHE_MIN_BYTES; a smaller
    cache costs time, never results). A class that cannot fit even without caches is refused (``what``
    names it, as ``require`` does)."""
    need = grade_bytes(pixels, processes) + processes * int(CACHE_MIN_BYTES * CACHE_OVERHEAD)
    require(need, what, "grade with fewer --workers, or at a smaller --size")
    have = available()
    if have is None:
        return most
    spare = (have - grade_bytes(pixels, processes)) / (processes * CACHE_OVERHEAD)
    return int(min(most, max(CACHE_MIN_BYTES, spare)))


def gb(n: int) -> str:
    return f"{n / 2**30:.1f} GB"


def require(need: int, what: str, advice: str) -> None:
    """Raise MinirtError (one line) when ``need`` bytes are more than this process may still use."""
    from minirt.errors import MinirtError

    have = available()
    if have is not None and need > have:
        raise MinirtError(f"{what} needs about {gb(need)} of memory, and {gb(have)} is available: {advice}")
