"""minirt.jit.arrays: NumPy arrays for Dr.Jit at 64-byte boundaries, whatever NumPy's allocator does, and a
kernel that reads one compiled once whichever array it reads."""

from __future__ import annotations

import drjit as dr
import numpy as np
import pytest

from minirt.jit import arrays as jitmem


@pytest.mark.parametrize("dtype", [np.float64, np.float32, np.uint32, np.int32, bool])
@pytest.mark.parametrize("n", [0, 1, 3, 17, 1000, 100_003])
def test_aligned_copy(dtype, n):
    src = np.arange(n * 2)[1::2] % 7  # a strided view: not contiguous
    a, e = jitmem.aligned(src, dtype), jitmem.empty((n, 2), dtype)
    assert a.flags.c_contiguous and a.dtype == np.dtype(dtype) and np.array_equal(a, src.astype(dtype))
    assert e.flags.c_contiguous and e.dtype == np.dtype(dtype) and e.shape == (n, 2)
    if n:  # (an empty array's address is NumPy's to choose, and nothing is read from it)
        assert a.ctypes.data % jitmem.ALIGN == 0 and e.ctypes.data % jitmem.ALIGN == 0


def test_one_kernel_for_arrays_wherever_numpy_put_them():
    """The same code on inputs at different offsets from a cache line: Dr.Jit compiles the offset into
    the loads (a kernel per alignment); aligned copies make it one kernel."""

    def compiled(arrays) -> int:
        with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
            dr.kernel_history()
            for a in arrays:
                x = dr.llvm.Float64(a)
                dr.eval(x * 3.25 + 0.5)
            hist = [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]
        return len({k["hash"] for k in hist})

    raw = np.random.default_rng(1).random(4100)
    offsets = [raw[k : k + 4000] for k in range(8)]  # views 8 bytes apart: every offset in a cache line
    assert compiled([np.ascontiguousarray(a) for a in offsets]) > 1  # what happened before
    assert compiled([jitmem.aligned(a, np.float64) for a in offsets]) == 1
