"""Hostile scene text: a scene file never chooses where files go or what the terminal shows.

Every hostile name below is rendered through the real command line; the outputs must land inside --out
under a safe name, the terminal must receive no control byte and no markup effect, and every input gets
exit 0 or a one-line exit 2 -- never a traceback.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from support.inproc import minirt

from minirt.io.untrusted import MAX_STEM, file_stem, printable, terminal_text

ROOT = Path(__file__).resolve().parents[2]
SCENE = (ROOT / "scenes" / "three_balls.toml").read_text()

HOSTILE = [
    "../../escaped",
    "/tmp/absolute",
    "a/b/c",
    "..",
    ".",
    "",
    "x[/]",
    "[link=file:///etc/passwd]click[/link]",
    "[bold red]loud",
    "\x1b]0;retitled\x07",
    "\x1b[2J\x1b[Hcleared",
    "bell\x07",
    "cr\rover",
    "nul\x00byte",
    "\u202eevil\u202c",
    "zero\u200bwidth",
    ":smile:",
    "$\\frac{1}{0}$",
    "-rf",
    "x" * 5000,
]


def _toml_string(s: str) -> str:
    return json.dumps(s)  # a JSON string with \\uXXXX escapes is a valid TOML basic string


def _run(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    """In this process (tests/support/inproc.py): the command's own exit status, stdout and stderr."""
    return minirt(*args, cwd=cwd)


def _run_child(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    """In a child process with a time-out, for a command that could block."""
    return subprocess.run(
        [sys.executable, "-m", "minirt", *args], cwd=cwd, capture_output=True, text=True, timeout=120,
        env={**os.environ, "COLUMNS": "200"},
    )  # fmt: skip


def _no_terminal_effects(text: str) -> None:
    assert "\x1b" not in text and "\x07" not in text and "\x00" not in text and "\r" not in text
    assert "\u202e" not in text and "\u200b" not in text


@pytest.mark.parametrize("name", HOSTILE, ids=range(len(HOSTILE)))
def test_file_stem_is_a_plain_name(name):
    stem = file_stem(name)
    assert stem and len(stem) <= MAX_STEM
    assert "/" not in stem and "\\" not in stem and "\x00" not in stem
    assert not stem.startswith((".", "-")) and ".." not in stem
    assert stem == file_stem(name)  # deterministic


def test_long_names_stay_apart():
    assert file_stem("a" * 300 + "1") != file_stem("a" * 300 + "2")


@pytest.mark.parametrize("name", HOSTILE, ids=range(len(HOSTILE)))
def test_terminal_text_is_inert(name):
    from rich.console import Console

    c = Console(record=True, width=10000, force_terminal=False, emoji=False, highlight=False)
    c.print(f"[bold]{terminal_text(name)}[/]")  # raises MarkupError if the markup leaked
    shown = c.export_text()
    _no_terminal_effects(shown)
    assert "[link=" not in name or "[link=" in shown  # the markup is printed, not obeyed


def test_printable_shows_the_bytes():
    assert printable("a\x1bb") == "a\\x1bb"
    assert printable("\u202e") == "\\u202e"
    assert printable(b"\xff".decode("utf-8", "surrogateescape")) == "\\xff"
    assert printable("x" * 10, limit=4) == "xxxx... (6 more characters)"


@pytest.mark.parametrize("name", HOSTILE, ids=range(len(HOSTILE)))
def test_render_with_a_hostile_name(tmp_path, name):
    scene = SCENE.replace('name = "three_balls"', f"name = {_toml_string(name)}")
    assert scene != SCENE
    (tmp_path / "work").mkdir()
    f = tmp_path / "work" / "hostile.toml"
    f.write_text(scene)
    p = _run("render", str(f), "--out", "out", "--width", "8", "--height", "8", cwd=tmp_path / "work")
    assert p.returncode == 0, p.stderr
    assert "Traceback" not in p.stderr
    _no_terminal_effects(p.stdout + p.stderr)
    written = sorted(q.relative_to(tmp_path) for q in tmp_path.rglob("*") if q.is_file())
    outside = [q for q in written if q.parts[:2] != ("work", "out") and q != Path("work/hostile.toml")]
    assert outside == []
    out = tmp_path / "work" / "out"
    names = sorted(q.name for q in out.iterdir())
    assert all(q.is_file() for q in out.iterdir())  # no folders made from a '/'
    assert len(names) == 3 and not any(n.startswith(".") for n in names)  # no temporary file left
    stem = file_stem(name, "hostile")
    assert names == sorted(f"{stem}.reference.{ext}" for ext in ("exr", "json", "png"))


@pytest.mark.parametrize(
    "text, message",
    [
        ("a = " + "[" * 5000 + "]" * 5000, "nested too deeply"),
        ("a = " + "{b = " * 3000 + "1" + "}" * 3000, "nested too deeply"),
    ],
    ids=["arrays", "inline-tables"],
)
def test_deep_nesting_is_one_line(tmp_path, text, message):
    f = tmp_path / "deep.toml"
    f.write_text(text)
    p = _run("render", str(f), cwd=tmp_path)
    assert p.returncode == 2
    assert p.stderr.count("\n") == 1 and message in p.stderr and "Traceback" not in p.stderr


def test_a_fifo_is_not_a_scene(tmp_path):
    fifo = tmp_path / "scene.toml"
    os.mkfifo(fifo)
    p = _run_child("render", str(fifo), cwd=tmp_path)  # would block for ever on open()
    assert p.returncode == 2 and "not a regular file" in p.stderr


def test_a_hostile_key_is_printed_as_text(tmp_path):
    f = tmp_path / "k.toml"
    f.write_text(SCENE + '\n["x[/]\\u001b[2J"]\nv = 1\n')
    p = _run("render", str(f), cwd=tmp_path)
    assert p.returncode == 2 and "MarkupError" not in p.stderr and "Traceback" not in p.stderr
    _no_terminal_effects(p.stderr)


def test_size_needs_both_numbers():
    from minirt.cli.options import parse_size
    from minirt.errors import MinirtError

    assert parse_size("64") == (64, 64)
    assert parse_size("10x20") == (10, 20)
    with pytest.raises(MinirtError):
        parse_size("10x")
