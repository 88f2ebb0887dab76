"""``minirt scenes`` and ``minirt doctor``: what is here -- the scenes a command accepts by name, and the
backends and libraries installed (with what to install for the missing ones).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from minirt.cli.console import out
from minirt.errors import MinirtError
from minirt.io.untrusted import terminal_text


def scenes(
    folder: Annotated[
        Path | None,
        typer.Argument(help="A folder of scene files (default: the bundled scenes, by name).", show_default=False),
    ] = None,
) -> None:
    """List the bundled scenes (or a folder's), one line each."""
    from minirt.errors import SceneError
    from minirt.model.bundled import BUNDLED
    from minirt.model.scene import load_scene

    files = sorted((folder or BUNDLED).glob("*.toml"))
    if not files:
        raise MinirtError(f"{folder}: no scene files (*.toml)")
    for f in files:
        shown = str(f) if folder else f.stem  # a bundled scene by the name every command accepts
        try:
            s = load_scene(f)
            out.print(
                terminal_text(f"{shown:<32} {s.camera.width}x{s.camera.height} {len(s.shapes)} shapes  {s.description}")
            )
        except SceneError as e:
            out.print(terminal_text(f"{shown:<32} INVALID: {e.lines[0]}"))


def doctor() -> None:
    """Which backends and libraries are present, their versions, and what to install for the missing ones."""
    import importlib.metadata as md

    from minirt.harness import backends

    t = Table(title="libraries", title_justify="left")
    t.add_column("package")
    t.add_column("version")
    for pkg in backends.packages():
        try:
            v = md.version(pkg)
        except md.PackageNotFoundError:
            v = "[red]missing[/] (run: make setup)"
        t.add_row(pkg, v)
    out.print(t)
    t = Table(title="backends", title_justify="left")
    t.add_column("backend")
    t.add_column("status")
    t.add_column("detail")
    all_ok = True
    for name in backends.all_names():
        i = backends.info(name)
        all_ok &= i.available
        t.add_row(name, "[green]ok[/]" if i.available else "[red]unavailable[/]", i.detail)
    out.print(t)
    if not all_ok:
        raise typer.Exit(1)
