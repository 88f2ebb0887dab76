"""The `minirt` command line (its entry point: minirt.cli.app.main): parsing and printing, nothing else."""
