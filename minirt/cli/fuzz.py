"""``minirt fuzz``: an adversarial campaign -- generated hard scenes checked against every oracle, as
independent jobs, with injected reference bugs to measure what the checks catch.

minirt.campaign makes the scenes, runs the jobs and writes the evidence; this module parses the lists,
keeps the progress bar and prints the counts and catch rates.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from minirt.cli.console import MAX_MESSAGE, emit_json, err, out, progress_bar
from minirt.cli.options import (
    FuzzWorkersOpt,
    JsonOpt,
    OraclesOpt,
    QuietOpt,
    SchedulerOpt,
    output_file,
    output_folder,
    parse_size,
    pool,
)
from minirt.io.untrusted import terminal_text

FUZZ_HELP = "\n\n".join([
    "An adversarial campaign: generated hard scenes checked against every oracle, as independent jobs.",
    "Scene i is family i mod F's number i // F (families: {families}); the same seed gives the same scenes "
    "and the same JSON. Each (scene, oracle) is one job, run in this process (--workers 1), on an embedded "
    "Dask LocalCluster (default: one worker per core once there are enough jobs) or on a running Dask "
    "cluster (--scheduler tcp://host:8786; its workers need minirt and the renderers installed). Results "
    "are cached in OUT/cache by content hash (scene text, oracle, defects, versions), so a rerun does only "
    "what changed. Scenes are made as their jobs are handed out, and a campaign this machine cannot hold "
    "is refused before it starts.",
    "--defects also checks each oracle against the reference with an injected bug (defects: {defects}): "
    "a defect that changes a scene's image must make some oracle FAIL there; the catch rate is reported.",
    "With a certified oracle installed, every check goes before it (the judge of last resort): a FAIL stands "
    "only where exact arithmetic certifies the reference wrong, and an oracle's disagreement it settles for "
    "the reference is that oracle's imprecision (a WARN, said in its evidence).",
    "Every non-PASS keeps its scene file, the check's JSON and both images in OUT. Writes OUT/fuzz.json "
    "(and --json). Exit status: 0 nothing failed, 1 a check failed, 2 a backend error or bad input.",
])  # fmt: skip


# The families and defects by name, written out: --help imports no campaign (its scenes, NumPy and pydantic
# cost a tenth of a second). tests/cli/test_startup.py keeps them equal to minirt.campaign's.
FAMILY_NAMES = ("random", "start", "grazing", "contact", "far", "scaled", "f32")
DEFECT_NAMES = ("last-shape-skipped", "radius-off", "t-scaled", "normal-flipped", "ids-swapped", "no-shadows",
                "no-reflection", "no-ambient", "light-moved", "specular-exponent")  # fmt: skip


def fuzz_help() -> str:
    return FUZZ_HELP.format(families=", ".join(FAMILY_NAMES), defects=", ".join(DEFECT_NAMES))


def fuzz(
    count: Annotated[int, typer.Option("--count", "-n", min=1, max=1_000_000, help="Scenes to generate.")] = 12,
    seed: Annotated[int, typer.Option("--seed", min=0, help="The campaign's seed.")] = 1,
    size: Annotated[str, typer.Option("--size", help="Every scene's image size, WIDTHxHEIGHT.")] = "24x24",
    families: Annotated[
        str, typer.Option("--families", metavar="LIST", help="Scene families (comma list or all).")
    ] = "all",
    backend: OraclesOpt = "all",
    defects: Annotated[
        str, typer.Option("--defects", metavar="LIST", help="Injected reference bugs to check (none, all or a list).")
    ] = "none",
    out_dir: Annotated[Path, typer.Option("--out", "-o", help="Output folder.")] = Path("renders/fuzz"),
    json_out: JsonOpt = None,
    workers: FuzzWorkersOpt = None,
    scheduler: SchedulerOpt = None,
    no_cache: Annotated[
        bool, typer.Option("--no-cache", help="Recompute every job (and do not store results).")
    ] = False,
    quiet: QuietOpt = False,
) -> None:
    """An adversarial campaign (help text: FUZZ_HELP)."""  # fmt: skip
    from minirt.campaign import campaign
    from minirt.harness import backends
    from minirt.jobs import batch as jobs

    wh = parse_size(size)
    fams = campaign.parse_families(families)
    names = backends.parse_backends(backend)
    backends.require_oracle(names)
    names = backends.oracles_among(names)
    kinds = campaign.parse_defects(defects)
    workers = pool(workers, scheduler, default=0)  # 0: sized below, from the jobs' count
    if json_out not in (None, "-"):
        output_file(Path(json_out), "--json")
    output_folder(out_dir)
    c = campaign.Campaign(seed=seed, families=fams, size=wh, backends=tuple(names), defects=kinds)
    total = count * len(names)
    workers = workers or jobs.default_workers(total, per_worker=8)
    counts = dict.fromkeys(campaign.VERDICTS, 0)
    with progress_bar(not quiet) as bar:
        where = f"on {scheduler}" if scheduler else f"{workers} processes" if workers > 1 else "1 process"
        task = bar.add_task(f"fuzz ({where})", total=total) if bar else None

        def done(job, res) -> None:
            counts[res["verdict"]] += 1
            if res["verdict"] in ("fail", "error"):
                err.print(
                    terminal_text(f"  {res['verdict'].upper()} {job.scene} {job.backend}: {res['reason']}", MAX_MESSAGE)
                )
            if bar:
                bar.update(task, description=terminal_text(f"fuzz {job.scene[:24]:<24} {counts['fail']} fail"))
                bar.advance(task)

        doc = campaign.fuzz(c, count, out_dir, workers, scheduler, use_cache=not no_cache, on_done=done)
    if json_out is not None:
        emit_json(json_out, doc)
    v = doc["verdicts"]
    said = ", ".join(f"{n} {k}" for k, n in v.items() if n)
    if doc["inconclusive"]:
        said += f" ({doc['inconclusive']} inconclusive)"
    text = (f"fuzz: {doc['scenes']} scenes x {len(names)} oracles ({where}): {said}; "
            f"{c.cached} of {total} jobs from the cache, {c.seconds:.1f} s")  # fmt: skip
    (err if json_out == "-" else out).print(terminal_text(text))
    for name, d in doc.get("defects", {}).items():
        rate = "-" if d["rate"] is None else f"{100 * d['rate']:.1f} %"
        inside = d["changes"] - d["changes_judged"]
        where = f"; {inside} only where the checks cannot see it (bands, edges, within tolerance)" if inside else ""
        (err if json_out == "-" else out).print(
            terminal_text(
                f"  defect {name:<18} caught in {d['caught']}/{d['changes']} scenes it changes ({rate}){where}"
            )
        )
    (err if json_out == "-" else out).print(f"wrote {terminal_text(out_dir)}/fuzz.json")
    raise typer.Exit(2 if v["error"] else 1 if v["fail"] else 0)
