"""The accuracy/time sweep (minirt.sweep): files written, errors fall where theory says, slopes near theory.

Small on purpose: 16x16 images (the default is 256x256), one timed run per setting, short knob lists.
The slopes are checked loosely
(theory: stratified jittered sampling gives RMSE ~ spp^-0.75 at edges, between the -0.5 of random
sampling and -1; an inscribed icosphere's radial gap, hence the faceted t error, shrinks by 4 per
subdivision level), since a 16x16 image has few edge pixels.
"""

from __future__ import annotations

import csv
import itertools
import json
import re
from types import SimpleNamespace

import pytest
from conftest import ROOT
from support.inproc import minirt

from minirt.model.rules import resolve
from minirt.model.scene import load_scene
from minirt.oracles.embree import EmbreeOracle
from minirt.oracles.povray import PovrayOracle
from minirt.sweep import document, run, series, timing

SIZE = 16
KNOBS = {
    "reference": {"spp": (1, 4, 16, 64), "converged_spp": 1024},
    "mitsuba": {"spp": (1, 16), "converged_spp": 256},
    "povray": {"antialias": (0, 2), "samples": (1, 16), "converged_spp": 1024},
    "embree": {"subdivisions": (0, 1, 2, 3, 4)},
}


@pytest.fixture(scope="module")
def exercise():
    sc = load_scene(ROOT / "scenes" / "exercise.toml")
    return sc, resolve(sc)


@pytest.fixture(scope="module")
def result(exercise, tmp_path_factory):
    sc, rules = exercise
    out = tmp_path_factory.mktemp("sweep")
    calls: list[tuple[int, int, str]] = []
    res = run.run_sweep(sc, rules, ["reference", "embree"], out, size=SIZE, repeats=1,
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
        assert r["seconds_median"] > 0 and len(r["runs"]) == 1
        # repeats=1 still renders an untimed warm-up first: its time is apart, its excess is the setup
        assert r["seconds_first"] > 0 and r["seconds_setup"] is not None and r["seconds_setup"] >= 0


def test_warm_up_is_not_timed():
    """A render whose first call pays a compilation (1 s here) is timed without it, even with repeats=1."""
    calls = []

    def render():
        calls.append(1)
        wall = 1.0 if len(calls) == 1 else 0.01
        return SimpleNamespace(ok=True, backend="reference", meta={"timings": {"wall": wall}})

    _, timed = timing.timed(render, repeats=1, slow_seconds=5.0)
    assert len(calls) == 2 and timed["runs"] == [0.01] and timed["seconds_median"] == 0.01
    assert timed["seconds_setup"] == pytest.approx(0.99) and timed["seconds_first"] == 1.0


def test_povray_time_below_its_timer_is_floored_and_marked(exercise):
    """POV-Ray's statistics count whole milliseconds: a 0 ms render is recorded at 1 ms and marked, not 0."""
    sc, rules = exercise
    cat = series.catalogue(sc, rules, {})
    stages = {"parse": 0.0, "bounding": 0.0, "photon": 0.0, "radiosity": 0.0, "trace": 0.0, "wall": 0.7}
    res = SimpleNamespace(ok=True, backend="povray", meta={"timings": {"passes": {"exr": stages}}})
    _, timed = timing.timed(lambda: res, repeats=3, slow_seconds=5.0, seconds=cat.series["povray/antialias"].seconds)
    assert timed["seconds_median"] == PovrayOracle.SWEEP_RESOLUTION and timed["seconds_at_resolution"]
    assert timed["seconds_setup"] == pytest.approx(0.7)  # the process start-up, apart
    row = {**run._row("povray", "antialias", 0, "ok"), **timed, "error": {"rmse": 0.01}, "cost": 1}
    assert series.usable(row, "rmse")  # on the log plot and in the fits
    result = {"scene": "x", "size": [8, 8], "repeats": 3, "rows": [row], "slopes": {}, "converged": {},
              "answer": document.answers([row], cat)}  # fmt: skip
    assert "≤ 0.001" in document.markdown(result)
    assert "≤ 0.001 s" in result["answer"][0]["line"]


def test_answer_line_per_backend(result):
    """One line per backend: the cheapest setting below one 8-bit level (RMSE < 1/255), with its time."""
    res, out, _ = result
    ans = {a["backend"]: a for a in res["answer"]}
    assert list(ans) == ["reference", "embree"]
    ref = ans["reference"]
    rows = _rows(res, "reference", "spp")
    good = [r for r in rows.values() if r["error"]["rmse"] < 1 / 255]
    assert good and ref["met"] and ref["knob"] == "spp"
    assert ref["seconds"] == min(r["seconds_median"] for r in good)
    assert rows[ref["value"]]["error"]["rmse"] < 1 / 255
    assert ref["line"].startswith("error < 1/255 costs ") and f"the reference at {ref['value']} spp" in ref["line"]
    emb = ans["embree"]
    if emb["met"]:
        assert emb["error"] < series.GEOMETRY_T_REL and "Embree at subdivision" in emb["line"]
    else:
        assert emb["line"].startswith("no setting tried reaches")
    assert res["answer_lines"][0].startswith(f"exercise {SIZE}x{SIZE}: error < 1/255 costs")
    md = (out / "sweep.md").read_text()
    assert md.index(res["answer_lines"][0]) < md.index("| backend")  # the answer opens the file
    assert json.loads((out / "sweep.json").read_text())["answer_lines"] == res["answer_lines"]


def test_answer_says_when_no_setting_reaches_it(exercise):
    cat = series.catalogue(*exercise, {})
    rows = [{**run._row("mitsuba", "spp", n, "ok"), "cost": n, "seconds_median": 0.1 * n,
             "seconds_setup": 0.0, "error": {"rmse": e}} for n, e in ((1, 0.05), (4, 0.02))]  # fmt: skip
    (a,) = document.answers(rows, cat)
    assert not a["met"] and a["value"] == 4
    assert a["line"].startswith("no setting tried reaches error < 1/255 with Mitsuba; best: Mitsuba at 4 spp")
    skipped = [run._row("povray", None, None, "skip", "povray not installed")]
    (b,) = document.answers(skipped, cat)
    assert not b["met"] and "not measured" in b["line"] and "povray not installed" in b["line"]


def test_markdown_tables_are_github_pipe_tables(result):
    res, out, _ = result
    lines = (out / "sweep.md").read_text().splitlines()
    head = next(i for i, line in enumerate(lines) if line.startswith("| backend"))
    table = lines[head : head + 2 + len(res["rows"])]
    assert set(table[1]) <= set("|-: ")  # the header rule
    assert len({len(line) for line in table}) == 1  # aligned columns
    assert all(line.count("|") == table[0].count("|") for line in table)


def test_colour_and_t_error_on_separate_axes(result):
    import matplotlib.image as mpimg

    _, out, _ = result
    both = mpimg.imread(out / "sweep.png")
    one = mpimg.imread(out / "sweep-reference.png")
    assert both.shape[1] > 1.8 * one.shape[1]  # two panels (colour, geometry) side by side; one for the reference


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
    res = run.run_sweep(sc, rules, ["embree", "no-such-backend"], tmp_path, size=8, repeats=1, knobs=KNOBS)
    by = {r["backend"]: r for r in res["rows"]}
    assert by["embree"]["status"] == "skip" and "embreex not installed" in by["embree"]["reason"]
    assert by["no-such-backend"]["status"] == "skip" and "unknown backend" in by["no-such-backend"]["reason"]
    assert re.search(r"\| SKIP +\|", (tmp_path / "sweep.md").read_text())
    assert (tmp_path / "sweep.png").exists() and (tmp_path / "sweep.csv").exists()


def test_oracles_sweep_small(exercise, tmp_path):
    """Mitsuba (its own converged render) and POV-Ray (antialiasing) run through the same path."""
    sc, rules = exercise
    res = run.run_sweep(sc, rules, ["mitsuba", "povray"], tmp_path, size=SIZE, repeats=1, knobs=KNOBS)
    for r in res["rows"]:
        assert r["status"] == "ok", r
        if r["backend"] == "povray":  # never a 0-second point: floored at the timer's 1 ms and marked
            assert r["seconds_median"] >= PovrayOracle.SWEEP_RESOLUTION
            assert not r["seconds_at_resolution"] or r["seconds_median"] == PovrayOracle.SWEEP_RESOLUTION
    assert [a["backend"] for a in res["answer"]] == ["mitsuba", "povray"]
    mi = _rows(res, "mitsuba", "spp")
    assert mi[1]["error"]["rmse"] > mi[16]["error"]["rmse"] > 0
    pov = _rows(res, "povray", "antialias")
    assert pov[0]["error"]["rmse"] > pov[2]["error"]["rmse"] > 0
    assert pov[2]["seconds_setup"] > 0.1  # POV-Ray's process start-up, reported apart
    # the exercise's own samples through POV-Ray's mesh camera converge like the reference's samples
    ps = _rows(res, "povray", "samples")
    assert ps[1]["error"]["rmse"] > ps[16]["error"]["rmse"] > 0


def test_povray_antialias_command_line(exercise):
    from minirt.oracles import povray

    sc, _ = exercise
    assert "-A" in povray.command(sc, 1, 1, 1, "exr")
    cmd = povray.command(sc, 1, 1, 1, "exr", antialias=3)
    assert "-A" not in cmd and cmd[cmd.index("+A0.0") + 1] == "+R3"


# ---------------------------------------------------------------------------------------------
# Series as jobs (minirt.jobs.batch): local processes, a cache

SMALL = {"reference": {"spp": (1, 4), "converged_spp": 16}, "embree": {"subdivisions": (0, 1)}}


def _errors(res) -> list:
    return [(r["backend"], r["knob"], r["value"], r["status"], r["error"]) for r in res["rows"]]


@pytest.fixture(scope="module")
def in_process(exercise, tmp_path_factory):
    sc, rules = exercise
    return run.run_sweep(sc, rules, ["reference", "embree"], tmp_path_factory.mktemp("here"), size=8, repeats=1,
                           knobs=SMALL)  # fmt: skip


def test_series_on_worker_processes_give_the_same_rows(exercise, in_process, tmp_path):
    sc, rules = exercise
    calls: list[tuple[int, int, str]] = []
    res = run.run_sweep(sc, rules, ["reference", "embree"], tmp_path, size=8, repeats=1, knobs=SMALL, workers=2,
                          progress=lambda d, t, label: calls.append((d, t, label)))  # fmt: skip
    assert _errors(res) == _errors(in_process)  # the same renders, wherever they ran
    assert res["converged"].keys() == in_process["converged"].keys()
    assert res["jobs"]["workers"] == 2 and in_process["jobs"]["workers"] == 1
    total = len(res["rows"])
    assert [d for d, _, _ in calls] == sorted(d for d, _, _ in calls) and calls[-1][:2] == (total, total)
    assert {label for _, _, label in calls} >= {"reference: done", "embree: done"}  # per series, not per task
    assert json.loads((tmp_path / "sweep.json").read_text())["jobs"]["where"].endswith("cores")


def test_cache_renders_only_the_series_that_changed(exercise, in_process, tmp_path):
    sc, rules = exercise
    cache = tmp_path / "cache"

    def go(knobs):
        return run.run_sweep(sc, rules, ["reference", "embree"], tmp_path / "out", size=8, repeats=1, knobs=knobs,
                               cache=cache)  # fmt: skip

    first = go(SMALL)
    assert first["jobs"]["cached"] == 0 and _errors(first) == _errors(in_process)
    again = go(SMALL)
    assert again["jobs"]["cached"] == 2 and again["rows"] == first["rows"]  # the very rows, times and all
    more = go({**SMALL, "embree": {"subdivisions": (0, 1, 2)}})  # embree's knob changed: its series only
    assert more["jobs"]["cached"] == 1
    assert [r for r in more["rows"] if r["backend"] == "reference"] == [
        r for r in first["rows"] if r["backend"] == "reference"
    ]
    assert sorted(r["value"] for r in more["rows"] if r["backend"] == "embree") == [0, 1, 2]


def test_a_skipped_series_is_not_cached(exercise, tmp_path):
    sc, rules = exercise
    for _ in range(2):
        res = run.run_sweep(sc, rules, ["no-such-backend"], tmp_path / "o", size=8, repeats=1, knobs=SMALL,
                              cache=tmp_path / "c")  # fmt: skip
        assert res["jobs"]["cached"] == 0 and res["rows"][0]["status"] == "skip"


def test_cli_workers_and_scheduler_together_is_one_line(tmp_path):
    both = ["--workers", "2", "--scheduler", "tcp://127.0.0.1:1"]
    p = minirt("sweep", "exercise", "--size", "8", *both, "--out", tmp_path / "o", "-q", cwd=ROOT)  # inproc.py
    assert p.returncode == 2 and p.stderr.strip().splitlines() == [
        "minirt: error: --workers and --scheduler: give one (the cluster has its own workers)"
    ], p.stderr
    assert not (tmp_path / "o").exists()


def test_a_knob_no_backend_has_is_an_error(exercise, tmp_path):
    """Knobs are per backend by name: a misspelt knob or backend would sweep the defaults unnoticed."""
    sc, rules = exercise
    with pytest.raises(ValueError, match="no sweep knob sp "):
        run.run_sweep(sc, rules, ["mitsuba"], tmp_path, size=8, repeats=1, knobs={"mitsuba": {"sp": (1,)}})
    with pytest.raises(ValueError, match="knobs for unknown backend mitsuba3"):
        run.run_sweep(sc, rules, ["mitsuba"], tmp_path, size=8, repeats=1, knobs={"mitsuba3": {"spp": (1,)}})
    assert not (tmp_path / "sweep.json").exists()
