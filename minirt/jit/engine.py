"""Dr.Jit's LLVM backend: check that it is usable before tracing, with a message that says how to fix it.

Dr.Jit loads the system's libLLVM at run time. It needs LLVM >= 19 (Debian ``libllvm19``): with
LLVM 15 some float kernels abort the whole process, and LLVM 14 is refused. ``DRJIT_LIBLLVM_PATH``
overrides the library Dr.Jit picks.
"""

from __future__ import annotations

import contextlib
import functools

from minirt.errors import MinirtError

MIN_LLVM = (19, 0, 0)
INSTALL_HINT = "install it with: sudo apt-get install -y libllvm19 (or point DRJIT_LIBLLVM_PATH at libLLVM >= 19)"


@functools.cache
def llvm_status() -> tuple[bool, str]:
    """(usable, description) of Dr.Jit's LLVM backend."""
    try:
        import drjit as dr
    except ImportError as e:  # pragma: no cover - drjit is a hard dependency
        return False, f"drjit is not installed ({e})"
    if not dr.has_backend(dr.JitBackend.LLVM):
        return False, f"Dr.Jit found no libLLVM; {INSTALL_HINT}"
    version = tuple(dr.detail.llvm_version())
    if version < MIN_LLVM:
        shown = ".".join(map(str, version))
        return False, f"Dr.Jit loaded libLLVM {shown}, but >= 19 is needed; {INSTALL_HINT}"
    return True, "libLLVM " + ".".join(map(str, version))


def require_llvm() -> None:
    ok, why = llvm_status()
    if not ok:
        raise MinirtError(why)


@contextlib.contextmanager
def threads(n: int):
    """Dr.Jit's thread pool at ``n`` threads within the block, as it was after (the pool is the process's)."""
    import drjit as dr

    before = dr.thread_count()
    if before == n:
        yield
        return
    dr.set_thread_count(n)
    try:
        yield
    finally:
        dr.set_thread_count(before)
