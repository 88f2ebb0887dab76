"""The README's Python API example runs as written (from a folder outside the repository, in the test's
process), and `import minirt` stays cheap: the API loads Dr.Jit, Mitsuba and NumPy only when a function
runs (that one in a fresh child process, where nothing is imported yet)."""

from __future__ import annotations

import contextlib
import io
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def readme_example() -> str:
    text = (ROOT / "README.md").read_text()
    section = text.split("\n## Python API\n", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    assert blocks, "README: no python block under ## Python API"
    return blocks[0]


def test_readme_python_api_example_runs(tmp_path):
    code = readme_example()
    assert "minirt.render(" in code and "minirt.check(" in code and "minirt.grade(" in code
    # run here, as a script in a folder outside the repository: its own namespace, stdout captured
    out = io.StringIO()
    with contextlib.chdir(tmp_path), contextlib.redirect_stdout(out):
        exec(compile(code, "README.md", "exec"), {"__name__": "__main__"})
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("(48, 64, 3) ")  # colour (H, W, 3), then the hit count, id and t
    assert lines[1].startswith("pass {'embree': 'pass'}")
    assert lines[2].startswith("differs ")  # the sample student made mistakes
    assert lines[3].startswith("minirt render ") and "--rule" in lines[3]


def test_import_minirt_is_cheap():
    code = (
        "import sys, minirt\n"
        "heavy = [m for m in ('numpy', 'drjit', 'mitsuba', 'pydantic', 'typer', 'minirt.model.scene')\n"
        "         if m in sys.modules]\n"
        "print(heavy, sorted(minirt.__all__))\n"
        "assert not heavy, heavy\n"
        "assert all(getattr(minirt, n) is not None for n in minirt.__all__)\n"
    )
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert p.returncode == 0, p.stdout + p.stderr


def test_check_with_workers_and_a_scheduler_is_bad_input_before_any_work():
    import pytest

    import minirt
    from minirt.errors import MinirtError

    with pytest.raises(MinirtError, match=r"^workers and scheduler: give one"):
        minirt.check("exercise", "embree", workers=2, scheduler="tcp://127.0.0.1:1")
    with pytest.raises(MinirtError, match=r"^workers and scheduler: give one"):
        minirt.check("exercise", "embree", workers=1, scheduler="tcp://127.0.0.1:1")  # 1 is still a choice
