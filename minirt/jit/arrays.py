"""NumPy arrays handed to Dr.Jit's LLVM backend.

Dr.Jit takes a contiguous NumPy array of the right type in place and compiles a kernel's loads of it
with the alignment its address happens to have (``align 64`` or ``align 1``): the same code on an array
that NumPy's allocator placed elsewhere is then another kernel, which misses the kernel cache and is
compiled again -- measured: Mitsuba rendering three_balls a second time in the same process compiled 87
of its 282 kernels again (1.8 s). ``aligned`` copies into memory at a 64-byte boundary, so a kernel
depends on its code alone.
"""

from __future__ import annotations

from typing import Any

import numpy as np

ALIGN = 64  # bytes: a cache line, the widest vector load (AVX-512)


def aligned(a: Any, dtype: Any) -> np.ndarray:
    """A C-contiguous copy of ``a`` as ``dtype`` starting at an ALIGN-byte boundary."""
    a = np.asarray(a, dtype=dtype)
    out = empty(a.shape, a.dtype)
    np.copyto(out, a)
    return out


def empty(shape: Any, dtype: Any = np.float64) -> np.ndarray:
    """An uninitialised C-contiguous array starting at an ALIGN-byte boundary (to fill in place)."""
    dtype = np.dtype(dtype)
    nbytes = int(np.prod(shape)) * dtype.itemsize
    buf = np.empty(nbytes + ALIGN, dtype=np.uint8)
    start = -buf.ctypes.data % ALIGN
    return buf[start : start + nbytes].view(dtype).reshape(shape)
