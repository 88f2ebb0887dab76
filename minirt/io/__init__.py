"""Files in and out: images (every image through OpenImageIO), atomic writes (a file appears whole or
not at all), JSON documents (jsonout: strict, versioned; documents: their pydantic models and the
shipped schemas), output names (names) and untrusted text (untrusted: text from a scene file or a
renderer made safe for a terminal or a file name).

May import: minirt.model, minirt.errors, minirt.version -- not Dr.Jit's kernels.
"""
