"""``minirt render`` and ``minirt export``: a scene as one or more backends draw it, or as another renderer
would open it.

Each backend renders through the registry (minirt.harness.backends.render_to_files); what is printed
here is its line per backend, the table of several, and the scene's hazard warnings
(minirt.reference.hazards.scene_warnings).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from minirt.cli.console import err, out, progress_bar, warn
from minirt.cli.options import (
    BACKEND_NAMES,
    HeightOpt,
    Precision,
    ProfileOpt,
    RuleOpt,
    SceneArg,
    WidthOpt,
    load,
    load_plain,
    output_folder,
)
from minirt.errors import MinirtError
from minirt.io.untrusted import terminal_text

RENDER_HELP = "\n\n".join([
    "Render a scene with one or more backends; write PNG, EXR (all buffers) and JSON per backend.",
    "Files are named SCENE.BACKEND.png (.exr, .json); a render under another profile or rule than the scene's own "
    "is named by what differs, e.g. exercise.reference+clamp=true.png, so it never overwrites the render of the "
    "scene's own model.",
    "Any size up to 16384x16384: the reference traces in tiles of 2^20 pixels and, rendering alone, writes each "
    "tile's rows as they come (a 4096x4096 render needs about 1.1 GB). Scenes of many balls go through a bounding "
    "volume hierarchy (100,000 balls: seconds).",
])  # fmt: skip


def render(
    scene_path: SceneArg,
    backend: Annotated[
        str, typer.Option("--backend", "-b", help=f"{', '.join(BACKEND_NAMES)}, a comma list, or all.")
    ] = "reference",
    out_dir: Annotated[
        Path | None, typer.Option("--out", "-o", help="Output folder (default renders/<scene name>).")
    ] = None,
    width: WidthOpt = None,
    height: HeightOpt = None,
    samples: Annotated[int | None, typer.Option("--samples", min=1, help="Rays per pixel (stratified).")] = None,
    precision: Annotated[Precision, typer.Option("--precision", help="Reference tracer precision.")] = Precision.f64,
    profile: ProfileOpt = None,
    rule: RuleOpt = None,
    timings: Annotated[
        bool,
        typer.Option(
            "--timings",
            help="Also record each backend's timings in its JSON sidecar (the sidecar then differs run to run; "
            "without it every file is bit-identical and the timings are printed only).",
        ),
    ] = False,
    quiet: Annotated[
        bool, typer.Option("--quiet", "-q", help="No progress bar and no per-backend lines (failures still print).")
    ] = False,
    timeout: Annotated[
        float | None,
        typer.Option(
            "--timeout",
            metavar="SECONDS",
            min=0.1,
            help="Longest a POV-Ray pass may run before it counts as hung (default: 30 s + 10 us per pixel, "
            "frame and sample).",
            show_default=False,
        ),
    ] = None,
) -> None:
    """Render a scene (help text: RENDER_HELP, paragraphs Rich wraps to the terminal)."""
    from minirt.harness import backends
    from minirt.io import images
    from minirt.io import names as naming
    from minirt.reference import hazards

    plain, scene, rules = load_plain(scene_path, width, height, samples, profile, rule)
    tag = naming.variant_tag(plain, scene, rules)
    names = backends.parse_backends(backend)
    dest = output_folder(out_dir or Path("renders") / naming.scene_stem(scene))
    w, h = scene.camera.width, scene.camera.height
    _render_fits(names, scene, rules)
    if not quiet:
        err.print(
            f"[bold]{terminal_text(scene.name)}[/] {w}x{h}, {scene.samples} sample(s)/pixel, profile {scene.profile}"
        )
    results, written = [], []
    # The files are written by a thread of their own while the warnings are worked out (minirt.io.images);
    # a backend is said "ok" only once they are written (leaving the block waits: a full disk is an error).
    with images.background_writes():
        _render_all(names, scene, rules, precision, samples, timeout, dest, tag, timings, quiet, results, written)
        ref = backends.reference_result(results)
        f32 = [n for n in names if backends.get(n).is_float32({"precision": precision.value})]
        said = list(hazards.scene_warnings(scene, rules, ref, precision.value, f32))
    for res, paths in written if not quiet else ():
        _report_render(res, paths)
    for line in said:
        warn(scene.name, line)
    if len(results) > 1:
        from minirt.pages.sheet import contact_sheet

        sheet = contact_sheet(results, dest / naming.contact_sheet_name(scene, tag))
        if not quiet:
            _render_table(results)
        out.print(f"wrote {terminal_text(dest)}/ ({sheet.name} and {sum(r.ok for r in results)} backend(s))")
    else:
        out.print(f"wrote {terminal_text(dest)}/")
    if not any(r.ok for r in results):
        raise typer.Exit(2)


def _render_all(names, scene, rules, precision, samples, timeout, dest, tag, timings, quiet, results, written) -> None:
    """Each backend's render and files (into ``results``, in order); a failure's line printed, a success
    kept in ``written`` with its files' paths, to be said once they are written."""
    from minirt.harness import backends
    from minirt.io import names as naming

    with progress_bar(not quiet) as bar:
        for name in names:
            task = bar.add_task(f"{name:<9}", total=1) if bar else None

            def tick(done: int, total: int, task=task) -> None:
                if bar:
                    bar.update(task, completed=done, total=total)

            opts = backends.get(name).options(precision.value, samples, timeout)
            # One backend alone: a large reference image is written tile by tile (bounded memory).
            stem = naming.render_stem(scene, name, tag)
            res, paths = backends.render_to_files(
                name, scene, rules, opts, dest, stem, timings, tick, stream=len(names) == 1, variant=tag
            )
            if bar:
                bar.update(task, completed=1, total=1)
            results.append(res)
            if res.ok:
                written.append((res, paths))
            else:
                err.print(f"  {name:<9} [yellow]{res.status.upper()}[/]: {terminal_text(res.reason)}")


def _report_render(res, paths) -> None:
    fx = res.meta.get("effects")
    took = res.meta.get("timings", {}).get("wall", 0.0)
    files = ", ".join(p.name for p in paths.values())
    err.print(f"  {res.backend:<9} [green]ok[/] {took:.2f}s -> {files}")
    if fx:
        err.print(f"            simulated: {', '.join(fx['simulated']) or 'nothing'}")
        err.print(f"            skipped:   {', '.join(fx['skipped']) or 'nothing'}")


def _render_table(results) -> None:
    t = Table(title="backends", title_justify="left")
    for col in ("backend", "status", "seconds", "passes / reason"):
        t.add_column(col)
    for r in results:
        passes = r.meta.get("passes")
        if isinstance(passes, list):
            passes = ", ".join(p if isinstance(p, str) else p.get("name", "?") for p in passes)
        t.add_row(
            r.backend,
            r.status,
            f"{r.meta.get('timings', {}).get('wall', 0.0):.2f}",
            terminal_text(r.reason)
            if not r.ok
            else str(passes or ", ".join(r.meta.get("effects", {}).get("simulated", []))),
        )
    err.print(t)


def _render_fits(names: list[str], scene, rules) -> None:
    """Bad input before any work: a render this machine cannot hold (minirt.jobs.memory), as one line. A
    backend alone that streams (the reference, larger than a tile) is written tile by tile
    (backends.render_to_files): no limit."""
    from minirt.harness import backends
    from minirt.jobs import memory

    w, h = scene.camera.width, scene.camera.height
    if len(names) == 1 and backends.get(names[0]).streams(scene, rules):
        return
    memory.require(
        backends.render_bytes(w * h, names),
        f"rendering {w}x{h} with {', '.join(names)}",
        "render at a smaller --width/--height, or with the reference alone (written tile by tile)",
    )


def export(
    scene_path: SceneArg,
    to: Annotated[
        str,
        typer.Option(
            "--to",
            metavar="RENDERER",
            help="An oracle's export: mitsuba (XML scene), povray (.pov + command), mesh (glTF), blender (.blend); "
            "a name it does not "
            "know lists the known ones.",
        ),
    ],
    out_dir: Annotated[Path, typer.Option("--out", "-o", help="Output folder.")] = Path("out"),
    profile: ProfileOpt = None,
    rule: RuleOpt = None,
) -> None:
    """Write the scene converted for another renderer, as a user would open it there."""
    from minirt.harness import backends

    targets = backends.export_targets()
    if to not in targets:
        raise MinirtError(f"--to: unknown target {to!r} (known: {', '.join(targets)})")
    scene, rules = load(scene_path, profile=profile, rules=rule)
    o = targets[to]
    files = o.export(scene, o.adapt(rules), output_folder(out_dir))
    for f in files:
        out.print(f"wrote {terminal_text(f)}")
