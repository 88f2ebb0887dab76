"""minirt.jobs.batch."""
