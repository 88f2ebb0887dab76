"""minirt.harness."""
