"""A student's program as a backend: ``program:SPEC``, rendered scene by scene in a sandbox.

Not an established renderer but the thing under test: ``minirt grade --program`` renders a suite of scenes
through it and diagnoses the images; ``minirt render -b program:SPEC`` and ``minirt check -b program:SPEC``
take it as any backend. Its rules are its own (``supported`` is empty: it is rendered as it is, and the
rules it follows are what grading finds out).

SPEC, and the conventions bridged:

- A command line with placeholders, ``"python3 tracer.py {scene} {out}"``: minirt writes the scene to
  ``{scene}`` (TOML, minirt's scene format) and ``{scene_json}`` (the same as JSON) and reads the image the
  program writes to ``{out}.EXT`` (protocol.py: the format, the extensions, float before 8-bit). The
  command is split as a POSIX shell would (shlex) but never run by a shell; a relative path in it that
  names an existing file is taken from the folder minirt runs in. The program runs in a fresh folder of
  its own, its working folder and the only one it may write.
- A C++ source of the exercise (a name ending in .cpp, .cc or .cxx): compiled once through minirt's
  driver and course files (cpp.py), then run once per scene. ``edition`` "2014" (the default) builds the
  scene through the 2014 interface; "2013" (the problem set's, whose constructors are the student's)
  through the course's ``adapter`` (README: "A program under test"). The 2014 interface has no specular
  colour: a scene's material reaches the program as (ambient, diffuse, reflection) only -- see
  ``edition_scene``. The colours come back as the program computed them, unclamped, in float32 (the
  course's Color holds floats): no 8-bit step. It follows the 2014 edition's rules (``eth2014``), whatever
  the scene's [model] table says: its interface carries none, so a check compares it under those.
- Options, in the backend's name or from ``grade``'s flags: ``program(edition=2013,adapter=FILE,
  timeout=S,sandbox=off):SPEC``. ``timeout``: seconds a scene may take (wall clock; its CPU limit is the
  same), default ``DEFAULT_TIMEOUT``; ``minirt grade --program`` derives it from the reference's time
  (minirt.grading.program). ``sandbox=off``: run without bubblewrap (limits kept; sandbox.py).

Every failure of the program -- compile error (the compiler's message kept), crash (the signal), time-out,
no image, an empty or wrong-sized one -- is the render's ``error`` with the reason in one line; it never
raises. Bad input from the user (no such source, an unparsable SPEC, no sandbox) is a MinirtError.
"""

from __future__ import annotations

import functools
import shlex
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from minirt.errors import MinirtError
from minirt.jobs import processes
from minirt.model.backend import Backend
from minirt.model.result import RenderResult
from minirt.model.rules import Rules
from minirt.model.scene import Ball, Scene
from minirt.oracles.program import cpp, protocol, sandbox

NAME = "program"
PREFIX = "program"
SOURCE_SUFFIXES = (".cpp", ".cc", ".cxx")
EDITIONS = ("2014", "2013")
# Seconds a scene may take when nothing better is known (render, check): a NumPy or C++ tracer renders
# the bundled scenes at 256^2 in well under this; grade derives its own from the reference's time.
DEFAULT_TIMEOUT = 60.0
MEMORY = 3 << 30  # address space of one run: Python with NumPy reserves ~1 GB of it before computing anything
PROCESSES = 32  # processes and threads at once (a tracer needs one; a few for its interpreter's helpers)


@dataclass(frozen=True)
class ProgramSpec:
    """What ``program:SPEC`` names, parsed: a command line or a C++ source, and its options."""

    text: str
    kind: str  # "command" | "cpp"
    argv: tuple[str, ...] = ()
    source: Path | None = None
    edition: str = "2014"
    adapter: Path | None = None
    timeout: float | None = None
    sandbox: bool = True
    visible: tuple[Path, ...] = field(default=())

    def describe(self) -> dict[str, Any]:
        return {
            "spec": self.text,
            "kind": self.kind,
            "edition": self.edition if self.kind == "cpp" else None,
            "adapter": str(self.adapter) if self.adapter else None,
            "sandbox": self.sandbox,
        }


def is_program(name: str) -> bool:
    return name.startswith(PREFIX + ":") or name.startswith(PREFIX + "(")


def parse_name(name: str) -> ProgramSpec:
    """``program:SPEC`` or ``program(k=v,...):SPEC`` (MinirtError for a bad one)."""
    rest = name[len(PREFIX) :]
    opts: dict[str, str] = {}
    if rest.startswith("("):
        close = rest.find("):")
        if close < 0:
            raise MinirtError(f"--backend {name!r}: write program(key=value,...):SPEC")
        for item in filter(None, (s.strip() for s in rest[1:close].split(","))):
            k, eq, v = item.partition("=")
            if not eq:
                raise MinirtError(f"--backend {name!r}: option {item!r} is not key=value")
            opts[k.strip()] = v.strip()
        rest = rest[close + 1 :]
    if not rest.startswith(":") or not rest[1:].strip():
        raise MinirtError(f"--backend {name!r}: give the program after 'program:'")
    unknown = sorted(set(opts) - {"edition", "adapter", "timeout", "sandbox"})
    if unknown:
        raise MinirtError(
            f"--backend {name!r}: unknown option {', '.join(unknown)} (edition, adapter, timeout, sandbox)"
        )
    timeout = _timeout(opts["timeout"]) if "timeout" in opts else None
    sandbox_on = opts.get("sandbox", "on") not in ("off", "no", "false", "0")
    adapter = Path(opts["adapter"]) if opts.get("adapter") else None
    return make_spec(rest[1:].strip(), opts.get("edition"), adapter, timeout, sandbox_on)


def _timeout(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        v = -1.0
    if not 0 < v < 1e6:
        raise MinirtError(f"timeout {text!r}: give seconds, a number > 0")
    return v


def default_edition(edition: str | None, adapter: Path | None) -> str:
    """The edition a C++ source is built for: the one given, else 2013 with an adapter (its interface needs
    one), else 2014."""
    return edition or ("2013" if adapter else "2014")


def make_spec(
    text: str,
    edition: str | None = None,
    adapter: Path | None = None,
    timeout: float | None = None,
    sandbox_on: bool = True,
) -> ProgramSpec:
    """The program ``text`` names (MinirtError for bad input): a C++ source when it is one existing file
    with a C++ suffix, else a command line with ``{out}`` and ``{scene}`` or ``{scene_json}``."""
    if edition is not None and edition not in EDITIONS:
        raise MinirtError(f"--edition {edition}: one of {', '.join(EDITIONS)}")
    if Path(text).suffix.lower() in SOURCE_SUFFIXES and " " not in text.strip():
        source = Path(text)
        if not source.is_file():
            raise MinirtError(f"--program {text}: no such file")
        ed = default_edition(edition, adapter)
        if ed == "2013" and adapter is None:
            raise MinirtError(
                "--edition 2013: its classes' constructors are the student's; give the course's --adapter FILE"
            )
        if ed == "2014" and adapter is not None:
            raise MinirtError("--adapter goes with the 2013 edition (the 2014 interface needs none)")
        if adapter is not None and not adapter.is_file():
            raise MinirtError(f"--adapter {adapter}: no such file")
        return ProgramSpec(text, "cpp", source=source, edition=ed, adapter=adapter, timeout=timeout, sandbox=sandbox_on)
    if edition is not None or adapter is not None:
        raise MinirtError(f"--edition and --adapter go with a C++ source (*.cpp), not a command line: {text!r}")
    try:
        argv = shlex.split(text)
    except ValueError as e:
        raise MinirtError(f"--program {text!r}: {e}") from None
    joined = " ".join(argv)
    if not argv or "{out}" not in joined or ("{scene}" not in joined and "{scene_json}" not in joined):
        raise MinirtError(
            f"--program {text!r}: a command needs {{scene}} (or {{scene_json}}) and {{out}}, e.g. "
            "'python3 tracer.py {scene} {out}' (or give a C++ source, raytracer.cpp)"
        )
    argv, visible = _absolute(argv)
    return ProgramSpec(text, "command", argv=tuple(argv), timeout=timeout, sandbox=sandbox_on, visible=tuple(visible))


def _absolute(argv: list[str]) -> tuple[list[str], list[Path]]:
    """The command with relative paths to existing files made absolute (the program runs in a folder of its
    own), and the folders the sandbox must show: each named file's folder, the executable's installation
    (the parent of its bin/ folder: a virtual environment's packages), the working folder."""
    out, visible = [], {Path.cwd()}
    for k, a in enumerate(argv):
        p = Path(a)
        if "{" not in a and (p.exists() or (k == 0 and shutil.which(a))):
            full = Path(shutil.which(a) or a) if k == 0 and not p.exists() else p
            full = full.absolute()
            if k > 0 or p.exists():
                a = str(full)
            # the named file and the file it resolves to (a virtual environment's python is a link to the
            # interpreter installed elsewhere, whose standard library is beside its bin/)
            for f in dict.fromkeys((full, full.resolve())):
                visible.add(f.parent)
                if f.parent.name == "bin":
                    visible.add(f.parent.parent)
        out.append(a)
    return out, sorted(visible)


@dataclass
class Run:
    """One scene through the program: the image (``pixels``, ``is_float``) or ``error``, and what it cost."""

    pixels: np.ndarray | None
    is_float: bool
    error: str
    seconds: float
    cpu_seconds: float = 0.0
    image_name: str = ""
    stderr: str = ""


def edition_scene(scene: Scene, edition: str | None) -> Scene:
    """The scene as the edition's interface can express it. The 2014 ``Shape`` takes ambient, diffuse and
    reflection colours and no specular one: each material's specular colour is replaced by its reflection
    colour, the only colour a 2014 program has to weight a highlight with (minirt's own 2014 solution
    does). A program that weights it otherwise differs from the model in the highlights, and grading says
    so. A plane is handed over with its normal of unit length (``written`` = 1): the course's own test
    scenes show that its ``Shape`` reads a plane's distance along the normal made of unit length (it drew
    (0.1, 0.9, -0.1), -5 five from the origin), where a scene here reads n·p = d with n as written -- with a
    unit normal both read the same plane. The scene's digest says it is the edition's (renders are cached
    by digest). Other editions: the scene as it is."""
    if edition != "2014":
        return scene
    from dataclasses import replace

    def fix(s):
        s = replace(s, material=replace(s.material, specular=s.material.reflection))
        return s if isinstance(s, Ball) else replace(s, written=1.0)

    return replace(scene, shapes=tuple(fix(s) for s in scene.shapes), digest=f"{scene.digest}+2014")


class ProgramOracle(Backend):
    name: ClassVar[str] = NAME
    display_name: ClassVar[str] = "the program"
    shades: ClassVar[bool] = True
    shading_model: ClassVar[str | None] = "exercise"
    concurrent: ClassVar[bool] = True  # its work is in processes of its own
    # Rendered as it is: a check compares it with the scene's own rules, bug rules included (what grading
    # names is what it follows).
    follows_bugs: ClassVar[bool] = True

    def __init__(self, spec: ProgramSpec | str) -> None:
        self.spec = parse_name(spec) if isinstance(spec, str) else spec
        self._build: cpp.Build | None = None

    def available(self) -> tuple[bool, str]:
        if self.spec.sandbox:
            ok, why = sandbox.available()
            if not ok:
                return False, f"{why}; untrusted code is not run unprotected (--no-sandbox to run it anyway)"
        return True, ""

    def version(self) -> str:
        return f"program {self.spec.text}"

    def options(self, precision: str = "f64", samples: int | None = None, timeout: float | None = None) -> dict:
        return {"timeout": timeout} if timeout else {}

    def runs_apart(self, options: dict[str, Any]) -> bool:
        """Started ahead in a check, except for the reference's own samples (``samples``), which it cannot
        shoot: a check compares its one image alone (minirt.harness.image_only)."""
        return "samples" not in options

    def adapt(self, rules: Rules) -> Rules:
        """The rules it follows: a C++ source of the 2014 edition the edition's (``eth2014``: its interface
        passes no rule settings, so the scene's [model] table cannot reach it), as ``grade --program``
        grades it; a command reads the scene file's rules, bug rules included."""
        if self.spec.kind == "cpp" and self.spec.edition == "2014":
            from minirt.model.rules import PROFILES

            return PROFILES["eth2014"]
        return rules

    def scene_as_rendered(self, scene: Scene) -> Scene:
        """The scene as the program receives it (``edition_scene``): what its image is graded against."""
        return edition_scene(scene, self.spec.edition if self.spec.kind == "cpp" else None)

    def require_sandbox(self) -> None:
        ok, why = self.available()
        if not ok:
            raise MinirtError(why)

    def build(self) -> cpp.Build | None:
        """The compiled program (C++ sources; compiled on first use, then cached); None for a command."""
        if self.spec.kind != "cpp":
            return None
        if self._build is None:
            self.require_sandbox()
            with processes.temporary_folder("minirt-build-") as work:
                self._build = cpp.build(self.spec.source, self.spec.edition, self.spec.adapter, self.spec.sandbox, work)
        return self._build

    def limits(self, scene: Scene, timeout: float | None) -> sandbox.Limits:
        seconds = timeout or self.spec.timeout or DEFAULT_TIMEOUT
        w, h = scene.camera.width, scene.camera.height
        # the largest image it may write: 4 float32 channels a pixel and a header, 16x over; at least 64 MB
        size = max(64 << 20, 16 * (16 * w * h + 4096))
        return sandbox.Limits(wall=seconds, cpu=seconds, memory=MEMORY, file_size=size, processes=PROCESSES)

    def run_scene(self, scene: Scene, timeout: float | None = None, nonfinite: bool = False) -> Run:
        """``scene`` rendered by the program (its failures in ``Run.error``; bad input raises). ``nonfinite``:
        a float image's NaN and infinite values are kept (else such an image is an error)."""
        self.require_sandbox()
        b = self.build()
        if b is not None and b.binary is None:
            return Run(None, False, "the program does not compile: " + _first_error(b.message), 0.0)
        scene = self.scene_as_rendered(scene)
        limits = self.limits(scene, timeout)
        with processes.temporary_folder("minirt-program-") as tmp:
            folder = tmp / "run"
            folder.mkdir()
            if b is not None:
                shutil.copyfile(b.binary, folder / "program")
                (folder / "program").chmod(0o755)
                (folder / "scene.dat").write_text(cpp.scene_data(scene), encoding="utf-8")
                argv = ["./program", "scene.dat", "image.pfm"]
            else:
                paths = {**protocol.write_scene(scene, folder), "out": folder / "image"}
                argv = [_fill(a, paths) for a in self.spec.argv]
            sandbox.share_with_sandbox(folder)
            t0 = time.perf_counter()
            outcome = sandbox.run(argv, folder, limits, self.spec.sandbox, list(self.spec.visible))
            seconds = time.perf_counter() - t0
            if not outcome.ok:
                return Run(
                    None,
                    False,
                    outcome.reason("the program", limits),
                    seconds,
                    outcome.cpu_seconds,
                    stderr=outcome.stderr,
                )
            try:
                w, h = scene.camera.width, scene.camera.height
                pixels, is_float, name = protocol.read_output(folder / "image", w, h, nonfinite)
            except MinirtError as e:
                return Run(None, False, str(e), seconds, outcome.cpu_seconds, stderr=outcome.stderr)
        return Run(pixels, is_float, "", seconds, outcome.cpu_seconds, name, outcome.stderr)

    def render(self, scene: Scene, rules: Rules, options: dict[str, Any] | None = None) -> RenderResult:
        options = options or {}
        w, h = scene.camera.width, scene.camera.height
        run = self.run_scene(scene, options.get("timeout"))
        meta = {"backend": NAME, "version": self.version(), "program": self.spec.describe(),
                "timings": {"program": run.seconds}}  # fmt: skip
        if self._build is not None:
            meta["compile"] = self._build.as_dict()
        if run.error:  # (failed() sets the backend itself)
            return RenderResult.failed(
                NAME, w, h, "error", run.error, **{k: v for k, v in meta.items() if k != "backend"}
            )
        meta["image"] = run.image_name
        if run.is_float:
            color = run.pixels.astype(np.float64)
            return RenderResult(NAME, w, h, color=color, meta=meta)
        levels = run.pixels
        return RenderResult(NAME, w, h, color=levels.astype(np.float64) / 255.0, image8=levels, meta=meta)


def _fill(arg: str, paths: dict[str, Path]) -> str:
    for key, p in paths.items():
        arg = arg.replace("{" + key + "}", str(p))
    return arg


def _first_error(message: str) -> str:
    for line in message.splitlines():
        if "error" in line:
            return line.strip()[:300]
    lines = [ln.strip() for ln in message.splitlines() if ln.strip()]
    return lines[0][:300] if lines else "(no message)"


@functools.cache
def backend(name: str) -> ProgramOracle:
    """The program backend ``name`` names (``program:SPEC``), one per name."""
    return ProgramOracle(name)


__all__ = [
    "ProgramOracle", "ProgramSpec", "Run", "backend", "default_edition", "is_program", "make_spec", "parse_name",
]  # fmt: skip
