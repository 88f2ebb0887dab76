"""The command line's common surface: --version, usage errors as one `minirt: error:` line (exit 2),
--json - on standard output with nothing else there, render --quiet."""

from __future__ import annotations

import importlib.metadata as md
import json
import subprocess
import sys
from pathlib import Path

import pytest
from support.inproc import minirt

ROOT = Path(__file__).resolve().parents[2]
MINIRT = [sys.executable, "-m", "minirt"]


def run(*args, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    """In this process (tests/support/inproc.py): the command's exit status and what it writes to both streams."""
    return minirt(*args, cwd=cwd)


def run_child(*args, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    """In a child process: all it writes, also what a library writes to the file descriptors directly."""
    return subprocess.run([*MINIRT, *map(str, args)], cwd=cwd, capture_output=True, text=True, timeout=300)


def test_version():
    p = run("--version")
    assert p.returncode == 0, p.stderr
    lines = p.stdout.splitlines()
    assert lines[0] == f"minirt {md.version('minirt')}"
    assert lines[1] == f"drjit {md.version('drjit')}, mitsuba {md.version('mitsuba')}"


USAGE = {
    "missing argument": (["render"], "Missing argument 'SCENE'.", "render"),
    "out of range": (["render", "x.toml", "--width", "0"], "Invalid value for '--width'", "render"),
    "unknown option": (["check", "--bakend", "x"], "No such option: --bakend", "check"),
    "unknown command": (["rendr"], "No such command 'rendr'", None),
    "bad choice": (["render", "x.toml", "--precision", "f16"], "Invalid value for '--precision'", "render"),
    "missing option": (["export", "x.toml"], "Missing option '--to'", "export"),
    "markup in the text": (["render", "x.toml", "--[red]x"], "No such option: --[red]x", "render"),
}


@pytest.mark.parametrize("case", list(USAGE))
def test_usage_errors_are_one_line_and_exit_2(case):
    args, message, command = USAGE[case]
    p = run(*args)
    assert p.returncode == 2, p.stderr
    assert p.stdout == ""
    lines = p.stderr.splitlines()
    assert len(lines) == 2, p.stderr
    assert lines[0].startswith("minirt: error: ") and message in lines[0], lines[0]
    assert lines[1] == ("try: minirt --help" if command is None else f"try: minirt {command} --help")
    assert "Usage:" not in p.stderr and "Traceback" not in p.stderr


def test_help_is_still_help():
    p = run("render", "--help")
    assert p.returncode == 0 and "Usage:" in p.stdout and "--quiet" in p.stdout


def test_check_json_dash_is_stdout_and_nothing_else(tmp_path):
    p = subprocess.run(
        [*MINIRT, "check", str(ROOT / "scenes/exercise.toml"), "-b", "embree", "--size", "12x8", "--json", "-", "-q"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert p.returncode == 0, p.stderr
    data = json.loads(p.stdout)  # the whole of stdout is the document
    assert data["schema_version"] == 1 and data["verdict"] == "pass"
    assert "PASS: 1 pass" in p.stderr  # the summary moved to stderr
    assert list(tmp_path.iterdir()) == []  # no file named "-"


def test_render_quiet(tmp_path):
    args = ["render", "scenes/exercise.toml", "--width", "8", "--height", "6"]
    loud = run_child(*args, "-o", tmp_path / "a")
    quiet = run_child(*args, "-o", tmp_path / "b", "--quiet")
    assert loud.returncode == quiet.returncode == 0, quiet.stderr
    assert "reference" in loud.stderr and "exercise" in loud.stderr
    assert quiet.stderr == ""
    assert quiet.stdout == f"wrote {tmp_path / 'b'}/\n"
    assert sorted(f.name for f in (tmp_path / "b").iterdir()) == sorted(f.name for f in (tmp_path / "a").iterdir())
