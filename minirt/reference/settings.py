"""What the reference's parts read while they build a kernel: the scene, its rules, the precision's
types, the scene's values, the effects simulated, and two switches. Plain data, no methods.

The parts (minirt.reference.interaction, shading, integrator, sampling) take a ``TraceSettings`` as their
first argument, ``tr``, and read only these fields, so they depend on this module and on each other,
never on the façade that assembles them (minirt.reference.tracer.Tracer, which is a ``TraceSettings``
with the methods that render). pbrt-v4 draws the same line: its interaction.h needs only ray.h and the
base types, and its OffsetRayOrigin takes plain data.
"""

from __future__ import annotations

from dataclasses import dataclass

from minirt.model.effects import Effects
from minirt.model.rules import Rules
from minirt.model.scene import Scene
from minirt.reference.values import Candidates, Types, Values


@dataclass(eq=False, repr=False)
class TraceSettings:
    """One scene under one set of rules, as the kernels see it.

    ``T``: the Dr.Jit types of the precision (``values.Types``); ``values``: how the kernels read the
    scene (constants unrolled, or the shape table's arrays: ``values.Values``); ``effects``: the terms
    simulated (after pruning); ``runtime``: the rules a search varies are values read at run time rather
    than constants compiled in (``Tracer``'s docstring); ``prune``: per-ray pruning of work that cannot
    change a pixel is on; ``looped``: the first level is the loop's first iteration and the image's width
    a value the kernel reads, however many rays (else only below ``integrator.LOOP_FIRST_LEVEL_BELOW``).
    Mutable as the tracer's attributes always were: a test or the campaign may replace ``effects`` (a
    tracer that forgets a term) before tracing.
    """

    scene: Scene
    rules: Rules | Candidates  # Candidates: several rule sets in one kernel (Tracer's batch)
    T: Types
    values: Values
    effects: Effects
    runtime: bool
    prune: bool
    looped: bool
