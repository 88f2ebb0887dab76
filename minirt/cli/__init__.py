"""The `minirt` command line (its entry point: minirt.cli.app.main): parsing and printing, nothing else.

- app: the Typer app, --version, the commands in --help's order, signals; console: the two streams, the
  progress bar, warnings, --json output; options: the options commands share and their parsers;
- one module per family of commands: render (render, export), probe, inventory (scenes, doctor), check
  (check, report), sweep, grade, fuzz. Each parses its flags, calls its capability's API, prints.

May import: minirt.grading, minirt.campaign, minirt.sweep and below (every capability); nothing imports
the CLI but the package's __main__ and the console script.
"""
