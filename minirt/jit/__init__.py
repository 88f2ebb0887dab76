"""minirt.jit."""
