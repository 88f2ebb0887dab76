"""minirt's version: one place, imported by the package root and by whatever records it in a result."""

__version__ = "0.1.0"
