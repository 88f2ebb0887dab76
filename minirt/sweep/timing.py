"""How the sweep times a setting: an untimed warm-up, then the median of the timed runs.

Each setting is rendered once untimed (the warm-up: JIT compilation, kernel and mesh caches, module
imports), then ``repeats`` times (only once when the warm-up took longer than ``slow_seconds``): even
``repeats = 1`` keeps compilation out of the time. ``seconds_median`` is the median of the timed runs and
``seconds_setup`` the warm-up's excess over it -- or, for a backend whose every run pays a start-up of its
own (``Series.seconds``: POV-Ray's process, ~0.65 s whatever the size), that start-up, which is then *not*
in ``seconds_median``; ``seconds_total`` has both. A timer that counts whole steps (POV-Ray's statistics:
milliseconds) records a median below its resolution *at* the resolution with ``seconds_at_resolution``
true (an upper bound, drawn hollow with a left arrow, "≤" in the tables), never as 0 (which would vanish
from a log plot). Times are wall clock of ``minirt.harness.backends.render`` (or what the backend's
``Series.seconds`` reads from the result), on however many cores the machine has.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Callable

from minirt.model.backend import Seconds
from minirt.model.result import RenderResult

SLOW_SECONDS = 5.0  # a setting whose first run takes longer is timed once more only
REPEATS = 3


def wall_seconds(res: RenderResult) -> tuple[float, float, float]:
    """(time of the render itself, per-run start-up, the timer's resolution; 0: fine-grained) of one result:
    the wall clock of minirt.harness.backends.render, no start-up, fine-grained."""
    return float(res.meta.get("timings", {}).get("wall", math.nan)), 0.0, 0.0


def timed(
    render: Callable[[], RenderResult], repeats: int, slow_seconds: float, seconds: Seconds = wall_seconds
) -> tuple[RenderResult, dict]:
    """One untimed warm-up render, then `repeats` timed ones (one when the warm-up took longer than
    `slow_seconds`); the last result and the timing summary. ``seconds`` reads a result's time (see
    wall_seconds)."""
    res = render()  # warm-up: JIT compilation, kernel and mesh caches, imports -- never in the median
    if not res.ok:
        return res, {}
    first, first_startup, _ = seconds(res)
    runs, startups = [], []
    resolution = 0.0
    for _ in range(1 if first + first_startup > slow_seconds else max(repeats, 1)):
        r = render()
        if not r.ok:
            return r, {}
        s, st, resolution = seconds(r)
        runs.append(s)
        startups.append(st)
        res = r
    median = statistics.median(runs)
    startup = statistics.median(startups)
    # A time below the timer's resolution (POV-Ray's statistics count whole milliseconds) is not 0: it is
    # plotted and fitted at the resolution and marked as an upper bound.
    floored = resolution > 0 and median < resolution
    if floored:
        median = resolution
    if startup > 0:  # a per-run start-up (POV-Ray's process): that is the setup
        setup: float = startup
    else:
        setup = max(first - median, 0.0)
    timing = {
        "seconds_median": median,
        "seconds_setup": setup,
        "seconds_first": first + first_startup,
        "seconds_total": median + startup,
        "seconds_at_resolution": floored,
        "timer_resolution": resolution or None,
        "runs": [round(r + s, 6) for r, s in zip(runs, startups, strict=True)],
    }
    return res, timing


def startup_text(r: dict) -> str:
    """A row's per-run start-up (its total beyond its median), as the answer names it; "" without one."""
    startup = (r.get("seconds_total") or 0.0) > r["seconds_median"]
    return f" (+{r['seconds_setup']:.2f} s process start-up)" if startup and r.get("seconds_setup") else ""


def seconds_text(r: dict) -> str:
    """A row's median time as the answer gives it: "≤" when at the timer's resolution, with its start-up."""
    return f"{'≤ ' if r.get('seconds_at_resolution') else ''}{r['seconds_median']:.3g} s" + startup_text(r)
