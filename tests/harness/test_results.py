"""A check's results (minirt.harness.results): the order of verdicts, the exit code, and when a backend is
inconclusive."""

from __future__ import annotations

from minirt.harness.results import BackendCheck, Check, CheckResult, worst


def test_verdict_order():
    assert worst(["pass", "skip", "warn"]) == "warn"
    assert worst(["pass", "fail", "error"]) == "error"
    assert worst(["skip", "skip"]) == "skip"
    assert CheckResult("fail", []).exit_code() == 1
    assert CheckResult("error", []).exit_code() == 2
    assert CheckResult("warn", []).exit_code() == 0


def test_a_backend_is_inconclusive_only_when_all_its_warnings_are():
    checks = {
        "geometry": Check("warn", reason="inconclusive: this oracle cannot judge this scene (x)"),
        "shading": Check("warn", reason="CIEDE2000 p95 1.50"),
    }
    b = BackendCheck("synthetic", "warn", checks=checks)
    assert not b.inconclusive  # the shading warning is a finding of its own
    b.checks.pop("shading")
    assert b.inconclusive and b.as_dict()["inconclusive"] is True
