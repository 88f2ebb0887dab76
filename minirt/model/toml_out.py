"""Scene documents written as TOML: the subset the scene format uses (tables of scalars and arrays, tables
of tables, arrays of tables). Python's tomllib reads TOML but does not write it; the campaign's generated
scenes and a program's scene files (minirt.oracles.program) are written here, numbers in their shortest
round-trip form so that a scene reads back as the same doubles."""

from __future__ import annotations

import json
import math
import re
from typing import Any

_BARE = re.compile(r"^[A-Za-z0-9_-]+$")


def _key(k: str) -> str:
    return k if _BARE.match(k) else json.dumps(k)


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            raise ValueError(f"not a finite number: {v!r}")
        return repr(v)  # shortest round-trip form, valid TOML (1e-07, -0.0, 12345.0)
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)  # JSON's escapes are TOML basic-string escapes
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} as TOML")


def dump_toml(doc: dict[str, Any]) -> str:
    """A scene document (tables of scalars and arrays, tables of tables, arrays of tables) as TOML."""
    out: list[str] = []
    for name, table in doc.items():
        if isinstance(table, list):
            for item in table:
                out.append(f"[[{_key(name)}]]")
                out += [f"{_key(k)} = {_value(v)}" for k, v in item.items()]
        elif table and all(isinstance(v, dict) for v in table.values()):
            for sub, t in table.items():
                out.append(f"[{_key(name)}.{_key(sub)}]")
                out += [f"{_key(k)} = {_value(v)}" for k, v in t.items()]
        else:
            out.append(f"[{_key(name)}]")
            out += [f"{_key(k)} = {_value(v)}" for k, v in table.items()]
    return "\n".join(out) + "\n"
