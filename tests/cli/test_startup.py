"""Start-up: a command imports only what it runs. `minirt --help` and every `minirt CMD --help` are text,
so they import no renderer (Dr.Jit, Mitsuba), no job system (Dask) and none of the capabilities behind
the commands (the campaign, the harness, the reference tracer, NumPy's users): each of those costs a
tenth of a second or more at every start (benchmarks/README.md, issue 37, has the figures)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
import typer

from minirt.cli import fuzz
from minirt.cli.app import app

COMMANDS = sorted(typer.main.get_command(app).commands)

# Run in a fresh interpreter (this one has imported everything), as the console script does; print the
# modules loaded once the help is out.
CHILD = """
import json, sys
sys.argv = ["minirt", *json.loads(sys.argv[1])]
from minirt.cli.app import main
try:
    main()
except SystemExit:
    pass
print("\\nMODULES " + json.dumps(sorted(sys.modules)))
"""

# Libraries no help text needs (top-level package names).
HEAVY = {"drjit", "mitsuba", "dask", "distributed", "numpy", "scipy", "PIL", "OpenImageIO", "trimesh", "bpy"}
# The minirt modules a help text may load: the command line itself and what it prints with.
LIGHT = {"minirt", "minirt.version", "minirt.errors", "minirt.io", "minirt.io.untrusted"}


def loaded_by(*args: str) -> tuple[str, set[str]]:
    p = subprocess.run(
        [sys.executable, "-c", CHILD, json.dumps(args)], capture_output=True, text=True, timeout=120, check=False
    )
    assert "MODULES " in p.stdout, p.stderr
    text, _, mods = p.stdout.rpartition("MODULES ")
    return text, set(json.loads(mods))


@pytest.mark.parametrize("args", [("--help",), *((c, "--help") for c in COMMANDS)], ids=" ".join)
def test_help_imports_no_command_module(args):
    text, mods = loaded_by(*args)
    assert "Usage" in text  # the help was printed (not an error before it)
    heavy = sorted(m for m in mods if m.split(".")[0] in HEAVY)
    assert not heavy, f"minirt {' '.join(args)} imports {heavy}"
    core = sorted(m for m in mods if m.startswith("minirt") and not m.startswith("minirt.cli") and m not in LIGHT)
    assert not core, f"minirt {' '.join(args)} imports {core}"


def test_the_check_can_fail():
    """The child sees an import a help text should not make (here: the campaign, as the fuzz help once did)."""
    _, mods = loaded_by("--help")
    assert "minirt.campaign" not in mods
    p = subprocess.run(
        [sys.executable, "-c", "import minirt.campaign.campaign\n" + CHILD, '["--help"]'],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert "minirt.campaign" in json.loads(p.stdout.rpartition("MODULES ")[2])


def test_fuzz_help_names_every_family_and_defect():
    """The fuzz help writes the names out (importing the campaign for them cost the help 0.1 s): the same
    names, in the same order, as the campaign's."""
    from minirt.campaign.campaign import DEFECTS
    from minirt.campaign.families import FAMILIES

    assert tuple(FAMILIES) == fuzz.FAMILY_NAMES
    assert tuple(DEFECTS) == fuzz.DEFECT_NAMES
    text = fuzz.fuzz_help()
    assert ", ".join(FAMILIES) in text and ", ".join(DEFECTS) in text


def test_a_command_runs_on_normal_pages():
    """main() turns transparent huge pages off for the run (their on-the-spot compaction stalled a 1024^2
    render's first touch of each buffer by up to seconds on a VM): Linux's switch, and NumPy's."""
    code = CHILD.replace(
        'print("\\nMODULES "',
        'import os; status = open("/proc/self/status").read() if os.path.exists("/proc/self/status") else ""\n'
        'print("THP", [ln for ln in status.splitlines() if ln.startswith("THP_enabled")], '
        'os.environ.get("NUMPY_MADVISE_HUGEPAGE"))\nprint("\\nMODULES "',
    )
    p = subprocess.run([sys.executable, "-c", code, '["scenes"]'], capture_output=True, text=True, timeout=120)
    line = next(ln for ln in p.stdout.splitlines() if ln.startswith("THP "))
    assert line.endswith(" 0"), line  # NumPy's switch
    if sys.platform.startswith("linux") and "THP_enabled" in line:  # kernels from 6.0 report it
        assert "THP_enabled:\\t0" in line, line


def test_help_names_every_backend():
    """The help texts write the backends' names out: the registry's, in its order."""
    from minirt.cli.options import BACKEND_NAMES
    from minirt.harness.backends import all_names

    assert tuple(all_names()) == BACKEND_NAMES


def test_a_command_collects_garbage_less_often():
    """main() raises the youngest generation's threshold to GC_YOUNG (a check's process collected ~1,500
    times at Python's 700), the older generations' ratios left as Python has them."""
    from minirt.cli.app import GC_YOUNG

    code = CHILD.replace('print("\\nMODULES "', 'import gc; print("GC", list(gc.get_threshold()))\nprint("\\nMODULES "')
    p = subprocess.run([sys.executable, "-c", code, '["scenes"]'], capture_output=True, text=True, timeout=120)
    line = next(ln for ln in p.stdout.splitlines() if ln.startswith("GC "))
    plain = subprocess.run([sys.executable, "-c", "import gc; print(list(gc.get_threshold()))"], capture_output=True,
                           text=True, check=True).stdout  # fmt: skip
    default = json.loads(plain)  # a Python that has not run minirt's main()
    assert json.loads(line[3:]) == [GC_YOUNG, *default[1:]] and default[0] < GC_YOUNG


FAULTS = """
import resource, sys
from minirt.cli.app import _keep_freed_memory, _normal_pages
_normal_pages()  # as main() does first: 4 KiB pages, whose faults are what is counted
import numpy as np
if sys.argv[1] == "kept":
    _keep_freed_memory()
def faults():
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt
before = faults()
for _ in range(20):  # a diagnosis step's life: whole-image temporaries of 8-24 MB, several alive at once
    a, b, c = np.ones(3 << 20), np.ones(3 << 19), np.ones(3 << 20)
    del a, c
    d = np.ones(1 << 20)
    del b, d
print(faults() - before)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's allocator: Linux only")
def test_a_command_keeps_the_memory_it_frees_for_its_next_arrays():
    """main() asks glibc to keep freed memory (``_keep_freed_memory``): temporaries of 8-24 MB made and
    freed twenty times, several alive at once, fault their pages in about once (60 MB: ~15,000 pages),
    where glibc's defaults hand freed blocks back and fault them in again (measured: ~270,000)."""
    import platform

    if platform.libc_ver()[0] != "glibc":
        pytest.skip("the C library is not glibc: _keep_freed_memory does nothing there")
    kept, plain = (
        int(subprocess.run([sys.executable, "-c", FAULTS, mode], capture_output=True, text=True, timeout=60,
                           check=True).stdout)
        for mode in ("kept", "plain")
    )  # fmt: skip
    once = (60 << 20) // 4096
    assert kept < 2 * once, kept
    assert plain > 5 * once, plain
