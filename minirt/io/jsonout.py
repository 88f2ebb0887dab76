"""Every JSON document minirt writes goes through here: strict JSON, versioned, atomic.

Strict means what a browser's ``JSON.parse`` accepts: no ``NaN``, ``Infinity`` or ``-Infinity``.
A non-finite number becomes ``null`` and a sibling key ``<key>_reason`` says what it was, e.g.
``"t_abs_max": null, "t_abs_max_reason": "infinite: no bound on pixels the oracle misses"``. A
producer that knows why a value is not finite puts that reason in the sibling key itself (its text
is kept); otherwise the reason is generic (``"infinite"``, ``"-infinite"``, ``"not a number"``). A
list with non-finite entries gets one reason for the list (``"<key>_reason": "entries 0, 2: infinite"``).
``json.dumps(..., allow_nan=False)`` then raises on anything the conversion missed, so a regression
fails loudly instead of writing invalid JSON.

Each top-level document carries ``"schema_version": SCHEMA_VERSION``; the JSON Schemas of the
documents (minirt.io.documents) are shipped in ``minirt/io/schemas/``.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

from minirt.io.atomic import atomic_path

SCHEMA_VERSION = 1
REASON_SUFFIX = "_reason"


def describe(x: float) -> str:
    """The generic reason for a non-finite number."""
    if math.isnan(x):
        return "not a number"
    return "infinite" if x > 0 else "-infinite"


def _nonfinite(o: Any) -> bool:
    return isinstance(o, float) and not math.isfinite(o)


def strict(o: Any) -> Any:
    """Plain JSON data (dict, list, str, int, float, bool, None) from ``o``: NumPy values, paths,
    pydantic models and objects with ``as_dict()`` converted; non-finite numbers as ``None`` with their
    reasons beside (see the module's docstring)."""
    o = _plain(o)
    if isinstance(o, dict):
        out: dict[str, Any] = {}
        reasons: dict[str, str] = {}
        for k, v in o.items():
            key = str(k)
            v = _plain(v)
            if _nonfinite(v):
                out[key] = None
                reasons[key + REASON_SUFFIX] = describe(v)
            elif isinstance(v, list) and (bad := _bad_entries(v)):
                out[key] = strict(v)
                reasons[key + REASON_SUFFIX] = "entries " + ", ".join(f"{i}: {why}" for i, why in bad)
            else:
                out[key] = strict(v)
        for rk, why in reasons.items():  # a producer's own reason is kept
            if not (isinstance(out.get(rk), str) and out[rk]):
                out[rk] = why
        return out
    if isinstance(o, list):
        return [None if _nonfinite(x) else strict(x) for x in (_plain(v) for v in o)]
    if _nonfinite(o):
        return None
    return o


def _bad_entries(v: list[Any]) -> list[tuple[int, str]]:
    out = []
    for i, x in enumerate(v):
        x = _plain(x)
        if _nonfinite(x):
            out.append((i, describe(x)))
        elif isinstance(x, list) and _bad_entries(x):
            out.append((i, "non-finite entries"))
    return out


def _plain(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, tuple | set | frozenset):
        return sorted(o) if isinstance(o, set | frozenset) else list(o)
    if isinstance(o, Path):
        return str(o)
    if hasattr(o, "model_dump"):  # a pydantic model
        return o.model_dump(mode="python")
    if hasattr(o, "as_dict") and not isinstance(o, dict):
        return o.as_dict()
    if isinstance(o, dict | list | str | int | float | bool) or o is None:
        return o
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def document(data: dict[str, Any]) -> dict[str, Any]:
    """A top-level document: strict, with ``schema_version``."""
    body = strict(data)
    if not isinstance(body, dict):
        raise TypeError(f"a JSON document is an object, not {type(body).__name__}")
    body.pop("schema_version", None)
    return {"schema_version": SCHEMA_VERSION, **body}


def dumps(data: dict[str, Any]) -> str:
    """The document's text: indented, keys sorted (the same data gives the same bytes), strict."""
    return json.dumps(document(data), indent=2, sort_keys=True, allow_nan=False) + "\n"


def write_json(path: str | Path, data: dict[str, Any]) -> None:
    """Write the document atomically (never a half-written file: the text is made before the file)."""
    text = dumps(data)
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def emit_json(dest: str | Path, data: dict[str, Any]) -> None:
    """``--json DEST``: ``-`` writes the document to standard output, anything else is a file."""
    if str(dest) == "-":
        text = dumps(data)
        sys.stdout.write(text)
        sys.stdout.flush()
        return
    write_json(dest, data)
