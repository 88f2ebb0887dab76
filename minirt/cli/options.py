"""The command line's shared arguments and options, and the parsing every command does the same way.

Each Typer annotation here is the one definition of an option that several commands take (its --help
text included); the parsers turn their strings into what the API takes (``--rule NAME=VALUE``, ``--size
WIDTHxHEIGHT``, a scene with the flags' overrides) and say bad input as one line naming the option.
Output folders and files are made before any work, so a bad --out fails in a second, not after a render.
"""

from __future__ import annotations

import os
from enum import StrEnum
from pathlib import Path
from typing import Annotated, Any

import typer

from minirt.errors import MinirtError


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
# The backends by name, written out for the help texts (importing the registry pulls NumPy into `--help`);
# tests/cli/test_startup.py holds them to the registry's names and order.
BACKEND_NAMES = ("reference", "mitsuba", "povray", "embree", "cycles", "exact")
OraclesOpt = Annotated[
    str,
    typer.Option(
        "--backend", "-b", help=f"Oracles to compare with: {', '.join(BACKEND_NAMES[1:])}, a comma list, or all."
    ),
]
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

# What every --scheduler and --cache says besides its own sentence (also grade's and sweep's own options).
CLUSTER_TRUST = (
    "Trusting a cluster: its scheduler and workers compute the results and can run any code in minirt (Dask "
    "sends jobs and results as pickles), so use a cluster you control; TLS (tls:// with Dask's security "
    "settings) is how Dask authenticates and encrypts one. minirt waits MINIRT_SCHEDULER_TIMEOUT seconds "
    "(default 5) for the scheduler to answer."
)
CACHE_TRUST = (
    "Entries are data (JSON and .npy), never code; DIR must be yours and writable by no one else, unless "
    "MINIRT_CACHE_SHARED=1 says you trust everyone who can write there."
)
SchedulerOpt = Annotated[
    str | None,
    typer.Option(
        "--scheduler", metavar="ADDRESS",
        help="Run the jobs on a running Dask cluster (tcp://host:8786); its workers need minirt and the renderers. "
        + CLUSTER_TRUST,
    ),
]  # fmt: skip


def _cache_opt(help_: str) -> Any:
    """``--cache DIR`` (results kept by content hash), what is kept and what the hash covers said by each command."""
    return Annotated[Path | None, typer.Option("--cache", metavar="DIR", help=help_)]


CacheOpt = _cache_opt(
    "Keep each (scene, oracle) check's result in DIR by content hash (scene text, size, oracle, versions); a rerun "
    "checks only what changed. " + CACHE_TRUST
)
GradeCacheOpt = _cache_opt(
    "With --class: keep each image's grade in DIR by content hash (image bytes, scene, rules, versions); a rerun "
    "grades only new or changed images. " + CACHE_TRUST
)
SweepCacheOpt = _cache_opt(
    "Keep each backend's series in DIR by content hash (scene text, rules, size, knobs, versions, machine); a rerun "
    "renders only what changed. " + CACHE_TRUST
)
JsonOpt = Annotated[
    str | None,
    typer.Option(
        "--json", metavar="FILE", help="Write the results as JSON to FILE (- for standard output; then nothing else)."
    ),
]


def parse_rules(items: list[str] | None) -> dict[str, Any]:
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


def load(path: Path, width=None, height=None, samples=None, profile=None, rules=None):
    """(scene with the flags' overrides, its rules)."""
    return load_plain(path, width, height, samples, profile, rules)[1:]


def load_plain(path: Path, width=None, height=None, samples=None, profile=None, rules=None):
    """(the scene as loaded, the scene with the flags' overrides, its rules): the file parsed once (a scene
    of 100,000 balls is 14 MB of TOML, ~4 s to parse)."""
    from minirt.model.bundled import find_scene, scene_and_rules
    from minirt.model.scene import load_scene

    plain = load_scene(find_scene(path))
    return plain, *scene_and_rules(plain, width, height, samples, profile, parse_rules(rules))


def parse_size(size: str | None) -> tuple[int, int] | None:
    if not size:
        return None
    try:
        w, sep, h = size.lower().partition("x")
        wh = (int(w), int(h if sep else w))  # "64" is 64x64; "10x" is a mistake, not 10x10
    except ValueError:
        raise MinirtError(f"--size {size}: expected WIDTHxHEIGHT, e.g. 128x128") from None
    from minirt.model.scene import LIMITS

    for name, v in zip(("width", "height"), wh, strict=True):  # the scene's limits, named as the user wrote them
        lo, hi = LIMITS[name]
        if not lo <= v <= hi:
            raise MinirtError(f"--size {size}: the {name} must be between {lo} and {hi}")
    return wh


def pool(workers: int | None, scheduler: str | None, default: int) -> int:
    """The worker count of a command's --workers/--scheduler pair (minirt.jobs.batch.pool)."""
    from minirt.jobs import batch as jobs

    return jobs.pool(workers, scheduler, default, "--workers and --scheduler")


def output_folder(path: Path, option: str = "--out", mode: int = 0o777) -> Path:
    """Make the output folder before any work, so a bad --out fails in a second, not after a render.
    ``mode``: a new folder's permissions (less the umask); a cache's is 0o700, this user's alone
    (minirt.jobs.cache refuses a folder others may write)."""
    try:
        path.mkdir(mode=mode, parents=True, exist_ok=True)
    except OSError as e:
        raise MinirtError(f"{option} {path}: cannot create the folder ({e.strerror or e})") from None
    if not os.access(path, os.W_OK):
        raise MinirtError(f"{option} {path}: the folder is not writable")
    return path


def output_file(path: Path | None, option: str) -> None:
    """Check an output file's path before any work -- not a folder, its folder there and writable or
    possible to make -- without making anything: a run rejected later (a bad scene, a missing image)
    leaves no empty folder behind. The file's folder is made when the file is written."""
    if path is None:
        return
    if path.is_dir():
        raise MinirtError(f"{option} {path}: is a folder, expected a file name")
    folder = path.parent
    there = folder
    while not os.path.lexists(there) and there != there.parent:  # the nearest part of the path that exists
        there = there.parent
    if not there.is_dir():
        raise MinirtError(f"{option} {folder}: cannot create the folder ({there} is not a folder)")
    if not os.access(there, os.W_OK | os.X_OK):
        what = (
            "the folder is not writable" if there == folder else f"cannot create the folder ({there} is not writable)"
        )
        raise MinirtError(f"{option} {folder}: {what}")
