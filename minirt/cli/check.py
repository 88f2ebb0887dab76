"""``minirt check`` and ``minirt report``: the reference against the oracles, as a table and its verdict,
or as an HTML report.

Both run minirt.harness.checks (the Python API's ``minirt.check`` runs it too) and print the table of
verdicts and figures, then each checked scene's hazard warnings.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from minirt.cli.console import emit_json, err, out, progress_bar, warn
from minirt.cli.options import (
    CacheOpt,
    CheckWorkersOpt,
    JsonOpt,
    OraclesOpt,
    QuietOpt,
    ScenesArg,
    SchedulerOpt,
    SizeOpt,
    output_file,
    output_folder,
    parse_size,
    pool,
)
from minirt.errors import MinirtError
from minirt.io.untrusted import terminal_text

VERDICT_STYLE = {"pass": "green", "warn": "yellow", "fail": "bold red", "error": "bold magenta", "skip": "dim"}


def _run_checks(paths, backend: str, size: str | None, quiet: bool, workers, scheduler, cache, program=None):
    """Shared by `check` and `report`: the flags, each checked in the order bad input is told, then the
    check (minirt.harness.checks) with a progress bar on a terminal. ``program``: check's flags for a
    program backend (``program_backends``). Returns the result, the backends' names the size and the scenes
    (each file parsed once)."""
    from minirt.harness import backends, checks

    workers = pool(workers, scheduler, default=1)

    files = checks.scene_files(paths)
    names = program_backends(backends.parse_backends(backend), **(program or {}))
    backends.require_oracle(names, programs_too=True)
    checks.refuse_cached_programs(names, cache)
    wh = parse_size(size)
    scenes = checks.read_all(files)  # bad input first, before any long work; each file parsed once
    if cache is not None:
        output_folder(cache, "--cache", mode=0o700)
    total = checks.job_count(files, names)
    with progress_bar(not quiet) as bar:
        task = bar.add_task("checking", total=total) if bar else None

        def step(done: int, steps: int, scene: str, name: str) -> None:
            if bar:
                bar.update(task, completed=done, description=f"{terminal_text(scene, 40)}: {name}")

        result = checks.run_checks(
            files, names, wh, workers=workers, scheduler=scheduler, cache=cache, on_step=step, scenes=scenes
        )
        if bar:
            bar.update(task, completed=total)
    return result, names, wh, scenes


def program_backends(names: list[str], edition=None, adapter=None, timeout=None, no_sandbox=False) -> list[str]:
    """``names`` with check's program flags (--edition, --adapter, --timeout, --no-sandbox) written into each
    program backend's name, ``program(key=value,...):SPEC`` (minirt.oracles.program), after its own options;
    each program then parsed (a bad combination is bad input) and its sandbox found, before any work."""
    from minirt.harness import backends

    given = {"edition": edition, "adapter": adapter, "timeout": timeout, "sandbox": "off" if no_sandbox else None}
    given = {k: v for k, v in given.items() if v is not None}
    flag = {"edition": "--edition", "adapter": "--adapter", "timeout": "--timeout", "sandbox": "--no-sandbox"}
    if given and not any(backends.is_program(n) for n in names):
        raise MinirtError(f"{flag[next(iter(given))]} goes with a program backend: -b 'program:SPEC'")
    out = []
    for n in names:
        if backends.is_program(n):
            opts = ",".join(f"{k}={v:g}" if k == "timeout" else f"{k}={v}" for k, v in given.items())
            if opts:
                own, _, spec = n[len("program") :].partition(":")
                n = f"program({own.strip('()') + ',' if own.strip('()') else ''}{opts}):{spec}"
            ok, why = backends.get(n).available()
            if not ok:
                raise MinirtError(f"--backend {n}: {why}")
        out.append(n)
    return out


def _print_warnings(result, names: list[str], size: tuple[int, int] | None, scenes) -> None:
    """The hazard warnings of every checked scene (minirt.harness.checks.hazard_warnings), one line each."""
    from minirt.harness import checks

    for scene_name, line in checks.hazard_warnings(result, names, size, scenes):
        warn(scene_name, line)


def _print_check(result) -> None:
    t = Table(title="minirt check", title_justify="left")
    for col in ("scene", "backend", "verdict", "geometry", "shading", "rules explaining its image", "seconds"):
        t.add_column(col)
    for s in result.scenes:
        for name, b in s.backends.items():
            g = b.checks.get("geometry")
            sh = b.checks.get("shading")
            if g is not None and g.verdict == "skip":  # a backend that gives only an image: said why
                geo = f"skip: {terminal_text(g.reason)}"
            else:
                geo = (
                    f"mask {g.figures['mask_mismatch']} ({g.figures['mask_mismatch_outside_band']} off band), "
                    f"id {g.figures['id_mismatch']}, dt {g.figures['depth_rel_err_max']:.1e}, "
                    f"n {g.figures['normal_deg_max']:.1e} deg"
                    if g
                    else "-"
                )
            if sh is None:
                shade = "-"
            elif sh.verdict == "skip":
                shade = "skip"
            elif "color8_max_diff" in sh.figures:
                shade = f"8-bit max {sh.figures['color8_max_diff']}, dE p95 {sh.figures['delta_e_p95']:.2f}"
            elif "diffuse_rel_err_max" in sh.figures:
                shade = f"diffuse rel {sh.figures['diffuse_rel_err_max']:.1e}, lit flips {sh.figures['lit_mismatch']}"
            else:
                shade = f"Z pass {sh.figures.get('pass_fraction', 0):.2%}"
            st = b.checks.get("stochastic")
            if st is not None and st.figures:
                shade += f"; Z pass {st.figures['pass_fraction']:.2%}"
            v = b.verdict
            verdict = f"[{VERDICT_STYLE[v]}]{v.upper()}[/]"
            if v in ("skip", "error", "fail", "warn") and b.reason:
                verdict += f" {terminal_text(b.reason)}"  # a backend's own words: no markup
            rd = b.rule_diagnosis
            if rd.ran:  # the diagnosis: which settings reproduce the oracle's image
                rules_ = ", ".join(f"{k}={v}" for k, v in rd.rules_explaining.items()) or "the scene's own"
                if rd.mismatch_pixels:
                    rules_ += f" ({rd.mismatch_pixels} px unexplained)"
            else:  # what each rule the oracle cannot follow would change in the reference
                rules_ = ", ".join(f"{k} changes {n} px" for k, n in b.rules.items() if n) or "-"
            t.add_row(terminal_text(s.scene), name, verdict, geo, shade, rules_, f"{b.seconds:.1f}")
    err.print(t)


CheckBackendOpt = Annotated[
    str,
    typer.Option(
        "--backend",
        "-b",
        help=OraclesOpt.__metadata__[0].help.rstrip(".")
        + "; and a student's program, 'program:SPEC' (a command line with {scene} and {out}, or a C++ source), "
        "last in the list: its image alone is compared (its geometry check says SKIP).",
    ),
]


def check(
    scene_paths: ScenesArg = None,
    backend: CheckBackendOpt = "all",
    json_out: JsonOpt = None,
    junit: Annotated[Path | None, typer.Option("--junit", help="Write the results as JUnit XML.")] = None,
    size: SizeOpt = None,
    workers: CheckWorkersOpt = None,
    scheduler: SchedulerOpt = None,
    cache: CacheOpt = None,
    quiet: QuietOpt = False,
    edition: Annotated[
        str | None,
        typer.Option("--edition", help="With a C++ program backend: the exercise's edition, 2014 (default) or 2013."),
    ] = None,
    adapter: Annotated[
        Path | None,
        typer.Option(
            "--adapter", metavar="FILE", help="With a 2013 C++ program backend: the course's adapter (README)."
        ),
    ] = None,
    timeout: Annotated[
        float | None,
        typer.Option("--timeout", min=0.001, help="With a program backend: seconds one scene may take (default 60)."),
    ] = None,
    no_sandbox: Annotated[
        bool,
        typer.Option(
            "--no-sandbox",
            help="With a program backend: run it without bubblewrap (limits kept, isolation not): only for code "
            "you trust.",
        ),
    ] = False,
) -> None:
    """Compare the reference tracer with the oracles: geometry pixel by pixel, shading, rules.

    A student's program is a backend too (-b 'program:python3 tracer.py {scene} {out}'): it gives only an
    image, so its geometry check says SKIP and its image is compared with the reference's level by level,
    off the edges (README: A program under test).

    Exit status: 0 all pass (or warn/skip), 1 a check failed, 2 bad input or a backend error.
    """
    from minirt.io import atomic

    if json_out != "-":
        output_file(Path(json_out) if json_out else None, "--json")
    output_file(junit, "--junit")
    program = {"edition": edition, "adapter": adapter, "timeout": timeout, "no_sandbox": no_sandbox}
    result, names, wh, scenes = _run_checks(scene_paths, backend, size, quiet, workers, scheduler, cache, program)
    _print_check(result)
    _print_warnings(result, names, wh, scenes)
    if json_out:
        emit_json(json_out, result.as_dict())
    if junit:
        from minirt.harness.junit import junit_xml

        atomic.write_text(junit, junit_xml(result))
    counts = {v: 0 for v in ("pass", "warn", "fail", "error", "skip")}
    for s in result.scenes:
        for b in s.backends.values():
            counts[b.verdict] += 1
    summary = ", ".join(f"{n} {v}" for v, n in counts.items() if n)
    vague = sum(b.inconclusive for s in result.scenes for b in s.backends.values())
    if vague:
        summary += f" ({vague} inconclusive: the oracle cannot judge the scene)"
    (err if json_out == "-" else out).print(f"{result.verdict.upper()}: {summary}")
    raise typer.Exit(result.exit_code())


def report(
    scene_paths: ScenesArg = None,
    backend: OraclesOpt = "all",
    out_dir: Annotated[Path, typer.Option("--out", "-o", help="Output folder for index.html.")] = Path("reports"),
    size: SizeOpt = None,
    sweep_dir: Annotated[
        Path | None, typer.Option("--sweep", help="Embed a sweep written by `minirt sweep --out DIR`.")
    ] = None,
    workers: CheckWorkersOpt = None,
    scheduler: SchedulerOpt = None,
    cache: CacheOpt = None,
    quiet: QuietOpt = False,
) -> None:
    """Write the HTML comparison report (DIR/index.html, opens from disk) and DIR/report.json."""
    import json as json_

    from minirt.pages.report import write_report

    sweep_data = None
    if sweep_dir is not None:
        f = sweep_dir / "sweep.json"
        if not f.is_file():
            raise MinirtError(f"--sweep {sweep_dir}: no sweep.json there (run: minirt sweep SCENE --out {sweep_dir})")
        try:
            sweep_data = json_.loads(f.read_text())
        except (OSError, ValueError) as e:
            raise MinirtError(f"{f}: not a readable sweep ({e})") from None
    from minirt.harness import backends

    backends.require_oracle(backends.parse_backends(backend), programs_too=True)  # before the folder is made
    output_folder(out_dir)
    result, names, wh, scenes = _run_checks(scene_paths, backend, size, quiet, workers, scheduler, cache)
    _print_check(result)
    _print_warnings(result, names, wh, scenes)
    command = "minirt " + " ".join(sys.argv[1:]) if sys.argv[1:2] == ["report"] else "minirt report"
    index = write_report(result, out_dir, command=command, sweep=sweep_data, sweep_dir=sweep_dir)
    out.print(f"{result.verdict.upper()}: wrote {terminal_text(index)}")
    raise typer.Exit(result.exit_code())
