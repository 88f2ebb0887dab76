"""A student's C++ source, compiled once through minirt's driver and run once per scene.

The course-side files come from minirt (course/): bitmap.h and vector3.h (with bitmap.cpp and vector3.cpp
that include them) and scene_io.h, minirt's reader of the scene's data file and writer of the float image.
The driver (course/driver2014.cpp, or driver2013.cpp with the course's adapter) ``#include``s the student's
file as raytracer.cpp -- its own ``main``, if any, renamed away -- reads the scene from the file named by
its first argument and writes the colours, unclamped, as a PFM to its second. So one compile serves every
scene. Files beside the source (its own headers: .h, .hpp, .cpp, .cc, .inl) are copied with it; the
course's names are minirt's.

Compiles are cached in the user's cache folder (``$MINIRT_PROGRAM_CACHE``, else ``$XDG_CACHE_HOME/minirt/
programs``, else ``~/.cache/minirt/programs``), one folder per key: the SHA-256 of the source and its
neighbours, the adapter, the edition, ``DRIVER_VERSION`` and the compiler's version line. A failed compile
is cached too (the same source fails the same way), with the compiler's message.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from minirt.errors import MinirtError
from minirt.jobs.cache import trusted_folder
from minirt.model.scene import Ball, Scene
from minirt.oracles.program import sandbox

DRIVER_VERSION = 2  # raised whenever a course file or driver changes what a compiled program does
COURSE_FILES = ("bitmap.h", "bitmap.cpp", "vector3.h", "vector3.cpp", "scene_io.h")
NEIGHBOUR_SUFFIXES = (".h", ".hpp", ".hh", ".cpp", ".cc", ".cxx", ".inl")
NEIGHBOURS_MAX = 64  # files beside the source copied with it ...
NEIGHBOUR_BYTES = 1 << 20  # ... each at most this long
COMPILER = ("g++", "-std=c++17", "-O2", "-w", "-o", "program", "driver.cpp")
# A compile may take 2 minutes and 4 GB (template-heavy code needs ~1 GB; g++ is several processes).
COMPILE_LIMITS = sandbox.Limits(wall=120.0, cpu=120.0, memory=4 << 30, file_size=256 << 20, processes=64)
MESSAGE_CHARS = 4000  # of the compiler's output kept for the page


@dataclass
class Build:
    """A compiled program: ``binary`` (None when the compile failed), ``message`` the compiler's output
    (its errors), ``key`` the cache key, ``cached`` whether it came from the cache."""

    key: str
    binary: Path | None
    message: str
    cached: bool

    def as_dict(self) -> dict:
        return {"ok": self.binary is not None, "key": self.key, "message": self.message}


def cache_folder() -> Path:
    env = os.environ.get("MINIRT_PROGRAM_CACHE")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "minirt" / "programs"


def _course(name: str) -> bytes:
    return resources.files("minirt.oracles.program").joinpath("course", name).read_bytes()


def _neighbours(source: Path) -> list[Path]:
    out = []
    for p in sorted(source.parent.iterdir()):
        if p == source or p.name in COURSE_FILES or p.suffix.lower() not in NEIGHBOUR_SUFFIXES:
            continue
        if p.is_symlink() or not p.is_file() or p.stat().st_size > NEIGHBOUR_BYTES:
            continue
        out.append(p)
    return out[:NEIGHBOURS_MAX]


def compiler_version() -> str:
    try:
        p = subprocess.run(["g++", "--version"], capture_output=True, text=True, timeout=30, check=False)
    except (OSError, subprocess.TimeoutExpired):
        return ""
    return (p.stdout.splitlines() or [""])[0]


def _inputs(source: Path, edition: str, adapter: Path | None) -> dict[str, bytes]:
    """Every file the compile reads, by its name in the build folder."""
    files = {p.name: p.read_bytes() for p in _neighbours(source)}
    files.update({name: _course(name) for name in COURSE_FILES})
    files["raytracer.cpp"] = source.read_bytes()
    files["driver.cpp"] = _course("driver2014.cpp" if edition == "2014" else "driver2013.cpp")
    if adapter is not None:
        files["adapter.cpp"] = adapter.read_bytes()
    return files


def build(source: Path, edition: str, adapter: Path | None, use_sandbox: bool, work: Path) -> Build:
    """The program compiled from ``source`` (from the cache when it was compiled before). ``work``: a folder
    the compile may use. Raises MinirtError for bad input (no such file, no g++)."""
    for p, label in ((source, "the program's source"), (adapter, "--adapter")):
        if p is not None and not p.is_file():
            raise MinirtError(f"{label} {p}: no such file")
    if shutil.which("g++") is None:
        raise MinirtError("compiling a C++ program needs g++ (Debian: apt-get install g++)")
    files = _inputs(source, edition, adapter)
    h = hashlib.sha256(f"driver {DRIVER_VERSION} edition {edition} {compiler_version()}\n".encode())
    for name in sorted(files):
        h.update(f"{name} {len(files[name])}\n".encode())
        h.update(files[name])
    key = h.hexdigest()
    root = cache_folder()
    trusted_folder(root, "the program cache")
    entry = root / key
    done = _cached(entry, key)
    if done is not None:
        return done
    folder = work / "build"
    folder.mkdir()
    for name, data in files.items():
        (folder / name).write_bytes(data)
    sandbox.share_with_sandbox(folder)
    outcome = sandbox.run(list(COMPILER), folder, COMPILE_LIMITS, use_sandbox)
    message = (outcome.stderr + outcome.stdout)[-MESSAGE_CHARS:]
    ok = outcome.ok and (folder / "program").is_file()
    if not ok and not message.strip():
        message = outcome.reason("the compiler", COMPILE_LIMITS)
    _store(root, entry, key, folder / "program" if ok else None, message)
    return Build(key, entry / "program" if ok else None, message, cached=False)


def _cached(entry: Path, key: str) -> Build | None:
    try:
        info = json.loads((entry / "compile.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    binary = entry / "program"
    if info.get("key") != key or (info.get("ok") and not binary.is_file()):
        return None
    return Build(key, binary if info.get("ok") else None, str(info.get("message", "")), cached=True)


def _store(root: Path, entry: Path, key: str, binary: Path | None, message: str) -> None:
    root.mkdir(parents=True, exist_ok=True, mode=0o700)
    tmp = root / f".{key}.{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(mode=0o700)
    if binary is not None:
        shutil.copyfile(binary, tmp / "program")
        (tmp / "program").chmod(0o755)
    info = {"key": key, "ok": binary is not None, "message": message}
    (tmp / "compile.json").write_text(json.dumps(info, indent=1) + "\n", encoding="utf-8")
    try:
        tmp.rename(entry)
    except OSError:  # another process stored the same key first: its entry is the same compile
        shutil.rmtree(tmp, ignore_errors=True)


def _f(v: float) -> str:
    return repr(float(v))


def scene_data(scene: Scene) -> str:
    """The scene as the driver reads it (course/scene_io.h)."""
    cam = scene.camera
    lines = [
        "minirt-scene 1",
        f"{cam.width} {cam.height} {scene.max_depth}",
        " ".join(_f(v) for v in cam.position),
        " ".join(_f(v) for v in (*scene.light.position, *scene.light.color)),
        " ".join(_f(v) for v in scene.background),
        str(len(scene.shapes)),
    ]
    for s in scene.shapes:
        m = s.material
        if isinstance(s, Ball):
            head = f"0 {' '.join(_f(v) for v in s.center)} {_f(s.radius)}"
        else:
            w = s.written
            head = f"1 {' '.join(_f(v * w) for v in s.normal)} {_f(s.distance * w)}"
        colours = " ".join(_f(v) for c in (m.ambient, m.diffuse, m.specular, m.reflection) for v in c)
        lines.append(f"{head} {colours}")
    return "\n".join(lines) + "\n"
