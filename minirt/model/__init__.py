"""minirt.model."""
