"""Running work: batch (many independent calls, here or on Dask workers), cache (results by content
hash), processes (child processes and temporary folders that do not outlive minirt), memory (long work
that cannot fit is refused before it starts).

May import: minirt.io, minirt.model, minirt.errors.
"""
