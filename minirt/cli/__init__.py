"""minirt.cli.app."""
