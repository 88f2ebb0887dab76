"""minirt.reference."""
