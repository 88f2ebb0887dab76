"""minirt.io.jsonout, the one writer of JSON: strict (no NaN/Infinity), versioned, reasons beside nulls."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from minirt.io import jsonout


def strict_loads(text: str):
    def reject(c):
        raise ValueError(f"not strict JSON: {c}")

    return json.loads(text, parse_constant=reject)


def test_non_finite_numbers_become_null_with_a_reason():
    d = strict_loads(
        jsonout.dumps(
            {
                "a": math.inf,
                "b": -np.float32("inf"),
                "c": float("nan"),
                "d": 1.5,
                "nested": {"t_abs_max": np.inf, "t_abs_max_reason": "infinite: unlimited on misses"},
                "xs": [1.0, math.inf, np.float64("nan")],
                "arr": np.array([0.5, np.inf]),
            }
        )
    )
    assert d["schema_version"] == jsonout.SCHEMA_VERSION == 1
    assert (d["a"], d["b"], d["c"], d["d"]) == (None, None, None, 1.5)
    assert (d["a_reason"], d["b_reason"], d["c_reason"]) == ("infinite", "-infinite", "not a number")
    assert "d_reason" not in d
    # a producer's own reason is kept as written
    assert d["nested"] == {"t_abs_max": None, "t_abs_max_reason": "infinite: unlimited on misses"}
    assert d["xs"] == [1.0, None, None] and d["xs_reason"] == "entries 1: infinite, 2: not a number"
    assert d["arr"] == [0.5, None] and d["arr_reason"] == "entries 1: infinite"


def test_types_are_converted_and_output_is_deterministic(tmp_path):
    data = {"p": Path("x/y.png"), "n": np.int64(3), "t": (1, 2), "s": {3, 1}, 2: "int key"}
    text = jsonout.dumps(data)
    assert text == jsonout.dumps(dict(reversed(list(data.items()))))  # key order does not matter
    d = strict_loads(text)
    assert d == {"schema_version": 1, "p": "x/y.png", "n": 3, "t": [1, 2], "s": [1, 3], "2": "int key"}


def test_an_unknown_type_raises_before_any_file_is_written(tmp_path):
    out = tmp_path / "x.json"
    with pytest.raises(TypeError, match="not JSON serialisable: object"):
        jsonout.write_json(out, {"bad": object()})
    assert list(tmp_path.iterdir()) == []  # no half-written file, no temporary left behind


def test_allow_nan_false_is_the_last_guard(monkeypatch):
    monkeypatch.setattr(jsonout, "strict", lambda o: o)  # a conversion that misses a value
    with pytest.raises(ValueError, match="not JSON compliant"):
        jsonout.dumps({"x": math.inf})


def test_emit_json_dash_is_stdout(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    jsonout.emit_json("-", {"v": math.inf})
    assert strict_loads(capsys.readouterr().out) == {"schema_version": 1, "v": None, "v_reason": "infinite"}
    assert not (tmp_path / "-").exists()
    jsonout.emit_json(str(tmp_path / "f.json"), {"v": 1})
    assert strict_loads((tmp_path / "f.json").read_text())["v"] == 1
