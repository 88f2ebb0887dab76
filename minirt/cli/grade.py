"""``minirt grade``: another tracer's image of a scene graded -- is it the exercise's model, and if not,
which rule settings explain it -- or, with --class, a whole class's images.

minirt.grading.grade grades one image and minirt.grading.classroom a class; this module checks the flags,
keeps the progress bar and prints the verdict, its diagnosis and the class's counts.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from minirt.cli.console import MAX_MESSAGE, class_progress, emit_json, err, out, progress_bar
from minirt.cli.options import (
    CLUSTER_TRUST,
    GradeCacheOpt,
    GradeWorkersOpt,
    JsonOpt,
    ProfileOpt,
    QuietOpt,
    RuleOpt,
    load,
    output_file,
    output_folder,
    parse_size,
    pool,
)
from minirt.cli.program_options import FuzzDirOpt, FuzzOpt, ProgramCommandOpt, ProgramFileOpt
from minirt.errors import MinirtError
from minirt.io.untrusted import terminal_text


# one piece: Typer's declarations of grade's options (one parameter each) and the dispatch to its three
# modes (one image, a class, a program), each of which is a function of its own
def grade(
    scene_path: Annotated[
        str | None,
        typer.Argument(
            metavar="SCENE", help="The scene the image shows: a file or a bundled scene's name.", show_default=False
        ),
    ] = None,
    image: Annotated[
        Path | None,
        typer.Argument(
            metavar="IMAGE",
            help="The other tracer's image: PNG, BMP, PPM/PGM, TGA, TIFF or EXR (a regular file; alpha is ignored).",
            show_default=False,
        ),
    ] = None,
    json_out: JsonOpt = None,
    out_dir: Annotated[
        Path | None,
        typer.Option(
            "--out",
            "-o",
            help="Write an HTML page with the pictures (DIR/index.html; with --program: one file, FILE.html, its "
            "pictures inside it).",
        ),
    ] = None,
    class_dir: Annotated[
        Path | None,
        typer.Option(
            "--class",
            metavar="DIR",
            help="Grade a whole class: DIR/<student>/<scene stem>.png (any supported type). Untrusted: no "
            "symbolic link in it is followed (a linked folder or image is an error row); hidden folders are "
            "skipped and listed.",
        ),
    ] = None,
    scenes_dir: Annotated[
        Path | None,
        typer.Option("--scenes", metavar="DIR", help="With --class: the scenes (default: the bundled scenes)."),
    ] = None,
    size: Annotated[str | None, typer.Option("--size", help="The scene rendered at WIDTHxHEIGHT.")] = None,
    workers: GradeWorkersOpt = None,
    scheduler: Annotated[
        str | None,
        typer.Option(
            "--scheduler",
            metavar="ADDRESS",
            help="With --class: grade on a running Dask cluster (tcp://host:8786); its workers need minirt "
            "and the same paths. " + CLUSTER_TRUST,
        ),
    ] = None,
    cache: GradeCacheOpt = None,
    profile: ProfileOpt = None,
    rule: RuleOpt = None,
    quiet: QuietOpt = False,
    program: Annotated[
        str | None,
        typer.Option(
            "--program",
            metavar="SPEC",
            help="Grade a program, not one image: a command line with {scene} (or {scene_json}) and {out}, "
            "e.g. 'python3 tracer.py {scene} {out}' (it writes {out}.pfm, .exr, .png, .ppm ...), or a C++ "
            "source, raytracer.cpp. It renders the program suite -- the grading set, five scenes that read the "
            "offset, t_max and the specular exponent, and for a 2014 source the course's own six test scenes "
            "-- (or SCENE alone) in a sandbox; the images are diagnosed together. Untrusted: see --no-sandbox.",
        ),
    ] = None,
    edition: Annotated[
        str | None,
        typer.Option("--edition", help="With a C++ --program: the exercise's edition, 2014 (default) or 2013."),
    ] = None,
    adapter: Annotated[
        Path | None,
        typer.Option(
            "--adapter",
            metavar="FILE",
            help="With a 2013 C++ --program: the course's C++ that builds a ball, a plane and the scene with "
            "the student's classes and traces one pixel (README: A program under test).",
        ),
    ] = None,
    timeout: Annotated[
        float | None,
        typer.Option(
            "--timeout",
            min=0.001,
            help="With --program or --program-file: seconds one scene may take (default: 200x the reference's "
            "time, at least 20).",
        ),
    ] = None,
    no_sandbox: Annotated[
        bool,
        typer.Option(
            "--no-sandbox",
            help="With --program: run it without bubblewrap (limits kept, isolation not): only for code you trust.",
        ),
    ] = False,
    program_file: ProgramFileOpt = None,
    program_command: ProgramCommandOpt = None,
    fuzz: FuzzOpt = 0,
    fuzz_dir: FuzzDirOpt = None,
) -> None:
    """Grade another tracer's image of a scene: is it the exercise's model, and if not, which rule
    settings explain it (searched over every rule; `minirt render SCENE --rule ...` with them reproduces
    the image). Pixels no rule setting explains are grouped by where they lie (the shape hit, t, lit or
    in shadow, what a reflection shows, ...), each group with a sentence and a `minirt probe ... --image`
    command for one of its pixels.

    With --program SPEC: the student's program itself renders the program suite (the grading set and
    the scenes built to tell every rule apart, at 96x96; a 2014 source also the course's own test scenes,
    each with the course's 10x10-grid verdict beside minirt's) or SCENE, in a sandbox; one diagnosis of
    all its images, one verdict for the program, one line per scene; --out FILE.html writes its page
    (every scene's pictures and the diagnosis, in one file). --fuzz N adds N hard scenes of the fuzz
    campaign and reports the program's numerical failures there.

    With --class DIR --program-file NAME (or --program-command): each student's program graded so, one
    row per student in OUT/grades.csv, grades.json and index.html.

    Exit status: 0 match (every pixel within one 8-bit level, ill-conditioned pixels aside), 1 differs
    (the diagnosis says how), 2 bad input. With --class: OUT/grades.csv, grades.json and index.html,
    one row per student and scene (missing or unreadable images are rows with verdict "error"); exit 0
    when the class was graded. Each image of a class is one job: on --workers processes here (each
    with its own render cache, pages written as images are graded) or on a Dask cluster (--scheduler);
    the files are the same bytes either way.
    """
    if program_file is not None or program_command is not None:
        from minirt.cli.program_class import grade_program_class_command

        if class_dir is None or program is not None or image is not None or fuzz or fuzz_dir is not None:
            raise MinirtError("--program-file and --program-command grade a class: --class DIR, no --program, "
                              "IMAGE or --fuzz")  # fmt: skip
        for given, option in ((scenes_dir, "--scenes"), (cache, "--cache")):
            if given is not None:
                raise MinirtError(f"{option} goes with a class of images, not of programs (SCENE picks a scene)")
        grade_program_class_command(
            class_dir, program_file=program_file, program_command=program_command, edition=edition, adapter=adapter,
            timeout=timeout, sandbox=not no_sandbox, scene_path=scene_path, out_dir=out_dir or Path("grades"),
            json_out=json_out, size=size, profile=profile, rule=rule, quiet=quiet, workers=workers,
            scheduler=scheduler,
        )  # fmt: skip
        return
    if (fuzz or fuzz_dir is not None) and program is None:
        raise MinirtError("--fuzz and --fuzz-dir go with --program")
    if program is not None:
        from minirt.cli.program import grade_program_command

        grade_program_command(
            program, scene_path, image, edition=edition, adapter=adapter, timeout=timeout, sandbox=not no_sandbox,
            json_out=json_out, size=size, profile=profile, rule=rule, quiet=quiet, class_dir=class_dir, page=out_dir,
            fuzz=fuzz, fuzz_dir=fuzz_dir,
        )  # fmt: skip
        return
    for given, option in ((edition, "--edition"), (adapter, "--adapter"), (timeout, "--timeout")):
        if given is not None:
            raise MinirtError(f"{option} goes with --program")
    if class_dir is not None:
        if scene_path is not None or image is not None:
            raise MinirtError("--class grades DIR/<student>/<scene>.png: give no SCENE or IMAGE with it")
        _grade_class(
            class_dir, scenes_dir=scenes_dir, out_dir=out_dir or Path("grades"), json_out=json_out, size=size,
            profile=profile, rule=rule, quiet=quiet, workers=workers, scheduler=scheduler, cache=cache,
        )  # fmt: skip
        return
    class_only = {"--scenes": scenes_dir, "--workers": workers, "--scheduler": scheduler, "--cache": cache}
    _grade_one(scene_path, image, json_out, out_dir, size, profile, rule, quiet, class_only)


def _grade_one(scene_path, image, json_out, out_dir, size, profile, rule, quiet, class_only: dict[str, Any]) -> None:
    """`minirt grade SCENE IMAGE`: one image graded, its verdict printed (and its JSON and page written);
    exits with the grade's status. ``class_only``: the options that go with --class alone, as given."""
    if scene_path is None or image is None:
        raise MinirtError(
            "grade needs SCENE and IMAGE (or --class DIR), e.g. minirt grade scenes/rules.toml student.png"
        )
    for option, given in class_only.items():
        if given is not None:
            raise MinirtError(f"{option} goes with --class")
    from minirt.grading import grade as grading
    from minirt.model.bundled import find_scene

    if json_out not in (None, "-"):
        output_file(Path(json_out), "--json")
    if out_dir is not None:
        output_folder(out_dir)
    path = find_scene(scene_path)
    wh = parse_size(size)
    scene, rules = load(path, *(wh or (None, None)), None, profile, rule)
    with progress_bar(not quiet) as bar:
        task = bar.add_task("grading", total=None) if bar else None
        g = grading.grade_image(scene, str(path), image, rules, size_override=wh)
        if bar:
            bar.update(task, completed=1, total=1)
    if json_out is not None:
        emit_json(json_out, g.as_dict())
    page = None
    if out_dir is not None:
        from minirt.grading.page import write_grade_page

        page = write_grade_page(g, out_dir)
    if json_out != "-":
        _print_grade(g, page)
    raise typer.Exit(g.exit_code)


def _print_grade(g, page: Path | None) -> None:
    from minirt.grading import grade as grading

    style = {"match": "green", "differs": "yellow", "error": "red"}[g.verdict]
    err.print(f"[bold {style}]{g.verdict.upper()}[/]", end=" ")
    err.print(terminal_text(f"{g.scene.name}: {g.summary()}", MAX_MESSAGE))
    for note in g.notes:
        err.print(f"  note: {terminal_text(note, MAX_MESSAGE)}")
    d = g.diagnosis
    for e in d.explained:
        if e.rule in d.undetermined:
            continue
        s = grading.sentence(e.rule, getattr(d.best, e.rule), getattr(d.given, e.rule))
        against = f", {e.against} against" if e.against else ""
        err.print(terminal_text(f"  {e.rule}={e.value} ({e.pixels} pixels{against}): {s}", MAX_MESSAGE))
    if d.one_of:
        err.print(terminal_text(f"  one of: {d.one_of.sentence}", MAX_MESSAGE))
    if d.broken_pixels:
        err.print(f"  {d.broken_pixels} pixels the scene's own rules draw right are wrong under these rules")
    for r in d.rejected:
        err.print(
            terminal_text(
                f"  not named: {r.rule}={r.value} (the search took it; {r.pixels} pixels for, {r.against} "
                f"against, {r.neither} matching neither value)",
                MAX_MESSAGE,
            )
        )
    for u in d.unexplained:
        err.print(terminal_text(f"  unexplained: {u.sentence}", MAX_MESSAGE))
        if u.fit is not None:
            said = "fitted" if u.fit.reproduces else "not fitted"
            err.print(terminal_text(f"    {said}: {u.fit.sentence}", MAX_MESSAGE))
        err.print(f"    one of them step by step: {terminal_text(g.probe_command(*u.example), MAX_MESSAGE)}")
    for i in d.indistinguishable:
        tell = (
            f"scene {i['scene_that_tells']} tells them apart"
            if i["scene_that_tells"]
            else "no bundled scene tells them apart"
        )
        err.print(terminal_text(f"  cannot tell {i['rule']}={i['value']} from {i['as']} in this scene ({tell})"))
    if d.reproducing:
        err.print(f"  reproduce: {terminal_text(g.reproduce(), MAX_MESSAGE)}")
    if page is not None:
        out.print(f"wrote {terminal_text(page)}")


def _grade_class(
    class_dir, *, scenes_dir, out_dir, json_out, size, profile, rule, quiet, workers, scheduler, cache
) -> None:
    """``grade --class``: the class found and the flags checked (in the order bad input is told, before any
    work), then minirt.grading.classroom.grade_folder with a progress bar; prints the verdicts' counts."""
    from minirt.grading import classroom

    people, files = classroom.find_class(class_dir, scenes_dir)
    skipped = classroom.skipped_entries(class_dir)
    if json_out not in (None, "-"):
        output_file(Path(json_out), "--json")
    output_folder(out_dir)
    if cache is not None:
        output_folder(cache, "--cache", mode=0o700)
    wh = parse_size(size)
    loaded = [(str(f), *load(f, *(wh or (None, None)), None, profile, rule)) for f in files]
    workers = pool(workers, scheduler, default=0)  # 0: one per core, sized to the images by grade_folder
    with progress_bar(not quiet) as bar:
        start, done = class_progress(
            bar, scheduler is None, "grading", lambda row: f"{row.student[:16]:<16} {row.scene[:12]:<12}"
        )
        graded = classroom.grade_folder(
            people, loaded, out_dir, workers=workers, scheduler=scheduler, cache=cache, quiet=quiet,
            on_start=start, on_done=done, skipped=skipped,
        )  # fmt: skip
    summary = graded.summary
    if json_out is not None:
        emit_json(json_out, summary)
    v = summary["verdicts"]
    (err if json_out == "-" else out).print(
        f"graded {len(people)} students x {len(files)} scenes: {v['match']} match, {v['differs']} differ, "
        f"{v['error']} error"
        + (f" ({graded.cached} of {graded.total} from the cache)" if graded.cached is not None else "")
        + f"; wrote {terminal_text(graded.index)}"
    )
    _print_skipped(skipped)


SKIPPED_SHOWN = 10  # entries of a class folder named on the terminal; grades.json and the page list them all


def _print_skipped(skipped) -> None:
    """One line per entry of the class folder that was not graded (hidden, not a folder), the first few."""
    for k in skipped[:SKIPPED_SHOWN]:
        err.print(f"skipped {terminal_text(k.folder, 80)}: {terminal_text(k.reason)}")
    if len(skipped) > SKIPPED_SHOWN:
        err.print(f"skipped {len(skipped) - SKIPPED_SHOWN} more (grades.json lists them all)")
