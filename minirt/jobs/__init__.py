"""Running work: batch (many independent calls, here or on Dask workers), cluster (the embedded Dask
cluster, in a session of its own) and worker (its worker processes' set-up), logs (Dask's records as one
line), cache (results by content hash) and data (the cache's format: data, never code, and the schemas
results are checked against), processes (child processes and temporary folders that do not outlive
minirt), memory (long work that cannot fit is refused before it starts).

May import: minirt.io, minirt.model, minirt.errors, minirt.version -- not Dr.Jit's kernels.
"""
