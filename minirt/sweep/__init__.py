"""minirt.sweep.sweep."""
