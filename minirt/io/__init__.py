"""Files in and out: images (every image through OpenImageIO), atomic writes (atomic: the one writer
of every file minirt produces, exports included -- a file appears whole or not at all, a planted
symlink is replaced, never written through), JSON documents (jsonout: strict, versioned; documents:
their pydantic models and the shipped schemas), output names (names) and untrusted text (untrusted:
text from a scene file or a renderer made safe for a terminal, a page, XML, a CSV cell or a file name).

May import: minirt.model, minirt.errors, minirt.version -- not Dr.Jit's kernels.
"""
