"""minirt: a reference ray tracer for ETH Informatik I problem 13.1, and the harness that checks it."""

__version__ = "0.1.0"
