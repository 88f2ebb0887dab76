"""Dr.Jit's LLVM backend, shared by the reference tracer and the Mitsuba oracle: engine checks that
libLLVM is usable (with a message that says how to fix it); arrays hands NumPy arrays to kernels at
the alignment that keeps a kernel compiled once.

May import: minirt.errors, minirt.version.
"""
