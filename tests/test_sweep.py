"""The accuracy/time sweep (minirt.sweep): files written, errors fall where theory says, slopes near theory.

Small on purpose: 16x16 images, one run per setting, short knob lists. The slopes are checked loosely
(theory: stratified jittered sampling gives RMSE ~ spp^-0.75 at edges, between the -0.5 of random
sampling and -1; an inscribed icosphere's radial gap, hence the faceted t error, shrinks by 4 per
subdivision level), since a 16x16 image has few edge pixels.
"""

from __future__ import annotations

import csv
import itertools
import json

import pytest
from conftest import ROOT

from minirt import sweep
from minirt.rules import resolve
from minirt.scene import load_scene
from oracles.embree import EmbreeOracle

SIZE = 16
KNOBS = sweep.Knobs(
    reference_spp=(1, 4, 16, 64),
    mitsuba_spp=(1, 16),
    povray_antialias=(0, 2),
    povray_samples=(1, 16),
    embree_subdivisions=(0, 1, 2, 3, 4),
    converged_reference_spp=1024,
    converged_mitsuba_spp=256,
)


@pytest.fixture(scope="module")
def exercise():
    sc = load_scene(ROOT / "scenes" / "exercise.toml")
    return sc, resolve(sc)


@pytest.fixture(scope="module")
def result(exercise, tmp_path_factory):
    sc, rules = exercise
    out = tmp_path_factory.mktemp("sweep")
    calls: list[tuple[int, int, str]] = []
    res = sweep.run_sweep(sc, rules, ["reference", "embree"], out, size=SIZE, repeats=1,
                          progress=lambda d, t, label: calls.append((d, t, label)), knobs=KNOBS)  # fmt: skip
    return res, out, calls


def _rows(res, backend, knob):
    return {r["value"]: r for r in res["rows"] if r["backend"] == backend and r["knob"] == knob}


def test_files_written(result):
    res, out, _ = result
    for name in ("sweep.csv", "sweep.md", "sweep.json", "sweep.png", "sweep-reference.png", "sweep-embree.png"):
        assert (out / name).stat().st_size > 0, name
    data = json.loads((out / "sweep.json").read_text())
    assert data["scene"] == "exercise" and data["size"] == [SIZE, SIZE]
    assert {"rows", "slopes", "pareto"} <= data.keys()
    for r in data["rows"]:
        assert {"backend", "knob", "value", "seconds_median", "seconds_setup", "error", "runs"} <= r.keys()
    with (out / "sweep.csv").open() as f:
        table = list(csv.DictReader(f))
    assert len(table) == len(res["rows"])
    assert (out / "sweep.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_progress_reports_every_task(result):
    res, _, calls = result
    total = len(res["rows"])
    assert all(t == total for _, t, _ in calls)
    assert [d for d, _, _ in calls] == sorted(d for d, _, _ in calls)
    assert calls[-1][:2] == (total, total)
    assert any("converged" in label for _, _, label in calls)


def test_every_row_ok_and_timed(result):
    res, _, _ = result
    for r in res["rows"]:
        assert r["status"] == "ok", r
        assert r["seconds_median"] >= 0 and len(r["runs"]) == 1


def test_reference_error_falls_with_samples(result):
    res, _, _ = result
    rows = _rows(res, "reference", "spp")
    errs = [rows[s]["error"]["rmse"] for s in (1, 4, 16, 64)]
    assert all(a > b for a, b in itertools.pairwise(errs)), errs
    flips = [rows[s]["error"]["flip"] for s in (1, 64)]
    assert flips[0] > flips[1] > 0
    slope = res["slopes"]["reference/spp"]["slope_cost"]
    assert -1.2 < slope < -0.3, slope


def test_reference_f32_against_f64(result):
    res, _, _ = result
    rows = _rows(res, "reference", "precision")
    assert rows["f64"]["error"]["rmse"] == 0 and rows["f64"]["error"]["t_rel_max"] == 0
    e = rows["f32"]["error"]
    assert 0 < e["t_rel_max"] < 1e-5  # a few float32 roundings
    assert e["mask_mismatch"] < 0.01 and e["rmse"] < 1e-3


def test_embree_geometry_error_falls_with_subdivision(result):
    res, _, _ = result
    rows = _rows(res, "embree", "subdivisions")
    errs = [rows[n]["error"]["t_rel_mean"] for n in range(5)]
    assert all(a > b for a, b in itertools.pairwise(errs)), errs
    assert rows[4]["error"]["mask_mismatch"] <= rows[0]["error"]["mask_mismatch"]
    factor = res["slopes"]["embree/subdivisions"]["factor_per_level"]
    assert 1 / 6 < factor < 1 / 2.5, factor


def test_pareto_front_marked(result):
    res, _, _ = result
    front = res["pareto"]["reference/spp"]
    assert front and 64 in front  # the most accurate setting is never beaten on error
    assert all(r["pareto"] == (r["value"] in front) for r in _rows(res, "reference", "spp").values())


def test_unavailable_backend_is_a_skip_row(exercise, tmp_path, monkeypatch):
    monkeypatch.setattr(EmbreeOracle, "available", lambda self: (False, "embreex not installed (test)"))
    sc, rules = exercise
    res = sweep.run_sweep(sc, rules, ["embree", "no-such-backend"], tmp_path, size=8, repeats=1, knobs=KNOBS)
    by = {r["backend"]: r for r in res["rows"]}
    assert by["embree"]["status"] == "skip" and "embreex not installed" in by["embree"]["reason"]
    assert by["no-such-backend"]["status"] == "skip" and "unknown backend" in by["no-such-backend"]["reason"]
    assert "| SKIP |" in (tmp_path / "sweep.md").read_text()
    assert (tmp_path / "sweep.png").exists() and (tmp_path / "sweep.csv").exists()


def test_oracles_sweep_small(exercise, tmp_path):
    """Mitsuba (its own converged render) and POV-Ray (antialiasing) run through the same path."""
    sc, rules = exercise
    res = sweep.run_sweep(sc, rules, ["mitsuba", "povray"], tmp_path, size=SIZE, repeats=1, knobs=KNOBS)
    for r in res["rows"]:
        assert r["status"] == "ok", r
    mi = _rows(res, "mitsuba", "spp")
    assert mi[1]["error"]["rmse"] > mi[16]["error"]["rmse"] > 0
    pov = _rows(res, "povray", "antialias")
    assert pov[0]["error"]["rmse"] > pov[2]["error"]["rmse"] > 0
    assert pov[2]["seconds_setup"] > 0.1  # POV-Ray's process start-up, reported apart
    # the exercise's own samples through POV-Ray's mesh camera converge like the reference's samples
    ps = _rows(res, "povray", "samples")
    assert ps[1]["error"]["rmse"] > ps[16]["error"]["rmse"] > 0


def test_povray_antialias_command_line(exercise):
    from oracles import povray

    sc, _ = exercise
    assert "-A" in povray.command(sc, 1, 1, 1, "exr")
    cmd = povray.command(sc, 1, 1, 1, "exr", antialias=3)
    assert "-A" not in cmd and cmd[cmd.index("+A0.0") + 1] == "+R3"
