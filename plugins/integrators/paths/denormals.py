"""The calling thread flushes subnormal floats to zero during a render, as Dr.Jit's pool threads do.

Dr.Jit's pool threads run the ``llvm`` kernels with the x86 MXCSR bits FTZ (results below
1.2e-38 become 0) and DAZ (such inputs read as 0). With ``dr.set_thread_count(1)`` the kernels
run on the calling thread instead, whose MXCSR Python leaves IEEE (subnormals kept): a path
whose energy or derivative passes through a subnormal product then ends differently, and a
render with 1 thread differed from one with 2 (a forward-mode derivative image of the box: 231
bins). `flushing` sets FTZ and DAZ on the calling thread for the length of a render and puts
the caller's floating-point environment back afterwards (NumPy in the same thread sees
subnormals flushed meanwhile). x86-64 with glibc only; elsewhere it does nothing.
"""
from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import platform
import struct

FTZ_DAZ = 0x8040        # MXCSR: flush to zero (bit 15), denormals are zero (bit 6)
_FENV_BYTES = 32        # glibc's x86-64 fenv_t: the x87 environment (28 bytes), then MXCSR
_MXCSR_OFFSET = 28

_libm = None


def _lib():
    global _libm
    if _libm is None:
        _libm = False
        if platform.machine() in ("x86_64", "AMD64") and platform.system() == "Linux":
            name = ctypes.util.find_library("m")
            if name:
                _libm = ctypes.CDLL(name)
    return _libm


@contextlib.contextmanager
def flushing():
    """FTZ and DAZ on the calling thread inside the block (see the module docstring)."""
    lib = _lib()
    if not lib:
        yield
        return
    saved = ctypes.create_string_buffer(_FENV_BYTES)
    if lib.fegetenv(saved) != 0:
        yield
        return
    env = bytearray(saved.raw)
    mxcsr = struct.unpack_from("<I", env, _MXCSR_OFFSET)[0]
    struct.pack_into("<I", env, _MXCSR_OFFSET, mxcsr | FTZ_DAZ)
    lib.fesetenv(ctypes.create_string_buffer(bytes(env), _FENV_BYTES))
    try:
        yield
    finally:
        lib.fesetenv(saved)


def flushed(method):
    """``method`` run inside `flushing` (a decorator for the integrators' render entry points)."""
    import functools

    @functools.wraps(method)
    def run(*args, **kwargs):
        with flushing():
            return method(*args, **kwargs)

    return run
