"""minirt.pages."""
