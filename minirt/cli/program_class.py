"""``minirt grade --class DIR --program-file NAME``: a class of programs, each student's graded over the
suite (minirt.grading.program_class); this module checks the flags before any work, keeps the progress bar
and prints the verdicts' counts."""

from __future__ import annotations

from pathlib import Path

from minirt.cli.console import class_progress, err, out, progress_bar
from minirt.cli.options import output_file, output_folder, pool
from minirt.errors import MinirtError
from minirt.io.untrusted import terminal_text


def grade_program_class_command(
    class_dir: Path, *, program_file, program_command, edition, adapter, timeout, sandbox, scene_path, out_dir,
    json_out, size, profile, rule, quiet, workers, scheduler,
) -> None:  # fmt: skip
    """``grade --class DIR --program-file NAME``: the class, the program's source and the suite checked (in
    the order bad input is told), then every student's program graded; prints the verdicts' counts."""
    from minirt.cli.console import emit_json
    from minirt.cli.program import load_suite
    from minirt.grading import classroom, program_class
    from minirt.oracles.program import sandbox as jail

    adapter = adapter.absolute() if adapter is not None else None  # read in the workers, wherever they run
    source = program_class.ProgramSource(program_file, program_command, edition, adapter, timeout, sandbox)
    source.check()
    people = classroom.students(class_dir)
    skipped = classroom.skipped_entries(class_dir)
    if sandbox:
        ok, why = jail.available()
        if not ok:
            raise MinirtError(f"{why}; untrusted code is not run unprotected (--no-sandbox to run it anyway)")
    if json_out not in (None, "-"):
        output_file(Path(json_out), "--json")
    output_folder(out_dir)
    suite = load_suite(scene_path, size, profile, rule, source.cpp_edition)
    workers = pool(workers, scheduler, default=0)  # 0: one per core, sized to the class by grade_programs
    with progress_bar(not quiet) as bar:
        start, done = class_progress(
            bar, scheduler is None, "grading programs", lambda row: f"{row.student[:16]:<16} {row.verdict}"
        )
        graded = program_class.grade_programs(
            people, source, suite, out_dir, profile_given=profile is not None, workers=workers, scheduler=scheduler,
            on_start=start, on_done=done, skipped=skipped,
        )  # fmt: skip
    summary = graded.summary
    if json_out is not None:
        emit_json(json_out, summary)
    v = summary["verdicts"]
    n, m = len(people), len(suite)
    (err if json_out == "-" else out).print(
        f"graded {n} program{'s' * (n != 1)} over {m} scene{'s' * (m != 1)}: {v['match']} match, "
        f"{v['differs']} differ, {v['error']} error; wrote {terminal_text(graded.index)}"
    )
    for k in skipped[:10]:
        err.print(f"skipped {terminal_text(k.folder, 80)}: {terminal_text(k.reason)}")
