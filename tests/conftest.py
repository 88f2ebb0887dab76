from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SCENES = sorted((ROOT / "scenes").glob("*.toml"))
sys.path.insert(0, str(Path(__file__).resolve().parent))  # the helpers: from support.plain import ...


@pytest.fixture(params=[p.stem for p in SCENES])
def scene_path(request) -> Path:
    return ROOT / "scenes" / f"{request.param}.toml"


# Test modules whose tests share a module-scoped fixture (a render, a command's output, a campaign on a
# cluster, a diagnosis cache): each runs on one pytest-xdist worker, so the fixture is made once, not
# once per worker that gets one of its tests. (Not xdist_group marks: xdist 3.8's loadgroup tags a
# marked test by rewriting Item._nodeid, which pytest 9 no longer reads, so the marks group nothing.)
SHARED_FIXTURE_MODULES = frozenset(
    f"tests/{m}.py"
    for m in (
        "package/test_bench", "harness/test_check_diagnosis", "diagnose/test_diagnose", "campaign/test_fuzz",
        "cli/test_grade_cli", "grading/test_class_hostile", "grading/test_grade_page", "harness/test_harness",
        "harness/test_geometry", "harness/test_shading", "io/test_json_documents", "jobs/test_memory",
        "oracles/test_oracle_mitsuba", "oracles/test_oracle_povray", "oracles/test_oracle_cycles",
        "reference/test_probe_image", "pages/test_report", "reference/test_start_band", "sweep/test_sweep",
        "program/test_program_check", "program/test_program_class", "program/test_program_suite",
    )
)  # fmt: skip


def pytest_xdist_make_scheduler(config, log):
    """``--dist loadgroup`` (pyproject.toml): the tests of SHARED_FIXTURE_MODULES as one unit per module,
    every other test on its own, each unit to whichever worker is free."""
    if config.getvalue("dist") != "loadgroup":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class SharedFixtureModules(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            module = nodeid.split("::", 1)[0]
            return module if module in SHARED_FIXTURE_MODULES else nodeid

    return SharedFixtureModules(config, log)


def pytest_xdist_auto_num_workers(config):
    """``-n auto``: a worker per core and as many again (at most four more). Much of the suite waits
    rather than computes -- POV-Ray's front end polls in 10-100 ms sleeps (a 16x16 render: 1.4 s of wall
    time, milliseconds of CPU), child processes and Dask clusters start -- so one worker per core leaves
    the cores idle about half the time: tests/harness/test_regression.py in one worker took 45 s of CPU in 93 s;
    on 2 cores, 4 workers ran it in 30.5 s, 2 workers in 44.9 s. PYTEST_XDIST_AUTO_NUM_WORKERS, when set,
    still decides (xdist's own hook reads it)."""
    if os.environ.get("PYTEST_XDIST_AUTO_NUM_WORKERS"):
        return None
    from minirt.jobs.batch import cores

    n = cores()
    return n + min(n, 4)
