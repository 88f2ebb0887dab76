"""minirt.diagnose.search."""
