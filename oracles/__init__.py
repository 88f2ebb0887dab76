"""Oracles: established renderers behind one interface (see oracles/base.py).

Adding a renderer means one new module -- or a subpackage, one job a file, when it grows (povray/,
mitsuba/) -- and one line in REGISTRY. They are imported lazily, so a missing renderer costs nothing
until it is asked for.
"""

from __future__ import annotations

import importlib

from minirt.oracles.base import Oracle

REGISTRY: dict[str, str] = {
    "mitsuba": "minirt.oracles.mitsuba:MitsubaOracle",
    "povray": "minirt.oracles.povray:PovrayOracle",
    "embree": "minirt.oracles.embree:EmbreeOracle",
    "cycles": "minirt.oracles.cycles:CyclesOracle",
    "exact": "minirt.oracles.exact:ExactOracle",
}


def names() -> list[str]:
    return list(REGISTRY)


def get(name: str) -> Oracle:
    """The oracle called `name` (KeyError for an unknown one)."""
    module, cls = REGISTRY[name].split(":")
    return getattr(importlib.import_module(module), cls)()
