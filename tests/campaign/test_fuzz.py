"""`minirt fuzz`: the campaign's make-test subset, its jobs, cache, evidence and defect injections.

The subset: a fixed seed, scenes of every family through every oracle, on an embedded Dask LocalCluster
of two workers -- 0 FAIL, 0 ERROR. A rerun comes from the cache and writes the same bytes; a run in this
process (--workers 1, no cache) writes them too. Defects: each changes the reference's image on most
scenes, and wherever it changes pixels a check judges, some oracle FAILs.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import jsonschema
import numpy as np
import pytest
from support.inproc import minirt

from minirt.campaign import campaign
from minirt.campaign.families import FAMILIES
from minirt.harness.backends import oracle_names
from minirt.io import documents
from minirt.model.result import RenderResult

ROOT = Path(__file__).resolve().parents[2]
PER_FAMILY = 3  # scenes of each family in the subset
ORACLES = oracle_names()  # every oracle the campaign checks by default (the registry's)
N = len(ORACLES)
SIZE = "16x16"


def fuzz(*args, cwd: Path = ROOT, env=None, timeout: int = 900) -> subprocess.CompletedProcess:
    """`minirt fuzz` in a child process: for a LocalCluster of worker processes, or a changed environment."""
    return subprocess.run(
        [sys.executable, "-m", "minirt", "fuzz", *map(str, args)],
        cwd=cwd, capture_output=True, text=True, timeout=timeout, env=env,
    )  # fmt: skip


def fuzz_here(*args) -> subprocess.CompletedProcess:
    """`minirt fuzz` in this process (tests/support/inproc.py): --workers 1 runs its jobs here, no child needed."""
    return minirt("fuzz", *args, cwd=ROOT)


@pytest.fixture(scope="module")
def subset(tmp_path_factory):
    """The subset on a LocalCluster of two worker processes (a child process), and -- while the child runs,
    so the two overlap -- the same seed's first scene of each family without the cache in this process
    (for test_rerun_comes_from_the_cache_with_the_same_bytes)."""
    out = tmp_path_factory.mktemp("fuzz") / "campaign"
    alone = tmp_path_factory.mktemp("fuzz-here")
    count = PER_FAMILY * len(FAMILIES)
    cmd = [sys.executable, "-m", "minirt", "fuzz", *map(str, ("--count", count, "--seed", 7, "--size", SIZE,
                                                              "--workers", 2, "-o", out, "-q"))]  # fmt: skip
    logs = tmp_path_factory.mktemp("fuzz-logs")
    with (logs / "out").open("w+") as so, (logs / "err").open("w+") as se:
        child = subprocess.Popen(cmd, cwd=ROOT, stdout=so, stderr=se, text=True, stdin=subprocess.DEVNULL)
        try:
            q = fuzz_here("--count", len(FAMILIES), "--seed", 7, "--size", SIZE, "--workers", 1, "--no-cache",
                          "-o", alone, "-q")  # fmt: skip
            child.wait(timeout=900)
        finally:
            if child.poll() is None:
                child.kill()
                child.wait()
        so.seek(0)
        se.seek(0)
        p = subprocess.CompletedProcess(cmd, child.returncode, so.read(), se.read())
    return out, count, p, (alone, q)


def test_subset_every_family_every_oracle_on_a_local_cluster(subset):
    out, count, p, _ = subset
    assert p.returncode == 0, p.stdout + p.stderr
    doc = json.loads((out / "fuzz.json").read_text())
    assert doc["scenes"] == count and doc["jobs"] == N * count
    assert doc["backends"] == ORACLES
    assert doc["verdicts"]["fail"] == 0 and doc["verdicts"]["error"] == 0, doc["failures"]
    assert sum(doc["verdicts"].values()) == doc["jobs"]
    assert set(doc["by_family"]) == set(FAMILIES)
    assert all(sum(v.values()) == N * PER_FAMILY for v in doc["by_family"].values())
    assert "(2 processes)" in p.stdout  # the jobs ran on a LocalCluster of two workers
    validator = jsonschema.Draft202012Validator(documents.shipped("fuzz"))
    assert not list(validator.iter_errors(doc))


def test_every_non_pass_keeps_its_scene_and_evidence(subset):
    out, _, _, _ = subset
    doc = json.loads((out / "fuzz.json").read_text())
    kept = {p.stem for p in out.glob("*.toml")}
    non_pass = sum(v for k, v in doc["verdicts"].items() if k != "pass")
    if not non_pass:
        assert not kept  # only non-PASS scenes are kept
    for f in out.glob("*.check.json"):
        scene = f.name.split(".")[0]
        assert scene in kept
        assert json.loads(f.read_text())["verdict"] != "pass"


def test_rerun_comes_from_the_cache_with_the_same_bytes(subset):
    out, count, _, (alone, q) = subset
    before = (out / "fuzz.json").read_bytes()
    p = fuzz_here("--count", count, "--seed", 7, "--size", SIZE, "--workers", 1, "-o", out)
    assert p.returncode == 0, p.stderr
    assert f"{N * count} of {N * count} jobs from the cache" in p.stdout
    assert (out / "fuzz.json").read_bytes() == before
    # and without the cache, in this process, the same bytes again (a few scenes: the same seed's first ones),
    # as those scenes' results read back from the cache the two-worker cluster wrote
    shutil.copytree(out / "cache", out / "again" / "cache")
    r = fuzz_here("--count", len(FAMILIES), "--seed", 7, "--size", SIZE, "--workers", 1, "-o", out / "again")
    assert q.returncode == r.returncode == 0, q.stderr + r.stderr
    assert f"{N * len(FAMILIES)} of {N * len(FAMILIES)} jobs from the cache" in r.stdout
    assert (alone / "fuzz.json").read_bytes() == (out / "again" / "fuzz.json").read_bytes()
    assert not (alone / "cache").exists()


def test_defects_are_caught_where_they_change_judged_pixels(tmp_path):
    kinds = ",".join(campaign.DEFECTS)
    p = fuzz_here("--count", 6, "--seed", 3, "--families", "random", "--size", "24x24", "--workers", 1, "--defects",
                  kinds, "-o", tmp_path, "-q")  # fmt: skip
    assert p.returncode == 0, p.stderr
    doc = json.loads((tmp_path / "fuzz.json").read_text())
    assert set(doc["defects"]) == set(campaign.DEFECTS)
    for name, d in doc["defects"].items():
        assert d["changes"] >= 1, f"{name} changed no scene: it tests nothing here"
        assert d["missed_judged"] == [], f"{name} changed judged pixels of {d['missed_judged']} and was not caught"
        assert d["caught"] <= d["changes"]
        assert f"defect {name}" in p.stdout


def test_a_crashing_oracle_is_an_error_with_its_scene_kept(tmp_path):
    fake = tmp_path / "bin" / "povray"
    fake.parent.mkdir()
    fake.write_text(
        '#!/bin/sh\n[ "$1" = --version ] && { echo "POV-Ray 3.7.0.10"; exit 0; }\n'
        'echo "Parse Error: boom" >&2\nexit 1\n'
    )
    fake.chmod(0o755)
    env = {**os.environ, "PATH": f"{fake.parent}{os.pathsep}{os.environ['PATH']}"}
    out = tmp_path / "out"
    p = fuzz("--count", 2, "--families", "random", "--size", "8x8", "-b", "povray", "--workers", 1, "-o", out, "-q",
             env=env)  # fmt: skip
    assert p.returncode == 2, p.stdout + p.stderr
    assert "ERROR random_1_0 povray" in p.stderr and "Parse Error" in p.stderr
    doc = json.loads((out / "fuzz.json").read_text())
    assert doc["verdicts"]["error"] == 2 and len(doc["failures"]) == 2
    assert {f["scene"] for f in doc["failures"]} == {"random_1_0", "random_1_1"}
    for s in ("random_1_0", "random_1_1"):
        assert (out / f"{s}.toml").is_file() and (out / f"{s}.povray.check.json").is_file()
    assert not list(out.glob("cache/*.json"))  # an error is not cached: the next run tries again


@pytest.mark.parametrize(
    "args, words",
    [
        (["--families", "nope"], "--families: unknown family nope"),
        (["--defects", "nope"], "--defects: unknown defect nope"),
        (["--size", "10x"], "--size"),
        (["-b", "reference"], "no oracle to compare with"),
        (["--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], "--workers and --scheduler"),
    ],
)
def test_bad_options_are_one_line_and_exit_2(args, words, tmp_path):
    p = fuzz_here(*args, "-o", tmp_path, "-q")
    assert p.returncode == 2, p.stderr
    assert words in p.stderr
    assert "Traceback" not in p.stderr


def test_an_unreachable_scheduler_is_one_line(tmp_path):
    p = fuzz_here("--count", 1, "--scheduler", "tcp://127.0.0.1:9", "-o", tmp_path, "-q")
    assert p.returncode == 2, p.stderr
    assert "cannot reach a Dask scheduler" in p.stderr and "Traceback" not in p.stderr


# ---- units ------------------------------------------------------------------------------------


def _result(hit, sid, t, color) -> RenderResult:
    h, w = hit.shape
    n = np.zeros((h, w, 3))
    n[..., 2] = 1
    return RenderResult("reference", w, h, hit=hit, shape_id=sid, t=t, normal=n, color=color,
                        terms={"diffuse": color})  # fmt: skip


def test_changes_sees_each_buffer_and_respects_where():
    hit = np.array([[True, False]])
    sid = np.array([[0, -1]])
    t = np.array([[2.0, np.inf]])
    c = np.full((1, 2, 3), 0.5)
    a = _result(hit, sid, t, c)
    assert not campaign.changes(a, _result(hit, sid, t, c), "exercise")
    assert campaign.changes(a, _result(~hit, sid, t, c), None)
    assert campaign.changes(a, _result(hit, sid + 1, t, c), None)
    assert campaign.changes(a, _result(hit, sid, t * 1.01, c), None)
    assert not campaign.changes(a, _result(hit, sid, t * (1 + 1e-12), c), None)
    one_level = c + 1 / 255
    assert not campaign.changes(a, _result(hit, sid, t, one_level), "exercise")  # rounding: the check allows it
    assert campaign.changes(a, _result(hit, sid, t, c + 3 / 255), "exercise")
    assert not campaign.changes(a, _result(hit, sid, t, c + 3 / 255), None)  # a geometry-only oracle
    assert not campaign.changes(a, _result(hit, sid, t, c + 3 / 255), "exercise", np.zeros_like(hit))
    # with the check's per-pixel tolerances a t or normal change counts only beyond them (mask and ids always)
    tol = (np.full((1, 2), 0.05), np.full((1, 2), 1.0))
    assert not campaign.changes(a, _result(hit, sid, t * 1.01, c), None, None, tol)  # dt 0.02 <= 0.05
    assert campaign.changes(a, _result(hit, sid, t * 1.05, c), None, None, tol)  # dt 0.1 > 0.05
    assert campaign.changes(a, _result(~hit, sid, t, c), None, None, tol)
    tilted = _result(hit, sid, t, c)
    tilted.normal = np.array([[[0.0, np.sin(0.05), np.cos(0.05)], [0.0, 0.0, 1.0]]])  # 2.9 degrees
    assert campaign.changes(a, tilted, None, None, tol) and not campaign.changes(
        a, tilted, None, None, (tol[0], tol[1] * 3)
    )


def test_job_key_changes_with_what_the_result_depends_on():
    v = {"minirt": "a", "drjit": "1", "povray": "3.7"}
    j = campaign.Job("s", "random", "text", "povray", ())
    k = campaign.job_key(j, v)
    assert k == campaign.job_key(campaign.Job("s", "random", "text", "povray", ()), dict(v))
    assert k != campaign.job_key(campaign.Job("s", "random", "text!", "povray", ()), v)
    assert k != campaign.job_key(campaign.Job("s", "random", "text", "mitsuba", ()), v)
    assert k != campaign.job_key(campaign.Job("s", "random", "text", "povray", ("t-scaled",)), v)
    assert k != campaign.job_key(j, {**v, "povray": "3.8"})
    assert k != campaign.job_key(j, {**v, campaign.JUDGE: "another certified oracle"})  # the judge it goes before
    assert k != campaign.job_key(j, {**v, "minirt": "b"})


def test_scenes_take_the_families_in_turn():
    fams = tuple(FAMILIES)
    got = campaign.scenes(2 * len(fams) + 1, 5, fams, (8, 8))
    assert [f for _, f, _ in got] == [*fams, *fams, fams[0]]
    assert got[0][0] == f"{fams[0]}_5_0" and got[len(fams)][0] == f"{fams[0]}_5_1"
    assert got == campaign.scenes(2 * len(fams) + 1, 5, fams, (8, 8))


def test_a_reference_that_misses_a_ball_fails_against_embree():
    """The defect campaign's far_2027_34 (seed 2027, 32x32): the reference with its near ball skipped misses
    46 pixels Embree hits. Embree's depth-tie band was relative to the reference's t, 0 on a miss, which
    put every such pixel in the band (the check was inconclusive); it is relative to the scene's nearest
    candidate now."""
    from minirt.campaign import families as fuzz
    from minirt.harness import compare as harness

    text = fuzz.scene_text("far", 2027, 34, 32, 32)
    scene, rules, _, bc = harness.check_text(text, "far_2027_34.toml", "embree", explain=False)
    assert bc.verdict == "pass", bc.reason
    bad = campaign._DefectiveReference(scene, campaign.DEFECTS["last-shape-skipped"])
    dc = harness.check_backend(scene, rules, "embree", bad, rendered=bc.result, explain=False)
    assert dc.verdict == "fail" and dc.checks["geometry"].figures["mask_mismatch_outside_band"] == 46, dc.reason


def test_a_reference_with_ids_the_scene_lacks_is_judged_not_a_crash():
    """The defect campaign's far_2027_3 (seed 2027, 32x32): one ball, and the ids-swapped defect reports it
    as shape 1. POV-Ray's per-shape root error was indexed by the reference's id and raised IndexError
    (16 ERRORs in the far family); an id the scene lacks is an id mismatch, and the check FAILs."""
    from minirt.campaign import families as fuzz

    text = fuzz.scene_text("far", 2027, 3, 32, 32)
    job = campaign.Job(scene="far_2027_3", family="far", text=text, backend="povray", defects=("ids-swapped",))
    out = campaign.run_job(job)
    assert out["verdict"] != "error", out["reason"]
    found = out["defects"]["ids-swapped"]
    assert found["changes"] and found["verdict"] == "fail"


def test_swapped_ids_beside_a_far_ball_fail_against_povray():
    """The defect campaign's f32_2027_22 (seed 2027, 32x32): the ids-swapped defect changed pixels POV-Ray's
    per-shape band judges, and passed -- its id-tie excuse was still the scene-wide one, 4 times the worst
    ball's bounding-box error, which excused every mismatch. Ties are per pair now, and the check FAILs."""
    from minirt.campaign import families as fuzz

    text = fuzz.scene_text("f32", 2027, 22, 32, 32)
    job = campaign.Job(scene="f32_2027_22", family="f32", text=text, backend="povray", defects=("ids-swapped",))
    out = campaign.run_job(job)
    assert out["verdict"] == "pass", out["reason"]
    assert out["defects"]["ids-swapped"] == {"changes": True, "changes_judged": True, "verdict": "fail"}
