"""Oracles: established renderers behind one interface (see oracles/base.py).

Adding a renderer means one new module -- or a subpackage, one job a file, when it grows (povray/,
mitsuba/) -- and one line in REGISTRY. They are imported lazily, so a missing renderer costs nothing
until it is asked for: minirt.harness.backends, the registry of every backend, imports each by the
path given here.

May import: minirt.jobs and below -- never the reference tracer (an oracle is an independent check of
it), the diagnosis, the harness or anything above.
"""

from __future__ import annotations

REGISTRY: dict[str, str] = {
    "mitsuba": "minirt.oracles.mitsuba:MitsubaOracle",
    "povray": "minirt.oracles.povray:PovrayOracle",
    "embree": "minirt.oracles.embree:EmbreeOracle",
    "cycles": "minirt.oracles.cycles:CyclesOracle",
    "exact": "minirt.oracles.exact:ExactOracle",
}
