"""The bundled scenes, installed as the package data ``minirt.scene_files`` (see pyproject.toml).

Only the *.toml files and samples/ matter here; minirt.scenes finds them by name.
"""
