"""What the tests of a student's program share: minirt run as a user runs it, a module's own build cache
for the C++ sources it compiles, and the grading scenes at a test's size."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from minirt.model.bundled import find_scene
from minirt.model.rules import Rules, resolve
from minirt.model.scene import load_scene


def bare_env(cwd: Path) -> dict[str, str]:
    """A bare environment for minirt run as a user runs it: PATH, the build cache in ``cwd/programs``, and
    Dr.Jit's kernel cache -- this process's. Without HOME, Dr.Jit would keep no kernel cache and compile
    every kernel again in every command (a grade over one scene at 48^2: 7.7 CPU-s instead of 2.9)."""
    env = {"MINIRT_PROGRAM_CACHE": str(cwd / "programs"), "PATH": "/usr/bin:/bin"}
    home = os.environ.get("HOME")
    kernels = os.environ.get("DRJIT_CACHE_DIR") or (home and os.path.join(home, ".drjit"))  # Dr.Jit's default
    if kernels:
        env["DRJIT_CACHE_DIR"] = kernels
    return env


def minirt(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    """``python -m minirt ARGS`` in ``cwd``, with a bare environment (``bare_env``)."""
    return subprocess.run([sys.executable, "-m", "minirt", *args], capture_output=True, text=True, cwd=cwd,
                          env=bare_env(cwd), timeout=600)  # fmt: skip


@pytest.fixture(scope="module", autouse=True)
def program_cache(tmp_path_factory):
    """The module's C++ builds in a folder of its own (imported by a test module, it applies to its tests)."""
    mp = pytest.MonkeyPatch()
    mp.setenv("MINIRT_PROGRAM_CACHE", str(tmp_path_factory.mktemp("programs")))
    yield
    mp.undo()


def grading_suite(stems: tuple[str, ...], size: int, rules: Rules | None = None) -> list[tuple[str, object, Rules]]:
    """(file, scene, rules) of the bundled scenes ``stems`` at size x size, one sample a pixel, each with its
    own rules unless ``rules``: what ``grade_program`` takes."""
    out = []
    for stem in stems:
        path = find_scene(stem)
        scene = load_scene(path).with_overrides(width=size, height=size, samples=1)
        out.append((str(path), scene, rules or resolve(scene)))
    return out
