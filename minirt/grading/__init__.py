"""minirt.grading."""
