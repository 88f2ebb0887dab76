"""Student code is hostile until proven otherwise: each program here attacks the machine or hangs, and
each must be contained -- its scene an ``error`` with the reason, the machine and minirt unharmed, the
time bounded by the scene's limit. Limits are small so the tests are fast."""

from __future__ import annotations

import socket
import sys
import time
from pathlib import Path

import pytest

from minirt.errors import MinirtError
from minirt.model.bundled import find_scene
from minirt.model.scene import load_scene
from minirt.oracles.program import ProgramOracle, make_spec, parse_name
from minirt.oracles.program import sandbox as sb

SCENE = load_scene(find_scene("rules")).with_overrides(width=16, height=16, samples=1)
TIMEOUT = 4.0  # seconds a hostile scene may take: each below ends far sooner, or is killed at this


@pytest.fixture(autouse=True)
def program_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("MINIRT_PROGRAM_CACHE", str(tmp_path / "programs"))


def python_program(tmp_path: Path, body: str) -> ProgramOracle:
    path = tmp_path / "student.py"
    path.write_text("import sys\nscene, out = sys.argv[1], sys.argv[2]\n" + body)
    return ProgramOracle(make_spec(f"{sys.executable} {path} {{scene}} {{out}}", timeout=TIMEOUT))


def run(oracle: ProgramOracle):
    t0 = time.perf_counter()
    r = oracle.run_scene(SCENE)
    return r, time.perf_counter() - t0


def test_the_sandbox_is_available_here():
    # the project's set-up installs bubblewrap (Makefile APT_PACKAGES): a machine without it is not set up
    assert sb.available() == (True, "")


def test_an_endless_loop_is_killed_at_the_scene_limit(tmp_path):
    r, took = run(python_program(tmp_path, "while True:\n    pass\n"))
    assert r.pixels is None and ("did not finish" in r.error or "SIGXCPU" in r.error or "SIGKILL" in r.error)
    assert took < TIMEOUT + 5


def test_a_fork_bomb_is_held(tmp_path):
    body = (
        "import os, time\n"
        "n = 0\n"
        "try:\n"
        "    while True:\n"
        "        if os.fork() == 0:\n"
        "            time.sleep(30)\n"
        "            os._exit(0)\n"
        "        n += 1\n"
        "except OSError as e:\n"
        "    sys.exit(f'fork failed after {n}: {e}')\n"
    )
    r, took = run(python_program(tmp_path, body))
    assert r.pixels is None
    assert "fork failed after" in r.error  # the process limit held it, not the clock
    assert int(r.error.split("fork failed after ")[1].split(":")[0]) < 64
    assert took < TIMEOUT + 5  # and its children died with the sandbox


def test_a_50_gb_allocation_fails(tmp_path):
    r, _ = run(python_program(tmp_path, "x = bytearray(50 * 2**30)\n"))
    assert r.pixels is None and "MemoryError" in r.error


def test_writing_outside_its_folder_fails(tmp_path):
    outside = tmp_path / "outside.txt"
    r, _ = run(python_program(tmp_path, f"open({str(outside)!r}, 'w').write('x')\n"))
    assert r.pixels is None and ("Read-only file system" in r.error or "Permission denied" in r.error)
    assert not outside.exists()


def test_opening_a_socket_finds_no_network(tmp_path):
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen(1)
        port = server.getsockname()[1]
        body = f"import socket\nsocket.create_connection(('127.0.0.1', {port}), timeout=2)\n"
        r, _ = run(python_program(tmp_path, body))
    assert r.pixels is None and ("Connection refused" in r.error or "unreachable" in r.error)


def test_printing_a_gigabyte_meets_the_file_size_limit(tmp_path):
    body = "chunk = 'x' * (1 << 20)\nfor _ in range(1024):\n    sys.stdout.write(chunk)\n"
    r, took = run(python_program(tmp_path, body))
    # Python ignores SIGXFSZ and reports the failed write; a C program dies of it
    assert r.pixels is None and ("SIGXFSZ" in r.error or "File too large" in r.error)
    assert took < TIMEOUT + 5


def test_no_image_and_a_wrong_sized_image_are_errors(tmp_path):
    r, _ = run(python_program(tmp_path, "pass\n"))
    assert r.error.startswith("the program wrote no image")
    body = "open(out + '.ppm', 'wb').write(b'P6\\n3 2\\n255\\n' + bytes(18))\n"
    r, _ = run(python_program(tmp_path, body))
    assert "is 3x2, the scene 16x16" in r.error
    r, _ = run(python_program(tmp_path, "open(out + '.ppm', 'wb').close()\n"))
    assert "empty" in r.error


def test_a_crash_is_reported_with_its_signal(tmp_path):
    r, _ = run(python_program(tmp_path, "import os, signal\nos.kill(os.getpid(), signal.SIGSEGV)\n"))
    assert "SIGSEGV" in r.error


CPP_HEAD = '#include "bitmap.h"\n#include "vector3.h"\n'


def cpp_program(tmp_path: Path, text: str) -> ProgramOracle:
    path = tmp_path / "raytracer.cpp"
    path.write_text(CPP_HEAD + text)
    return ProgramOracle(make_spec(str(path), timeout=TIMEOUT))


def test_a_compile_error_keeps_the_compilers_message(tmp_path):
    oracle = cpp_program(tmp_path, "int f() { return undeclared_name; }\n")
    r, _ = run(oracle)
    assert r.error.startswith("the program does not compile:") and "undeclared_name" in r.error
    assert "undeclared_name" in oracle.build().message and oracle.build().binary is None
    # the failure is cached: a second oracle of the same source does not compile again
    assert ProgramOracle(oracle.spec).build().cached


def test_a_cpp_endless_loop_in_raytrace_is_killed(tmp_path):
    text = (
        "enum ShapeType { BALL, PLANE };\n"
        "struct Shape { Shape(ShapeType, Vector, double, Color, Color, Color) {} };\n"
        "struct Scene {\n"
        "  Scene(Vector, Vector, Color, int, int) {}\n"
        "  void add_shape(const Shape&) {}\n"
        "  void raytrace(Bitmap&, int) { volatile int x = 0; while (true) { x = x + 1; } }\n"
        "};\n"
    )
    oracle = cpp_program(tmp_path, text)
    r, took = run(oracle)
    assert oracle.build().binary is not None, oracle.build().message
    assert r.pixels is None and ("did not finish" in r.error or "SIGXCPU" in r.error)
    assert took < TIMEOUT + 60  # the compile included


def test_bad_specs_are_one_line_errors(tmp_path):
    with pytest.raises(MinirtError, match="needs \\{scene\\}"):
        make_spec("python3 tracer.py")
    with pytest.raises(MinirtError, match="no such file"):
        make_spec(str(tmp_path / "missing.cpp"))
    (tmp_path / "a.cpp").write_text("")
    with pytest.raises(MinirtError, match="give the course's --adapter"):
        make_spec(str(tmp_path / "a.cpp"), edition="2013")
    with pytest.raises(MinirtError, match="unknown option"):
        parse_name("program(colour=red):x {scene} {out}")
    spec = parse_name("program(timeout=3,sandbox=off):python3 t.py {scene} {out}")
    assert (spec.timeout, spec.sandbox, spec.kind) == (3.0, False, "command")


def test_a_program_ends_the_backend_list_commas_and_all():
    from minirt.harness import backends

    name = "program:python3 a,b.py {scene} {out}"
    assert backends.parse_backends(f"reference,{name}") == ["reference", name]
    assert backends.get(name).spec.argv[1] == "a,b.py"
