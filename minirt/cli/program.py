"""``minirt grade --program SPEC``: a student's program graded over a suite of scenes (minirt.grading.program);
this module checks the flags, loads the suite, keeps the progress bar and prints a line per scene."""

from __future__ import annotations

from pathlib import Path

import typer

from minirt.cli.console import MAX_MESSAGE, emit_json, err, out, progress_bar
from minirt.cli.options import load, output_file, parse_size
from minirt.cli.program_fuzz import fuzz_folder, print_fuzz, run_fuzz
from minirt.errors import MinirtError
from minirt.io.untrusted import terminal_text


def grade_program_command(
    program: str, scene_path, image, *, edition, adapter, timeout, sandbox, json_out, size, profile, rule, quiet,
    class_dir, page=None, fuzz=0, fuzz_dir=None,
) -> None:  # fmt: skip
    from minirt.grading import program as grading
    from minirt.oracles.program import make_spec

    if image is not None or class_dir is not None:
        raise MinirtError(
            "--program renders its own images: give no IMAGE or --class with it (a class of programs: --class DIR "
            "--program-file NAME)"
        )
    spec = make_spec(program, edition, adapter, timeout, sandbox)
    if json_out not in (None, "-"):
        output_file(Path(json_out), "--json")
    output_file(page, "--out")
    folder = fuzz_folder(fuzz_dir, json_out) if fuzz else None
    edition = spec.edition if spec.kind == "cpp" else None
    suite = [
        (f, sc, grading.given_rules(r, spec, profile is not None))
        for f, sc, r in load_suite(scene_path, size, profile, rule, edition)
    ]
    with progress_bar(not quiet) as bar:
        task = bar.add_task("grading the program", total=len(suite)) if bar else None

        def done(g) -> None:
            if bar:
                bar.advance(task)

        g = grading.grade_program(spec, suite, timeout, on_scene=done)
        hard = run_fuzz(spec, g, fuzz, folder, size, bar) if fuzz else None
    doc = g.as_dict() | ({"fuzz": hard} if hard is not None else {})
    if json_out is not None:
        emit_json(json_out, doc)
    if page is not None:
        from minirt.grading.program_page import write_program_page

        write_program_page(g, page)
    if json_out != "-":
        _print(g)
        if hard is not None:
            print_fuzz(hard, program)
        if page is not None:
            out.print(f"wrote {terminal_text(page)}")
    # a numerical failure on a hard scene is a difference from the model, whatever the suite said
    raise typer.Exit(max(g.exit_code, 1 if hard and hard["failed"] else 0))


def load_suite(scene_path, size, profile, rule, edition: str | None = None) -> list:
    """The scenes a program is graded over: SCENE alone (at --size, default the suite's size), or the
    program suite (minirt.grading.suite; a C++ source of ``edition`` 2014 also the course's test scenes),
    each at its own size unless --size, as (file, scene, rules) with the scene's rules (--profile and
    --rule applied)."""
    from minirt.grading import suite as suite_mod
    from minirt.model.bundled import find_scene

    wh = parse_size(size)
    if scene_path is not None:
        scenes = [(find_scene(scene_path), wh or suite_mod.SUITE_SIZE)]
    else:
        scenes = [(s.path, wh or s.size) for s in suite_mod.program_suite(edition)]
    return [(str(path), *load(path, w, h, None, profile, rule)) for path, (w, h) in scenes]


def _print(g) -> None:
    style = {"match": "green", "differs": "yellow", "error": "red"}[g.verdict]
    err.print(f"[bold {style}]{g.verdict.upper()}[/]", end=" ")
    err.print(terminal_text(f"{g.spec.text}: {g.summary()}", MAX_MESSAGE))
    if g.compile is not None and not g.compile["ok"]:
        for line in g.compile["message"].splitlines()[:20]:
            err.print(f"  {terminal_text(line, MAX_MESSAGE)}")
    for s in g.scenes:
        d = s.as_dict()
        named = [f"{k}={v}" for k, v in d["rules"].items()] + [f"{k} undecided" for k in d["undetermined"]]
        named = ", ".join(named)
        what = d["error"] or (named or "as the model") + (
            f"; {d['mismatch_pixels']} pixels unexplained" if d["mismatch_pixels"] else ""
        )
        if "course_grid" in d:  # one of the 2014 course's test scenes: its own test's verdict beside
            what += f"; the course's 10x10-grid test: {d['course_grid'] or 'needs a float image'}"
        out.print(terminal_text(f"  {d['scene']:<30} {d['verdict']:<8} {what}", MAX_MESSAGE))
    for e in g.as_dict()["diagnosis"]["explained"]:
        if not e["decided"]:
            continue
        err.print(
            terminal_text(
                f"  {e['rule']}={e['value']} ({e['pixels']} pixels over the suite): {e['sentence']}", MAX_MESSAGE
            )
        )
    if g.diagnosis.undetermined_sentence:
        err.print(terminal_text(f"  one of: {g.diagnosis.undetermined_sentence}", MAX_MESSAGE))
    for r in g.diagnosis.rejected:
        err.print(terminal_text(f"  not named: {r.rule}={r.value} ({r.pixels} for, {r.against} against)", MAX_MESSAGE))
    for i in g.diagnosis.indistinguishable:
        err.print(terminal_text(f"  cannot tell {i['rule']}={i['value']} from {i['as']} in any scene of the suite"))
