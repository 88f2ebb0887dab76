"""minirt.io."""
