"""The interface every oracle implements: minirt.model.backend's Backend, which the reference tracer
implements too. An oracle is an established renderer; its module (or its package's __init__.py) says, at
the top, the conventions it had to bridge, and its class why each of its tolerances is what it is
(geometry_tolerance, beside the derivations). Oracles import only the core (minirt.model, minirt.io,
minirt.jobs, minirt.jit)."""

from __future__ import annotations

from minirt.model.backend import Backend


class Oracle(Backend):
    """An established renderer behind the Backend interface."""
