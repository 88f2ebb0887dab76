"""The `minirt` command line: the only place that parses arguments and prints.

Typer (on Click) gives typed options, generated --help and usage errors with exit status 2; rich
draws progress bars and tables on stderr. Bad input is one line per problem and exit status 2,
never a traceback (set MINIRT_DEBUG=1 to see one for an unexpected internal error).
"""

from __future__ import annotations

import math
import os
import signal
import sys
from contextlib import contextmanager
from enum import StrEnum
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from rich.table import Table

from minirt.errors import MinirtError
from minirt.io.untrusted import terminal_text

try:  # Typer >= 0.20 raises the exceptions of the Click it vendors; older ones use Click itself
    from typer._click import exceptions as click_errors
except ImportError:  # pragma: no cover
    from click import exceptions as click_errors

app = typer.Typer(
    name="minirt",
    help="A reference ray tracer for ETH Informatik I problem 13.1, checked against Mitsuba 3, POV-Ray and Embree.",
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    context_settings={"help_option_names": ["-h", "--help"]},
)


def _closed_streams_to_devnull() -> None:
    """A standard stream whose descriptor was closed before minirt started (``minirt ... >&-``, a
    daemon's): Python leaves sys.stdout or sys.stderr None, and minirt died of an AttributeError --
    at import for stderr, at its first message for stdout -- with exit 1, a FAIL's status, even for a
    broken scene. What cannot be said goes to /dev/null; the exit status still tells (0, 1, 2)."""
    for name in ("stdout", "stderr"):
        if getattr(sys, name) is None:
            setattr(sys, name, open(os.devnull, "w"))  # noqa: SIM115 -- the process's stream until exit


_closed_streams_to_devnull()  # before the consoles below ask stderr whether it is a terminal
# Tables in logs and pipes get room to breathe; a terminal keeps its own width.
err = Console(stderr=True, highlight=False, emoji=False, soft_wrap=True, width=None if sys.stderr.isatty() else 160)
out = Console(highlight=False, emoji=False, soft_wrap=True)


class _PipeClosed(Exception):
    """The reader of standard output (or error) went away: ``minirt check ... | head -1``."""


def _pipe_closed() -> None:
    """Console.on_broken_pipe: Rich's own exits 1, which reads as a FAIL verdict; ``main`` exits as a
    process killed by SIGPIPE would, once the clean-ups on the way out have run."""
    raise _PipeClosed


out.on_broken_pipe = err.on_broken_pipe = _pipe_closed
MAX_MESSAGE = 2000  # characters of one message line built from untrusted parts (a file name, a key)


class Precision(StrEnum):
    f64 = "f64"
    f32 = "f32"


SceneArg = Annotated[
    Path,
    typer.Argument(
        metavar="SCENE", help="A scene file (TOML) or a bundled scene's name, e.g. exercise.", show_default=False
    ),
]
ProfileOpt = Annotated[
    str | None,
    typer.Option(
        "--profile",
        help="Model profile: exercise (the pseudo-code, literally), conventional (as POV-Ray does) or eth2014 "
        "(the course's 2014 edition).",
    ),
]
RuleOpt = Annotated[
    list[str] | None,
    typer.Option("--rule", help="Override one model rule, e.g. --rule shadow_range=to-light (repeatable)."),
]
WidthOpt = Annotated[int | None, typer.Option("--width", min=1, help="Image width in pixels (overrides the scene).")]
HeightOpt = Annotated[int | None, typer.Option("--height", min=1, help="Image height in pixels (overrides the scene).")]
ScenesArg = Annotated[
    list[Path] | None,
    typer.Argument(
        metavar="SCENE...", help="Scene files, bundled scenes' names or folders (default: the bundled scenes)."
    ),
]
OraclesOpt = Annotated[str, typer.Option("--backend", "-b", help="Oracles to compare with (comma list or all).")]
SizeOpt = Annotated[str | None, typer.Option("--size", help="Render at WIDTHxHEIGHT instead of the scene's size.")]
QuietOpt = Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")]


def _workers_opt(default: str) -> Any:
    """``--workers N`` (local worker processes, a Dask LocalCluster), its default said by each command."""
    return Annotated[
        int | None,
        typer.Option(
            "--workers", metavar="N", min=1, max=256, show_default=False,
            help=f"Run the jobs on N local worker processes, a Dask LocalCluster (default: {default}; 1: here).",
        ),
    ]  # fmt: skip


CheckWorkersOpt = _workers_opt("every check in this process")
GradeWorkersOpt = _workers_opt("with --class, one per core, none with fewer than 16 images")
FuzzWorkersOpt = _workers_opt("one per core, none with fewer than 8 jobs each")
SweepWorkersOpt = _workers_opt("1, one series after the other: series at once share cores, and so their times")

SchedulerOpt = Annotated[
    str | None,
    typer.Option(
        "--scheduler", metavar="ADDRESS",
        help="Run the jobs on a running Dask cluster (tcp://host:8786); its workers need minirt and the renderers.",
    ),
]  # fmt: skip
CacheOpt = Annotated[
    Path | None,
    typer.Option(
        "--cache", metavar="DIR",
        help="Keep each (scene, oracle) check's result in DIR by content hash (scene text, size, oracle, "
        "versions); a rerun checks only what changed.",
    ),
]  # fmt: skip
JsonOpt = Annotated[
    str | None,
    typer.Option(
        "--json", metavar="FILE", help="Write the results as JSON to FILE (- for standard output; then nothing else)."
    ),
]


def _version(value: bool) -> None:
    if not value:
        return
    import importlib.metadata as md

    def v(pkg: str) -> str:
        try:
            return md.version(pkg)
        except md.PackageNotFoundError:
            return "missing"

    out.print(f"minirt {v('minirt')}", markup=False)
    out.print(f"drjit {v('drjit')}, mitsuba {v('mitsuba')}", markup=False)
    raise typer.Exit(0)


@app.callback()
def _options(
    version: Annotated[
        bool,
        typer.Option(
            "--version",
            callback=_version,
            is_eager=True,
            help="Print minirt's version and the pinned drjit and mitsuba versions, then exit.",
        ),
    ] = False,
) -> None:
    pass


def _parse_rules(items: list[str] | None) -> dict[str, Any]:
    out_: dict[str, Any] = {}
    for item in items or []:
        if "=" not in item:
            raise MinirtError(f"--rule {item}: expected NAME=VALUE, e.g. --rule clamp=true")
        k, v = (s.strip() for s in item.split("=", 1))
        low = v.lower()
        if low in ("true", "false"):
            out_[k] = low == "true"
        else:
            try:
                out_[k] = float(v)
            except ValueError:
                out_[k] = v
    return out_


def _load(path: Path, width=None, height=None, samples=None, profile=None, rules=None):
    """(scene with the flags' overrides, its rules)."""
    return _load_plain(path, width, height, samples, profile, rules)[1:]


def _load_plain(path: Path, width=None, height=None, samples=None, profile=None, rules=None):
    """(the scene as loaded, the scene with the flags' overrides, its rules): the file parsed once (a scene
    of 100,000 balls is 14 MB of TOML, ~4 s to parse)."""
    from minirt.model import rules as rules_mod
    from minirt.model.bundled import find_scene
    from minirt.model.scene import load_scene

    plain = load_scene(find_scene(path))
    scene = plain.with_overrides(width=width, height=height, samples=samples, profile=profile)
    return plain, scene, rules_mod.resolve(scene, profile, _parse_rules(rules))


@contextmanager
def _progress(enabled: bool = True):
    """A progress bar on stderr, only on a terminal (pipes and CI logs get none)."""
    if not enabled or not err.is_terminal:
        yield None
        return
    with Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total}"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=err,
        transient=True,
    ) as p:
        yield p


def _warn(scene_name: str, line: str) -> None:
    """A warning: one line on stderr, ``minirt: warning: SCENE: ...`` (as errors are ``minirt: error: ...``)."""
    err.print(terminal_text(f"minirt: warning: {scene_name}: {line}", MAX_MESSAGE))


HAZARD_PREVIEW_PIXELS = 2**18  # offset hazards of a render without buffers are counted on a render this size


def _hazard_warnings(scene, rules, reference=None, precision: str = "f64", float32_by: list[str] = ()) -> None:
    """Warn about the scene's offset hazards (on ``reference``'s primary hits, else on a reference render of
    the scene, reduced to HAZARD_PREVIEW_PIXELS when larger) and, for float32 tracers, its coordinates."""
    from minirt.reference import hazards, tracer

    for line in hazards.float32_warnings(scene, "float32 (" + ", ".join(float32_by) + ")") if float32_by else []:
        _warn(scene.name, line)
    if rules.offset == "error-bound":
        return
    note = ""
    if reference is None or not reference.ok or reference.hit is None:
        w, h = scene.camera.width, scene.camera.height
        k = math.sqrt(HAZARD_PREVIEW_PIXELS / (w * h))
        if k < 1:
            scene = scene.with_overrides(width=max(1, int(w * k)), height=max(1, int(h * k)))
            note = f" (counted on a {scene.camera.width}x{scene.camera.height} render of the scene)"
        try:
            reference = tracer.render(scene, rules, precision=precision)
        except MinirtError:  # the render itself reported why it cannot trace this scene
            return
    for line in hazards.offset_warnings(scene, rules, reference, precision):
        _warn(scene.name, line + note)


# ---------------------------------------------------------------------------------------------
RENDER_HELP = "\n\n".join([
    "Render a scene with one or more backends; write PNG, EXR (all buffers) and JSON per backend.",
    "Files are named SCENE.BACKEND.png (.exr, .json); a render under another profile or rule than the scene's own "
    "is named by what differs, e.g. exercise.reference+clamp=true.png, so it never overwrites the render of the "
    "scene's own model.",
    "Any size up to 16384x16384: the reference traces in tiles of 2^20 pixels and, rendering alone, writes each "
    "tile's rows as they come (a 4096x4096 render needs about 1.1 GB). Scenes of many balls go through a bounding "
    "volume hierarchy (100,000 balls: seconds).",
])  # fmt: skip


@app.command(help=RENDER_HELP)
def render(
    scene_path: SceneArg,
    backend: Annotated[
        str, typer.Option("--backend", "-b", help="reference, mitsuba, povray, embree, a comma list, or all.")
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
    from minirt.io import names as naming

    plain, scene, rules = _load_plain(scene_path, width, height, samples, profile, rule)
    tag = naming.variant_tag(plain, scene, rules)
    names = backends.parse_backends(backend)
    dest = _out_dir(out_dir or Path("renders") / naming.scene_stem(scene))
    w, h = scene.camera.width, scene.camera.height
    _render_fits(names, scene, rules)
    if not quiet:
        err.print(
            f"[bold]{terminal_text(scene.name)}[/] {w}x{h}, {scene.samples} sample(s)/pixel, profile {scene.profile}"
        )
    results = []
    with _progress(not quiet) as bar:
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
                if not quiet:
                    _report_render(res, paths)
            else:
                err.print(f"  {name:<9} [yellow]{res.status.upper()}[/]: {terminal_text(res.reason)}")
    ref = backends.reference_result(results)
    f32 = [n for n in names if backends.get(n).is_float32({"precision": precision.value})]
    _hazard_warnings(scene, rules, ref, precision.value, f32)
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


# ---------------------------------------------------------------------------------------------
@app.command()
def probe(
    scene_path: Annotated[
        str,
        typer.Argument(
            metavar="SCENE", help="A scene file or a bundled scene's name, e.g. exercise.", show_default=False
        ),
    ],
    x: Annotated[int, typer.Argument(help="Pixel column (0 = left).", show_default=False)],
    y: Annotated[int, typer.Argument(help="Pixel row (0 = top).", show_default=False)],
    as_json: Annotated[
        bool, typer.Option("--json", help="Write the probe as JSON to standard output (strict JSON, nothing else).")
    ] = False,
    image: Annotated[
        Path | None,
        typer.Option(
            "--image", metavar="IMAGE", help="Another tracer's image of the scene: show its value at the pixel too."
        ),
    ] = None,
    width: WidthOpt = None,
    height: HeightOpt = None,
    precision: Annotated[Precision, typer.Option("--precision")] = Precision.f64,
    profile: ProfileOpt = None,
    rule: RuleOpt = None,
) -> None:
    """Trace one pixel step by step: ray, every shape's intersection, shadow ray, terms, reflections.

    With --image, the other tracer's value at that pixel beside the reference's (read as `grade` reads it).
    """
    from minirt.model.bundled import find_scene
    from minirt.reference.probe import image_pixel
    from minirt.reference.probe import probe as run_probe

    scene, rules = _load(find_scene(scene_path), width, height, None, profile, rule)
    target = notes = None
    if image is not None:
        from minirt.grading.grade import check_size, load_target

        target = load_target(image)
        try:
            notes = check_size(scene, target, str(image))
        except MinirtError as e:  # grade's message, with probe's options for the size
            rows, cols = target.shape
            raise MinirtError(
                str(e).replace(f"grade with --size {cols}x{rows}", f"probe with --width {cols} --height {rows}")
            ) from None
    p = run_probe(scene, rules, x, y, precision.value)
    if target is not None:
        p["image"] = image_pixel(scene, p, target, rules, notes)
    if as_json:
        _emit_json("-", p)
        return
    _print_probe(p)


def _fmt(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, list):
        return "(" + ", ".join(f"{c:.9g}" for c in v) + ")"
    return f"{v:.12g}" if isinstance(v, float) else str(v)


def _offset_text(off: dict[str, Any]) -> str:
    """probe's line on the secondary rays' offset at a hit (minirt.reference.hazards.offset_at)."""
    if off["offset"] == "error-bound":
        return "offset: error-bound (secondary rays start the hit point's error bound away)"
    text = f"offset {_fmt(off['offset'])} along the {'new ray' if off['along'] == 'ray' else 'normal'}"
    notes = []
    if off["below_rounding"]:
        notes.append(
            f"below the hit point's rounding {off['rounding']:.3g}: the ray may start behind the surface (acne risk)"
        )
    for j in off["jumps"]:
        notes.append(
            f"the {j['ray']} ray's origin jumps over shape {j['shape']}'s surface, {j['gap']:.3g} from the point "
            "(a near contact): it starts beyond it"
        )
    return text + (": " + "; ".join(notes) if notes else f" (the hit point's rounding is {off['rounding']:.3g}: safe)")


def _print_probe(p: dict[str, Any]) -> None:
    x, y = p["pixel"]
    out.print(f"pixel ({x}, {y}) of {terminal_text(p['scene'])}")
    for lvl in p["levels"]:
        ind = "  " * lvl["depth"]
        head = "primary ray" if lvl["depth"] == 0 else f"reflection {lvl['depth']}"
        out.print(f"{ind}{head}: origin {_fmt(lvl['ray']['origin'])} direction {_fmt(lvl['ray']['direction'])}")
        for s in lvl["shapes"]:
            out.print(f"{ind}  shape {s['id']} ({s['type']}): " + ("miss" if s["t"] is None else f"t = {_fmt(s['t'])}"))
        hit = lvl["hit"]
        if hit is None:
            out.print(f"{ind}  -> no hit")
        else:
            out.print(
                f"{ind}  -> hit shape {hit['id']} ({terminal_text(hit['material'])}) at t = {_fmt(hit['t'])}, "
                f"point {_fmt(hit['point'])}, normal {_fmt(hit['normal'])}"
            )
            sh = lvl.get("shadow")
            if sh:
                blk = ", ".join(f"shape {b['id']} at t = {_fmt(b['t'])}" for b in sh["blockers"]) or "nothing"
                out.print(
                    f"{ind}  shadow ray from {_fmt(sh['origin'])} towards the light "
                    f"({_fmt(sh['light_distance'])} away): blocked by {blk}"
                )
            off = lvl.get("offset")
            if off:
                out.print(f"{ind}  {_offset_text(off)}", markup=False)
        for k, v in lvl["terms"].items():
            out.print(f"{ind}  {k:<10} {_fmt(v)}")
    out.print(f"colour {_fmt(p['color'])} -> clamped {_fmt(p['color_clamped'])} -> 8-bit {tuple(p['color8'])}")
    im = p.get("image")
    if im:
        for note in im["notes"]:
            out.print(f"note: {terminal_text(note)}")
        if im["format"] == "float":
            yours, ref = _fmt(im["value"]), _fmt(im["reference"])
            diff = "the same" if im["difference"] == 0 else f"differs by {im['difference']:.6g}"
        else:
            yours, ref = str(tuple(im["value"])), str(tuple(im["reference"]))
            n = im["difference"]
            diff = "the same" if n == 0 else f"differs by {n} level{'s' if n != 1 else ''}"
        out.print(terminal_text(f"your image: {yours} [{im['format']}]  reference: {ref} -> {diff}"))


# ---------------------------------------------------------------------------------------------
@app.command()
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


@app.command()
def doctor() -> None:
    """Which backends and libraries are present, their versions, and what to install for the missing ones."""
    import importlib.metadata as md

    from minirt.harness import backends

    t = Table(title="libraries", title_justify="left")
    t.add_column("package")
    t.add_column("version")
    for pkg in ("drjit", "mitsuba", "OpenImageIO", "trimesh", "embreex", "numpy", "colour-science", "flip-evaluator"):
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


@app.command()
def export(
    scene_path: SceneArg,
    to: Annotated[
        str,
        typer.Option(
            "--to",
            metavar="RENDERER",
            help="An oracle's export: mitsuba (XML scene), povray (.pov + command), mesh (glTF); a name it does not "
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
    scene, rules = _load(scene_path, profile=profile, rules=rule)
    o = targets[to]
    files = o.export(scene, o.adapt(rules), _out_dir(out_dir))
    for f in files:
        out.print(f"wrote {terminal_text(f)}")


# ---------------------------------------------------------------------------------------------
VERDICT_STYLE = {"pass": "green", "warn": "yellow", "fail": "bold red", "error": "bold magenta", "skip": "dim"}


def _scene_paths(paths: list[Path] | None) -> list[Path]:
    """SCENE... of check and report: files, bundled scenes' names and folders; none: every bundled scene."""
    from minirt.model.bundled import BUNDLED, find_scene

    if not paths:
        return sorted(BUNDLED.glob("*.toml"))
    out_: list[Path] = []
    for p in paths:
        if p.is_dir():
            out_ += sorted(p.glob("*.toml"))
        else:
            out_.append(find_scene(p))
    return out_


def _parse_size(size: str | None) -> tuple[int, int] | None:
    if not size:
        return None
    try:
        w, sep, h = size.lower().partition("x")
        wh = (int(w), int(h if sep else w))  # "64" is 64x64; "10x" is a mistake, not 10x10
    except ValueError:
        raise MinirtError(f"--size {size}: expected WIDTHxHEIGHT, e.g. 128x128") from None
    if min(wh) < 1:
        raise MinirtError(f"--size {size}: width and height must be >= 1")
    return wh


def _pool(workers: int | None, scheduler: str | None, default: int) -> int:
    """The worker count of a command's --workers/--scheduler pair (minirt.jobs.batch.pool)."""
    from minirt.jobs import batch as jobs

    return jobs.pool(workers, scheduler, default, "--workers and --scheduler")


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


def run_checks(
    paths,
    backend: str,
    size: str | None,
    quiet: bool,
    workers: int | None = None,
    scheduler: str | None = None,
    cache: Path | None = None,
):
    """Shared by `check` and `report`: render and compare, with a progress bar on a terminal."""
    from minirt.harness import backends
    from minirt.harness import run as harness

    workers = _pool(workers, scheduler, default=1)

    scenes_ = _scene_paths(paths)
    names = backends.parse_backends(backend)
    backends.require_oracle(names)
    wh = _parse_size(size)
    for p in scenes_:  # bad input first, before any long work
        _load(p)
    if cache is not None:
        _out_dir(cache, "--cache")
    oracle_count = max(1, len(backends.oracles_among(names)))
    with _progress(not quiet) as bar:
        task = bar.add_task("checking", total=len(scenes_) * oracle_count) if bar else None

        jobs_mode = workers > 1 or scheduler is not None or cache is not None

        def tick(i: int, scene: str, name: str, j: int, n: int) -> None:
            if not bar:
                return
            label = f"{terminal_text(scene, 40)}: {name}"
            if jobs_mode:  # jobs finish in any order: one step each
                bar.update(task, advance=1, description=label)
            else:
                bar.update(task, completed=i * oracle_count + j, description=label)

        result = harness.run(scenes_, names, wh, tick, workers=workers, scheduler=scheduler, cache=cache)
        if bar:
            bar.update(task, completed=len(scenes_) * oracle_count)
    return result


def _check_warnings(result, backend: str, size: str | None) -> None:
    """The hazard warnings of every checked scene, on its reference render (rules of the scene)."""
    from minirt.harness import backends
    from minirt.harness import run as harness

    names = backends.parse_backends(backend)
    for sc in result.scenes:
        scene, rules = harness._scene_and_rules(sc.file, _parse_size(size))
        f32 = [n for n in sc.backends if n in names and backends.get(n).is_float32({})]
        _hazard_warnings(scene, rules, sc.reference, "f64", f32)


def _print_check(result) -> None:
    t = Table(title="minirt check", title_justify="left")
    for col in ("scene", "backend", "verdict", "geometry", "shading", "rules explaining its image", "seconds"):
        t.add_column(col)
    for s in result.scenes:
        for name, b in s.backends.items():
            g = b.checks.get("geometry")
            sh = b.checks.get("shading")
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


@app.command()
def check(
    scene_paths: ScenesArg = None,
    backend: OraclesOpt = "all",
    json_out: JsonOpt = None,
    junit: Annotated[Path | None, typer.Option("--junit", help="Write the results as JUnit XML.")] = None,
    size: SizeOpt = None,
    workers: CheckWorkersOpt = None,
    scheduler: SchedulerOpt = None,
    cache: CacheOpt = None,
    quiet: QuietOpt = False,
) -> None:
    """Compare the reference tracer with the oracles: geometry pixel by pixel, shading, rules.

    Exit status: 0 all pass (or warn/skip), 1 a check failed, 2 bad input or a backend error.
    """
    from minirt.io.atomic import atomic_path

    if json_out != "-":
        _out_file(Path(json_out) if json_out else None, "--json")
    _out_file(junit, "--junit")
    result = run_checks(scene_paths, backend, size, quiet, workers, scheduler, cache)
    _print_check(result)
    _check_warnings(result, backend, size)
    if json_out:
        _emit_json(json_out, result.as_dict())
    if junit:
        from minirt.harness.junit import junit_xml

        with atomic_path(junit) as tmp:
            tmp.write_text(junit_xml(result))
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


@app.command(help=SWEEP_HELP)
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
            "machine); a rerun renders only what changed.",
        ),
    ] = None,
    quiet: QuietOpt = False,
) -> None:
    """What accuracy costs in time (help text: SWEEP_HELP, paragraphs Rich wraps to the terminal)."""
    from minirt.harness import backends
    from minirt.sweep.sweep import run_sweep

    scene, rules = _load(scene_path, profile=profile, rules=rule)
    names = backends.parse_backends(backend)
    workers = _pool(workers, scheduler, default=1)
    _out_dir(out_dir)
    with _progress(not quiet) as bar:
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


@app.command()
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

    backends.require_oracle(backends.parse_backends(backend))  # before the folder is made
    _out_dir(out_dir)
    result = run_checks(scene_paths, backend, size, quiet, workers, scheduler, cache)
    _print_check(result)
    _check_warnings(result, backend, size)
    command = "minirt " + " ".join(sys.argv[1:]) if sys.argv[1:2] == ["report"] else "minirt report"
    index = write_report(result, out_dir, command=command, sweep=sweep_data, sweep_dir=sweep_dir)
    out.print(f"{result.verdict.upper()}: wrote {terminal_text(index)}")
    raise typer.Exit(result.exit_code())


# ---------------------------------------------------------------------------------------------
@app.command()
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
            metavar="IMAGE", help="The other tracer's image: PNG, BMP, PPM/PGM, TGA, TIFF or EXR.", show_default=False
        ),
    ] = None,
    json_out: JsonOpt = None,
    out_dir: Annotated[
        Path | None, typer.Option("--out", "-o", help="Write an HTML page with the pictures (DIR/index.html).")
    ] = None,
    class_dir: Annotated[
        Path | None,
        typer.Option(
            "--class", metavar="DIR", help="Grade a whole class: DIR/<student>/<scene stem>.png (any supported type)."
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
            "and the same paths.",
        ),
    ] = None,
    cache: Annotated[
        Path | None,
        typer.Option(
            "--cache",
            metavar="DIR",
            help="With --class: keep each image's grade in DIR by content hash (image bytes, scene, rules, "
            "versions); a rerun grades only new or changed images.",
        ),
    ] = None,
    profile: ProfileOpt = None,
    rule: RuleOpt = None,
    quiet: QuietOpt = False,
) -> None:
    """Grade another tracer's image of a scene: is it the exercise's model, and if not, which rule
    settings explain it (searched over every rule; `minirt render SCENE --rule ...` with them reproduces
    the image).

    Exit status: 0 match (every pixel within one 8-bit level, ill-conditioned pixels aside), 1 differs
    (the diagnosis says how), 2 bad input. With --class: OUT/grades.csv, grades.json and index.html,
    one row per student and scene (missing or unreadable images are rows with verdict "error"); exit 0
    when the class was graded. Each image of a class is one job: on --workers processes here (each
    with its own render cache, pages written as images are graded) or on a Dask cluster (--scheduler);
    the files are the same bytes either way.
    """
    if class_dir is not None:
        if scene_path is not None or image is not None:
            raise MinirtError("--class grades DIR/<student>/<scene>.png: give no SCENE or IMAGE with it")
        _grade_class(
            class_dir, scenes_dir, out_dir or Path("grades"), json_out, size, profile, rule, quiet, workers, scheduler,
            cache,
        )  # fmt: skip
        return
    if scene_path is None or image is None:
        raise MinirtError(
            "grade needs SCENE and IMAGE (or --class DIR), e.g. minirt grade scenes/rules.toml student.png"
        )
    class_only = ((scenes_dir, "--scenes"), (workers, "--workers"), (scheduler, "--scheduler"), (cache, "--cache"))
    for given, option in class_only:
        if given is not None:
            raise MinirtError(f"{option} goes with --class")
    from minirt.grading import grade as grading
    from minirt.model.bundled import find_scene

    if json_out not in (None, "-"):
        _out_file(Path(json_out), "--json")
    if out_dir is not None:
        _out_dir(out_dir)
    path = find_scene(scene_path)
    wh = _parse_size(size)
    scene, rules = _load(path, *(wh or (None, None)), None, profile, rule)
    with _progress(not quiet) as bar:
        task = bar.add_task("grading", total=None) if bar else None
        g = grading.grade_image(scene, str(path), image, rules, size_override=wh)
        if bar:
            bar.update(task, completed=1, total=1)
    if json_out is not None:
        _emit_json(json_out, g.as_dict())
    page = None
    if out_dir is not None:
        from minirt.grading.page import write_grade_page

        page = write_grade_page(g, out_dir)
    if json_out != "-":
        _print_grade(g, page)
    raise typer.Exit(g.exit_code)


def _emit_json(dest: str, data: dict[str, Any]) -> None:
    """Every command's --json: strict JSON with schema_version, to the file or (``-``) to standard output,
    which then holds nothing else (messages go to standard error)."""
    from minirt.io.jsonout import emit_json

    try:
        emit_json(dest, data)
    except BrokenPipeError:  # Click would exit 1 (a FAIL verdict's status) on it: see _pipe_closed
        raise _PipeClosed from None


def _print_grade(g, page: Path | None) -> None:
    from minirt.grading import grade as grading

    style = {"match": "green", "differs": "yellow", "error": "red"}[g.verdict]
    err.print(f"[bold {style}]{g.verdict.upper()}[/]", end=" ")
    err.print(terminal_text(f"{g.scene.name}: {g.summary()}", MAX_MESSAGE))
    for note in g.notes:
        err.print(f"  note: {terminal_text(note, MAX_MESSAGE)}")
    d = g.diagnosis
    for e in d.explained:
        s = grading.sentence(e.rule, getattr(d.best, e.rule), getattr(d.given, e.rule))
        err.print(terminal_text(f"  {e.rule}={e.value} ({e.pixels} pixels): {s}", MAX_MESSAGE))
    for i in d.indistinguishable:
        tell = (
            f"scene {i['scene_that_tells']} tells them apart"
            if i["scene_that_tells"]
            else "no bundled scene tells them apart"
        )
        err.print(terminal_text(f"  cannot tell {i['rule']}={i['value']} from {i['as']} in this scene ({tell})"))
    if d.changed:
        err.print(f"  reproduce: {terminal_text(g.reproduce(), MAX_MESSAGE)}")
    if page is not None:
        out.print(f"wrote {terminal_text(page)}")


def _grade_class(
    class_dir, scenes_dir, out_dir, json_out, size, profile, rule, quiet, workers, scheduler, cache
) -> None:
    from minirt.grading import classroom
    from minirt.grading.page import write_class_page
    from minirt.io.images import write_json
    from minirt.jobs import batch as jobs
    from minirt.jobs import memory
    from minirt.model.bundled import BUNDLED

    people = classroom.students(class_dir)
    folder = scenes_dir or BUNDLED
    if not folder.is_dir():
        raise MinirtError(f"--scenes {folder}: no such folder")
    files = sorted(folder.glob("*.toml"))
    submitted = {p.stem for s in people for p in s.iterdir() if p.is_file()}
    files = [f for f in files if f.stem in submitted]
    if not files:
        raise MinirtError(f"--class {class_dir}: no image is named after a scene in {folder} (e.g. exercise.png)")
    if json_out not in (None, "-"):
        _out_file(Path(json_out), "--json")
    _out_dir(out_dir)
    if cache is not None:
        _out_dir(cache, "--cache")
    wh = _parse_size(size)
    loaded = [(str(f), *_load(f, *(wh or (None, None)), None, profile, rule)) for f in files]
    total = len(people) * len(loaded)
    workers = _pool(workers, scheduler, default=0) or jobs.default_workers(total)
    budget = classroom.PROCESS_CACHE_BYTES  # a cluster's workers: their memory is not ours to measure
    if scheduler is None:
        biggest = max(loaded, key=lambda x: x[1].camera.width * x[1].camera.height)[1].camera
        n = max(1, workers)
        budget = memory.class_cache_bytes(
            biggest.width * biggest.height, n, budget,
            f"grading a class at {biggest.width}x{biggest.height} in {n} process{'es' if n > 1 else ''}",
        )  # fmt: skip
    with _progress(not quiet) as bar:
        label = f"grading ({workers} processes)" if scheduler is None and workers > 1 else "grading"
        task = bar.add_task(label, total=total) if bar else None

        def done(job, row) -> None:
            if bar:
                bar.update(task, description=terminal_text(f"{row.student[:16]:<16} {row.scene[:12]:<12}"))
                bar.advance(task)

        store = None if cache is None else classroom.class_cache(cache, out_dir)
        rows = classroom.grade_class(
            people, loaded, out_dir, workers=workers, scheduler=scheduler, on_done=done, cache=store,
            cache_bytes=budget,
        )  # fmt: skip
    summary = classroom.class_dict(rows, [f.stem for f in files])
    index = write_class_page(rows, summary, out_dir, quiet=quiet)
    summary["grades"] = [r.as_dict() for r in rows]  # with the pages' links
    classroom.write_csv(out_dir / "grades.csv", rows)
    write_json(out_dir / "grades.json", summary)
    if json_out is not None:
        _emit_json(json_out, summary)
    v = summary["verdicts"]
    (err if json_out == "-" else out).print(
        f"graded {len(people)} students x {len(files)} scenes: {v['match']} match, {v['differs']} differ, "
        f"{v['error']} error"
        + (f" ({store.hits} of {total} from the cache)" if store is not None else "")
        + f"; wrote {terminal_text(index)}"
    )


FUZZ_HELP = "\n\n".join([
    "An adversarial campaign: generated hard scenes checked against every oracle, as independent jobs.",
    "Scene i is family i mod F's number i // F (families: {families}); the same seed gives the same scenes "
    "and the same JSON. Each (scene, oracle) is one job, run in this process (--workers 1), on an embedded "
    "Dask LocalCluster (default: one worker per core once there are enough jobs) or on a running Dask "
    "cluster (--scheduler tcp://host:8786; its workers need minirt and the renderers installed). Results "
    "are cached in OUT/cache by content hash (scene text, oracle, defects, versions), so a rerun does only "
    "what changed.",
    "--defects also checks each oracle against the reference with an injected bug (defects: {defects}): "
    "a defect that changes a scene's image must make some oracle FAIL there; the catch rate is reported.",
    "Every non-PASS keeps its scene file, the check's JSON and both images in OUT. Writes OUT/fuzz.json "
    "(and --json). Exit status: 0 nothing failed, 1 a check failed, 2 a backend error or bad input.",
])  # fmt: skip


def _fuzz_help() -> str:
    from minirt.campaign.campaign import DEFECTS
    from minirt.campaign.families import FAMILIES

    return FUZZ_HELP.format(families=", ".join(FAMILIES), defects=", ".join(DEFECTS))


@app.command(help=_fuzz_help())
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
    from minirt.campaign.families import FAMILIES
    from minirt.harness import backends
    from minirt.io.images import write_json
    from minirt.jobs import batch as jobs

    wh = _parse_size(size)
    fams = (
        tuple(FAMILIES)
        if families.strip().lower() == "all"
        else tuple(f.strip() for f in families.split(",") if f.strip())
    )
    unknown = [f for f in fams if f not in FAMILIES]
    if unknown or not fams:
        raise MinirtError(
            f"--families: unknown family {', '.join(unknown) or repr(families)} (known: all, {', '.join(FAMILIES)})"
        )
    names = backends.parse_backends(backend)
    backends.require_oracle(names)
    names = backends.oracles_among(names)
    kinds = campaign.parse_defects(defects)
    workers = _pool(workers, scheduler, default=0)  # 0: sized below, from the jobs' count
    if json_out not in (None, "-"):
        _out_file(Path(json_out), "--json")
    _out_dir(out_dir)
    c = campaign.Campaign(seed=seed, families=fams, size=wh, backends=tuple(names), defects=kinds)
    c.scenes = campaign.scenes(count, seed, fams, wh)
    total = len(c.scenes) * len(names)
    workers = workers or jobs.default_workers(total, per_worker=8)
    counts = dict.fromkeys(campaign.VERDICTS, 0)
    with _progress(not quiet) as bar:
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

        campaign.run(c, None if no_cache else out_dir / "cache", workers=workers, scheduler=scheduler, on_done=done)
    campaign.write_evidence(c, out_dir)
    doc = campaign.summary(c)
    write_json(out_dir / "fuzz.json", doc)
    if json_out is not None:
        _emit_json(json_out, doc)
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


# ---------------------------------------------------------------------------------------------
def _out_dir(path: Path, option: str = "--out") -> Path:
    """Make the output folder before any work, so a bad --out fails in a second, not after a render."""
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise MinirtError(f"{option} {path}: cannot create the folder ({e.strerror or e})") from None
    if not os.access(path, os.W_OK):
        raise MinirtError(f"{option} {path}: the folder is not writable")
    return path


def _out_file(path: Path | None, option: str) -> None:
    if path is not None:
        if path.is_dir():
            raise MinirtError(f"{option} {path}: is a folder, expected a file name")
        _out_dir(path.parent if str(path.parent) else Path("."), option)


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _command_path(ctx) -> str:
    """`minirt CMD` however minirt was started (the console script or python -m minirt)."""
    names = []
    while ctx is not None and ctx.parent is not None:
        names.append(ctx.info_name)
        ctx = ctx.parent
    return " ".join(["minirt", *reversed(names)])


_stopped_by: list[int] = []  # the signal that stopped this run (Typer may turn the interrupt into a status)


def _on_signal(signum, frame) -> None:
    from minirt.jobs import processes

    _stopped_by.append(signum)
    processes.kill_all()  # the renderers first, so the threads waiting for them return at once
    raise KeyboardInterrupt  # SIGTERM and SIGHUP unwind like Ctrl-C: the same clean-up on the way out


def _stopped(signum: int) -> None:
    """Every clean-up has run on the way here (the interrupt unwound through them): say so and exit."""
    err.print("minirt: aborted" if signum == signal.SIGINT else f"minirt: stopped by {signal.Signals(signum).name}")
    sys.exit(128 + signum)


def main() -> None:
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, _on_signal)
    try:
        rv = app(standalone_mode=False)
        if _stopped_by:
            _stopped(_stopped_by[0])
        sys.stdout.flush()  # a closed pipe shows here, not as a warning at the interpreter's exit
        sys.exit(rv if isinstance(rv, int) else 0)
    except (_PipeClosed, BrokenPipeError):
        # Nobody reads what is left to say: no message, and the status of a command killed by SIGPIPE
        # (141), not 1 (FAIL) or 2 (bad input). Writes are atomic, so every file written is whole.
        devnull = os.open(os.devnull, os.O_WRONLY)
        for fd in (1, 2):
            os.dup2(devnull, fd)  # the interpreter's last flush then has nowhere to fail
        sys.exit(128 + signal.SIGPIPE)
    except MinirtError as e:
        for line in e.lines or [str(e)]:
            err.print(f"minirt: error: {terminal_text(line, MAX_MESSAGE)}")
        sys.exit(2)
    except typer.Exit as e:
        sys.exit(e.exit_code)
    except (typer.Abort, KeyboardInterrupt):  # Click turns Ctrl-C into Abort
        _stopped(_stopped_by[0] if _stopped_by else signal.SIGINT)
    except click_errors.NoArgsIsHelpError as e:  # `minirt` or a command alone: its help
        e.show()
        sys.exit(2)
    except click_errors.UsageError as e:  # a bad option or argument: one line, like every other bad input
        err.print(f"minirt: error: {terminal_text(_one_line(e.format_message()), MAX_MESSAGE)}")
        if e.ctx is not None:
            err.print(f"try: {terminal_text(_command_path(e.ctx))} --help")
        sys.exit(2)
    except click_errors.ClickException as e:  # Click's other errors (a file it could not open): the same line
        err.print(f"minirt: error: {terminal_text(_one_line(e.format_message()), MAX_MESSAGE)}")
        sys.exit(2 if e.exit_code in (0, 1) else e.exit_code)
    except OSError as e:  # an output folder that cannot be made or written, a disk that is full: bad input
        if os.environ.get("MINIRT_DEBUG"):
            raise
        where = e.filename if e.filename is not None else "output"
        err.print(f"minirt: error: {terminal_text(where)}: {terminal_text(e.strerror or e)}")
        sys.exit(2)
    except Exception as e:
        if os.environ.get("MINIRT_DEBUG"):
            raise
        err.print(f"minirt: internal error: {type(e).__name__}: {terminal_text(e)} (set MINIRT_DEBUG=1 for details)")
        sys.exit(1)
