"""The package as a user gets it: `python -m build` makes an sdist and, from it, a wheel (in an
isolated build environment, so the build requirements in pyproject.toml are the ones tested); the
wheel holds minirt with its oracles, the bundled scenes and the sample student image, and nothing
else at the top level; installed into a fresh venv it works from a folder outside the repository.

The fresh venv reaches minirt's dependencies (Dr.Jit, Mitsuba, ...) through a .pth line naming the
project venv's site-packages, and the wheel is installed with --no-deps: nothing is downloaded again.
A .pth line only adds a folder to sys.path (its own .pth files are not run), so the checkout's
editable install stays invisible: the minirt that runs is the wheel's.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import sysconfig
import tarfile
import tomllib
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SCENES = sorted(p.name for p in (ROOT / "scenes").glob("*.toml"))
# every scene file, the program suite's (scenes/suite/) included, as a path under scenes/
SCENE_FILES = sorted(p.relative_to(ROOT / "scenes").as_posix() for p in (ROOT / "scenes").rglob("*.toml"))
# every module of the oracles, subpackages included, as a path under oracles/ ("povray/oracle.py")
# the oracles' modules, and the course-side C++ files the program oracle hands a student's source
ORACLES = sorted(
    p.relative_to(ROOT / "oracles").as_posix()
    for p in [*(ROOT / "oracles").rglob("*.py"), *(ROOT / "oracles" / "program" / "course").glob("*")]
    if "__pycache__" not in p.parts
)


def run(*cmd: str | Path, cwd: Path, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    p = subprocess.run([str(c) for c in cmd], cwd=cwd, capture_output=True, text=True, env=env)
    assert p.returncode == 0, f"{' '.join(map(str, cmd))}: exit {p.returncode}\n{p.stdout}\n{p.stderr}"
    return p


def test_every_package_is_listed():
    """Every source folder that is a Python package is in pyproject.toml's packages list. setuptools
    would still copy an unlisted one into the wheel, as data of its parent (with a warning that it
    will stop doing so), so the wheel's contents alone do not catch a forgotten subpackage."""
    with (ROOT / "pyproject.toml").open("rb") as f:
        listed = set(tomllib.load(f)["tool"]["setuptools"]["packages"])
    folders = {"minirt": ROOT / "minirt", "minirt.oracles": ROOT / "oracles", "minirt.scene_files": ROOT / "scenes"}
    found = {
        ".".join([name, *init.parent.relative_to(folder).parts])
        for name, folder in folders.items()
        for init in folder.rglob("__init__.py")
    }
    assert found - listed == set()


@pytest.mark.slow
def test_build_install_and_run_outside_the_repository(tmp_path):
    """One test, not two: under pytest-xdist two tests could each build the package."""
    dist = tmp_path / "dist"
    run(sys.executable, "-m", "build", "--outdir", dist, ROOT, cwd=tmp_path)
    check_contents(dist)
    smoke_test_installed(dist, tmp_path)


def check_contents(dist: Path) -> None:
    (wheel,) = dist.glob("minirt-*.whl")
    (sdist,) = dist.glob("minirt-*.tar.gz")
    with zipfile.ZipFile(wheel) as z:
        names = z.namelist()
        text = z.read(next(n for n in names if n.endswith(".dist-info/entry_points.txt"))).decode()
    top = {n.split("/")[0] for n in names}
    assert len(top) == 2 and "minirt" in top and all(t == "minirt" or t.endswith(".dist-info") for t in top), top
    assert not any(n.startswith("oracles/") for n in names)
    assert {n.removeprefix("minirt/oracles/") for n in names if n.startswith("minirt/oracles/")} == set(ORACLES)
    in_wheel = [n.removeprefix("minirt/scene_files/") for n in names if n.startswith("minirt/scene_files/")]
    assert sorted(n for n in in_wheel if n.endswith(".toml")) == SCENE_FILES
    assert "minirt/scene_files/samples/rules.student.png" in names
    assert any(n.endswith(".dist-info/licenses/LICENSE") for n in names)
    assert "minirt = minirt.cli.app:main" in text and "[pytest11]" in text
    with tarfile.open(sdist) as t:
        members = {m.split("/", 1)[-1] for m in t.getnames()}
    assert {"LICENSE", "pyproject.toml", "README.md", "scenes/samples/rules.student.png"} <= members
    assert {f"oracles/{o}" for o in ORACLES} <= members


def smoke_test_installed(dist: Path, tmp_path: Path) -> None:
    (wheel,) = dist.glob("minirt-*.whl")
    venv = tmp_path / "venv"
    run(sys.executable, "-m", "venv", "--without-pip", venv, cwd=tmp_path)
    python = venv / "bin" / "python"
    purelib = "import sysconfig; print(sysconfig.get_path('purelib'))"
    site = Path(run(python, "-c", purelib, cwd=tmp_path).stdout.strip())
    (site / "project-dependencies.pth").write_text(sysconfig.get_path("purelib") + "\n")
    run(sys.executable, "-m", "pip", "--python", python, "install", "--quiet", "--no-deps", wheel, cwd=tmp_path)

    work = tmp_path / "elsewhere"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    minirt = venv / "bin" / "minirt"
    listed = run(minirt, "scenes", cwd=work, env=env).stdout.split()
    assert {s.removesuffix(".toml") for s in SCENES} <= set(listed)
    run(minirt, "render", "exercise", "--width", "16", "--height", "16", "--out", work / "out", "-q", cwd=work, env=env)
    assert (work / "out" / "exercise.reference.png").stat().st_size > 0
    run(minirt, "check", "exercise", "-b", "embree", "--size", "16x16", "-q", cwd=work, env=env)
    # above 64^2 the certified oracle's check starts worker processes of the installed package's
    # (python -m minirt.oracles.exact.worker)
    said = run(minirt, "check", "exercise", "-b", "exact", "--size", "72x72", "--json", "-", "-q", cwd=work, env=env)
    assert json.loads(said.stdout)["verdict"] == "pass"
    probe = (
        "import importlib.util, minirt\n"
        "from minirt.model.bundled import SAMPLES\n"
        "assert importlib.util.find_spec('oracles') is None, 'a top-level oracles package'\n"
        "assert (SAMPLES / 'rules.student.png').is_file()\n"
        "print(minirt.__file__)\n"
        "print(minirt.render('exercise', 'embree', width=8, height=8).hit.shape)\n"
    )
    lines = run(python, "-c", probe, cwd=work, env=env).stdout.splitlines()
    assert lines[0].startswith(str(site)), lines  # the wheel's minirt, not the checkout's
    assert lines[1] == "(8, 8)"
