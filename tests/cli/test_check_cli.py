"""`minirt check` and `render --backend all` through the command line: exit codes, JSON, JUnit,
and a missing or crashing backend reported while the others still run."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from support.inproc import minirt

from minirt.harness import backends
from minirt.harness.results import CheckResult, worst
from minirt.harness.run import check_scene
from minirt.model.result import RenderResult

ROOT = Path(__file__).resolve().parents[2]


def run(*args: str) -> subprocess.CompletedProcess:
    """The command's entry point in this process (tests/support/inproc.py): its exit status and both streams."""
    return minirt(*args, cwd=ROOT)


def run_child(*args: str, env=None) -> subprocess.CompletedProcess:
    """A child process: for a changed environment, or Dask worker processes of its own."""
    return subprocess.run(
        [sys.executable, "-m", "minirt", *args], capture_output=True, text=True, cwd=ROOT, env=env, timeout=300
    )


def test_check_json_and_junit(tmp_path):
    j, x = tmp_path / "r.json", tmp_path / "r.xml"
    p = run("check", "scenes/exercise.toml", "--size", "48x48", "--json", str(j), "--junit", str(x), "-q")
    assert p.returncode == 0, p.stderr
    assert p.stdout.startswith("PASS")
    d = json.loads(j.read_text())
    assert d["verdict"] == "pass"
    s = d["scenes"][0]
    assert s["scene"] == "exercise" and s["file"] == "scenes/exercise.toml"
    assert set(s["backends"]) == set(backends.oracle_names())  # every oracle, by default
    m = s["backends"]["mitsuba"]
    geo_keys = {"verdict", "pixels", "mask_mismatch", "mask_mismatch_outside_band", "id_mismatch"}
    geo_keys |= {"depth_rel_err_max", "depth_rel_err_p99", "normal_deg_max"}
    assert geo_keys <= set(m["geometry"])
    assert m["geometry"]["pixels"] == 48 * 48
    assert {"verdict", "shading", "rule_effects", "rule_diagnosis", "seconds"} <= set(m)
    # the exercise's background rule alone changes pixels Mitsuba cannot reproduce
    assert m["rule_effects"]["background"] > 0
    assert m["rule_diagnosis"]["ran"] is False  # Mitsuba's colour is a physical model
    assert "mask_outside_band" in d["thresholds"] and d["thresholds"]["mask_outside_band"]["why"]
    suites = ET.parse(x).getroot()
    assert suites.find("testsuite").get("name") == "exercise"
    assert int(suites.find("testsuite").get("failures")) == 0


def test_a_bundled_scene_is_recorded_by_its_name(tmp_path):
    """check.json names a bundled scene by its name, not by where minirt is installed (the same document on
    every machine), as the API's result and JUnit do; a path the user gives stays as given."""
    from minirt.model.bundled import BUNDLED

    p = minirt("check", "exercise", str(BUNDLED / "rules.toml"), "scenes/matte.toml", "-b", "embree",
               "--size", "8x8", "--json", "-", "-q", "--junit", str(tmp_path / "j.xml"), cwd=ROOT)  # fmt: skip
    assert p.returncode == 0, p.stderr
    d = json.loads(p.stdout)
    assert [s["file"] for s in d["scenes"]] == ["exercise", "rules", "scenes/matte.toml"]
    assert str(BUNDLED) not in p.stdout and str(BUNDLED) not in (tmp_path / "j.xml").read_text()


def test_rejected_run_leaves_no_json_folder(tmp_path):
    """--json and --junit are checked before any work but their folders are made only when written: a run
    rejected later (a missing scene, a bad --junit) leaves no empty folder behind."""
    for args in (["nosuch"], ["scenes/exercise.toml", "--junit", str(tmp_path)]):
        p = run("check", *args, "--json", str(tmp_path / "new" / "deeper" / "r.json"), "-q")
        assert p.returncode == 2 and len(p.stderr.splitlines()) == 1, p.stderr
        assert not (tmp_path / "new").exists()
    p = run("check", "exercise", "-b", "embree", "--size", "8x8", "-q", "--json", str(tmp_path / "new" / "r.json"))
    assert p.returncode == 0 and json.loads((tmp_path / "new" / "r.json").read_text())["verdict"] == "pass"


def test_check_bad_input_exits_2(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[camera]\ndistance = -1\n")
    p = run("check", str(bad), "-q")
    assert p.returncode == 2 and "camera.distance: must be > 0" in p.stderr and "Traceback" not in p.stderr


def test_missing_povray_is_a_skip_and_the_others_render(tmp_path):
    env = dict(os.environ)
    env["PATH"] = str(Path(sys.executable).parent)  # no povray on this PATH
    p = run_child("render", "scenes/exercise.toml", "--backend", "all", "--width", "32", "--height", "32",
                  "--out", str(tmp_path), env=env)  # fmt: skip
    assert p.returncode == 0, p.stderr
    assert "povray    SKIP" in p.stderr and "apt-get install" in p.stderr
    names = {f.name for f in tmp_path.iterdir()}
    assert {"exercise.reference.png", "exercise.mitsuba.exr", "exercise.embree.exr", "exercise.contact.png"} <= names
    assert not any(n.startswith("exercise.povray") for n in names)


def test_crashing_oracle_is_an_error_and_the_others_run(monkeypatch):
    import minirt.oracles.embree

    def boom(self, scene, rules, options=None):
        raise RuntimeError("segfault in the intersector")

    monkeypatch.setattr(minirt.oracles.embree.EmbreeOracle, "render", boom)
    sc = check_scene(ROOT / "scenes" / "exercise.toml", ["embree", "mitsuba"], (24, 24))
    assert sc.backends["embree"].verdict == "error"
    assert "segfault in the intersector" in sc.backends["embree"].reason
    assert sc.backends["mitsuba"].verdict == "pass"
    assert CheckResult(worst([sc.verdict]), [sc]).exit_code() == 2


def test_render_result_failed_carries_reason():
    r = backends.render("nope-backend", *_tiny())
    assert isinstance(r, RenderResult) and r.status == "error" and "nope-backend" in r.reason


def _tiny():
    from minirt.model.rules import resolve
    from minirt.model.scene import load_scene

    sc = load_scene(ROOT / "scenes" / "exercise.toml").with_overrides(width=8, height=8)
    return sc, resolve(sc)


@pytest.mark.parametrize("spec", ["all", "reference,embree"])
def test_parse_backends(spec):
    names = backends.parse_backends(spec)
    assert "reference" in names and len(names) >= 2


def _without_timings(d):
    if isinstance(d, dict):
        return {k: _without_timings(v) for k, v in d.items() if k not in ("seconds", "timings", "renders")}
    if isinstance(d, list):
        return [_without_timings(v) for v in d]
    return d


def test_check_as_jobs_on_a_local_cluster_gives_the_same_document(tmp_path):
    """--workers 2: each (scene, oracle) is a Dask job on a LocalCluster; verdicts, figures and reasons are
    those of the in-process run (only the seconds differ)."""
    args = ["check", "exercise", "shadows", "--size", "24x24", "-q"]
    # the cluster's run starts first, in a child, and the in-process run overlaps its start-up
    cmd = [sys.executable, "-m", "minirt", *args, "--workers", "2", "--json", str(tmp_path / "there.json")]
    with subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) as child:
        here = run(*args, "--json", str(tmp_path / "here.json"))
        out, err = child.communicate(timeout=300)
    there = subprocess.CompletedProcess(cmd, child.returncode, out, err)
    assert here.returncode == there.returncode == 0, here.stderr + there.stderr
    a = json.loads((tmp_path / "here.json").read_text())
    b = json.loads((tmp_path / "there.json").read_text())
    assert [s["scene"] for s in b["scenes"]] == ["exercise", "shadows"]
    assert _without_timings(a) == _without_timings(b)


def test_check_workers_and_scheduler_together_is_bad_input():
    p = run("check", "exercise", "--workers", "2", "--scheduler", "tcp://127.0.0.1:1", "-q")
    assert p.returncode == 2 and "--workers and --scheduler" in p.stderr


def test_check_cache_reruns_only_what_changed(tmp_path):
    """--cache DIR: a rerun takes every unchanged (scene, oracle) check from DIR -- the same document,
    down to the seconds the first run measured -- and redoes the checks of a changed scene, and of an entry
    that was damaged."""
    scenes = tmp_path / "scenes"
    scenes.mkdir()
    for name in ("exercise", "shadows"):
        (scenes / f"{name}.toml").write_text((ROOT / "scenes" / f"{name}.toml").read_text())
    cache = tmp_path / "cache"
    args = ["check", str(scenes / "exercise.toml"), str(scenes / "shadows.toml"), "--size", "24x24", "-q"]
    args += ["--backend", "embree", "--cache", str(cache)]

    def doc(name):
        p = run(*args, "--json", str(tmp_path / name))
        assert p.returncode == 0, p.stderr
        return {s["scene"]: s["backends"]["embree"] for s in json.loads((tmp_path / name).read_text())["scenes"]}

    first = doc("1.json")
    assert len(list(cache.iterdir())) == 2
    assert doc("2.json") == first  # seconds included: nothing was checked again
    text = (scenes / "shadows.toml").read_text()
    (scenes / "shadows.toml").write_text(text.replace("[camera]", "# an edit\n[camera]", 1))
    third = doc("3.json")
    assert third["exercise"] == first["exercise"]
    # The edited scene was checked again: a new entry under its new hash. (Not its seconds: rounded to
    # milliseconds, two runs of a 24x24 check can measure the same.)
    assert len(list(cache.iterdir())) == 3
    assert _without_timings(third["shadows"]) == _without_timings(first["shadows"])  # a comment changes nothing
    for entry in cache.iterdir():  # damaged entries are checked again, never used
        entry.write_bytes(entry.read_bytes()[:100])
    fourth = doc("4.json")
    # the two entries this run uses were written again whole; the old shadows entry stays cut short
    assert sorted(e.stat().st_size > 100 for e in cache.iterdir()) == [False, True, True]
    assert _without_timings(fourth) == _without_timings(third)


def test_check_cache_folder_must_be_writable(tmp_path):
    p = run("check", "exercise", "--cache", "/proc/minirt-cache", "-q")
    assert p.returncode == 2 and "--cache /proc/minirt-cache" in p.stderr, p.stderr
