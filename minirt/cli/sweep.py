"""``minirt sweep``: what accuracy costs in time -- each backend's accuracy knob against time and error.

minirt.sweep.run renders the settings and writes sweep.csv, sweep.md, sweep.json and the plots; this
module prints the fitted slopes and the answer lines.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from minirt.cli.console import err, out, progress_bar
from minirt.cli.options import (
    CACHE_TRUST,
    ProfileOpt,
    QuietOpt,
    RuleOpt,
    SceneArg,
    SchedulerOpt,
    SweepWorkersOpt,
    load,
    output_folder,
    pool,
)
from minirt.io.untrusted import terminal_text

SWEEP_HELP = "\n\n".join([
    "What accuracy costs in time: each backend's accuracy knob against time and error.",
    "Prints one line per backend: the cheapest setting whose image error (colour RMSE against the converged "
    "image) is below one 8-bit level, 1/255, with its time; for Embree, which does not shade, the cheapest whose "
    "geometry passes the check with a mean relative t error below 3.8e-6 (the check's float32 tolerance). "
    "The same lines open sweep.md and are in sweep.json (\"answer\").",
    "Knobs: the reference in float32/float64 and at 1-256 samples; Mitsuba at 1-1024 spp; POV-Ray with "
    "antialiasing off, +A0.0 +R1..4, and the exercise's own 1-16 samples (mesh camera); Embree at icosphere "
    "subdivision 0-7.",
    "Each setting is rendered once untimed (JIT compilation, caches), then --repeats times. Writes sweep.csv, "
    "sweep.md, sweep.json and log-log plots (colour and t error on separate axes) with the Pareto front and "
    "fitted slopes. At the default 256x256 the sweep takes about three minutes on two cores.",
    "Each backend's series is one job: --workers N runs N at once in local processes, --scheduler on a Dask "
    "cluster (times are then those of each worker, Dr.Jit on one thread; sweep.json's \"jobs\" says how they ran), "
    "and --cache DIR keeps each series by content hash (scene, rules, knobs, size, versions, machine), so a rerun "
    "renders only what changed.",
])  # fmt: skip


def sweep(
    scene_path: SceneArg,
    out_dir: Annotated[Path, typer.Option("--out", "-o", help="Output folder.")] = Path("renders/sweep"),
    backend: Annotated[str, typer.Option("--backend", "-b", help="Backends to sweep (comma list or all).")] = "all",
    size: Annotated[int, typer.Option("--size", min=4, help="Square image size in pixels.")] = 256,
    repeats: Annotated[
        int, typer.Option("--repeats", min=1, help="Timed runs per setting (median), after one untimed warm-up run.")
    ] = 3,
    profile: ProfileOpt = None,
    rule: RuleOpt = None,
    workers: SweepWorkersOpt = None,
    scheduler: SchedulerOpt = None,
    cache: Annotated[
        Path | None,
        typer.Option(
            "--cache",
            metavar="DIR",
            help="Keep each backend's series in DIR by content hash (scene text, rules, size, knobs, versions, "
            "machine); a rerun renders only what changed. " + CACHE_TRUST,
        ),
    ] = None,
    quiet: QuietOpt = False,
) -> None:
    """What accuracy costs in time (help text: SWEEP_HELP, paragraphs Rich wraps to the terminal)."""
    from minirt.harness import backends
    from minirt.sweep.run import run_sweep

    scene, rules = load(scene_path, profile=profile, rules=rule)
    names = backends.parse_backends(backend)
    workers = pool(workers, scheduler, default=1)
    output_folder(out_dir)
    with progress_bar(not quiet) as bar:
        task = bar.add_task("sweep", total=1) if bar else None

        def tick(done: int, total: int, label: str) -> None:
            if bar:
                bar.update(task, completed=done, total=total, description=label[:40])

        result = run_sweep(
            scene, rules, names, out_dir, size=size, repeats=repeats, progress=tick,
            workers=workers, scheduler=scheduler, cache=cache,
        )  # fmt: skip
    for name, sl in sorted(result.get("slopes", {}).items()):
        if isinstance(sl, dict) and sl.get("slope_cost") is not None:
            err.print(f"  {name:<28} error ~ cost^{sl['slope_cost']:.2f}")
    for line in result.get("answer_lines", []):
        out.print(terminal_text(line))
    out.print(f"wrote {terminal_text(out_dir)}/sweep.md, sweep.csv, sweep.json, sweep.png")
