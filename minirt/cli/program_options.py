"""The options of ``grade`` that a class of programs and ``--fuzz`` add (minirt.cli.program_class,
minirt.cli.program_fuzz), declared once."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

ProgramFileOpt = Annotated[
    str | None,
    typer.Option(
        "--program-file",
        metavar="NAME",
        help="With --class: grade each student's program, DIR/<student>/NAME, over the grading suite (or SCENE) "
        "in the sandbox: a C++ source (raytracer.cpp; --edition, --adapter) is compiled and run; any other "
        "file needs --program-command. One row per student: verdict, rules named, rules undecided, "
        "unexplained pixels, why it failed (a compile error, a crash, a time-out).",
        show_default=False,
    ),
]
ProgramCommandOpt = Annotated[
    str | None,
    typer.Option(
        "--program-command",
        metavar="CMD",
        help="With --class: how to run each student's program, a command line with {dir} (the student's "
        "folder) or {file} (its --program-file), {scene} and {out}, e.g. 'python3 {dir}/tracer.py {scene} {out}'.",
        show_default=False,
    ),
]
FuzzOpt = Annotated[
    int,
    typer.Option(
        "--fuzz",
        metavar="N",
        min=0,
        max=10_000,
        help="With --program: also render N hard scenes of the fuzz campaign's families (rays starting on "
        "surfaces, grazing, contact, far away, scaled, float32's limits; seeded, the same N scenes every time) "
        "and report the program's numerical failures there -- acne, lost shadows, NaN/inf pixels, others -- "
        "each with its scene file to reproduce it (README: Hard cases through the student's code).",
    ),
]
FuzzDirOpt = Annotated[
    Path | None,
    typer.Option(
        "--fuzz-dir",
        metavar="DIR",
        help="With --fuzz: where the failing scenes' files are written (default: beside --json FILE, else ./fuzz).",
        show_default=False,
    ),
]
