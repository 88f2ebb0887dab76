"""tools/same_outputs.py and benchmarks/bench_cpu.py: the before/after comparison says what differs, and the
CPU benchmark names its machine and counts the processes a command waits for."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _load(path: Path):
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def same():
    return _load(ROOT / "tools" / "same_outputs.py")


def test_timing_keys_are_dropped_at_any_depth_and_nothing_else(same):
    doc = {"a": 1, "timings": {"total": 2.0}, "runs": [{"seconds": 3, "verdict": "pass", "wall": 1}]}
    assert same.strip_times(doc) == {"a": 1, "runs": [{"verdict": "pass"}]}


def test_compare_names_what_differs(same, tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    for d in (a, b):
        (d / "sub").mkdir(parents=True)
    (a / "doc.json").write_text(json.dumps({"verdict": "pass", "timings": {"total": 1.0}}))
    (b / "doc.json").write_text(json.dumps({"verdict": "pass", "timings": {"total": 9.0}}))
    (a / "sub" / "img.exr").write_bytes(b"\x00\x01")
    (b / "sub" / "img.exr").write_bytes(b"\x00\x01")
    assert same.compare(a, b) == []  # only a time differs
    (b / "doc.json").write_text(json.dumps({"verdict": "fail", "timings": {"total": 9.0}}))
    (b / "sub" / "img.exr").write_bytes(b"\x00\x02")
    (a / "only.png").write_bytes(b"x")
    got = same.compare(a, b)
    assert got[0] == "only in one tree: only.png"
    assert [d.split(":")[0] for d in got[1:]] == ["doc.json", "sub/img.exr"]


def test_a_tree_without_its_own_environment_is_refused(same, tmp_path):
    with pytest.raises(SystemExit, match=r"no \.venv/bin/python"):
        same.interpreter(tmp_path)


def test_this_tree_against_itself_writes_the_same(tmp_path):
    cmd = "render exercise --width 16 --height 12 --out {out} --quiet"
    p = subprocess.run([sys.executable, str(ROOT / "tools" / "same_outputs.py"), "--base", str(ROOT), "--command",
                        cmd, "--keep", str(tmp_path)], capture_output=True, text=True)  # fmt: skip
    assert p.returncode == 0, p.stdout + p.stderr
    assert "1 of 1 commands write the same outputs" in p.stdout
    assert sorted(f.name for f in (tmp_path / "a" / "00").iterdir()) == [
        "exercise.reference.exr", "exercise.reference.json", "exercise.reference.png"]  # fmt: skip


def test_bench_cpu_names_the_machine_and_counts_a_command(tmp_path):
    out = tmp_path / "cpu.json"
    p = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_cpu.py"), "--only", "help", "--runs", "1",
                        "--out", str(out)], capture_output=True, text=True, cwd=ROOT)  # fmt: skip
    assert p.returncode == 0, p.stderr
    assert p.stdout.startswith("machine: ") and "logical cores" in p.stdout
    assert any(f in p.stdout for f in ("AVX-512", "AVX2, no AVX-512", "no AVX2"))
    got = json.loads(out.read_text())
    assert got["commands"]["help"]["A"]["median"] > 0
