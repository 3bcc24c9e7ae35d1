"""Host arrays handed to Dr.Jit kernels.

Dr.Jit's LLVM backend maps a NumPy array's memory instead of copying it, and compiles the kernels
that read it for that pointer's alignment: a whole vector's worth or none. NumPy's allocations
land on either by chance, so the same render would now and then compile its path kernel again
(about a second) for arrays that only changed address. Uploading through a buffer aligned to
256 bytes (a 16-lane vector of float64 needs 128) gives every upload the aligned form.
"""
from __future__ import annotations

import drjit as dr
import numpy as np

_ALIGN = 256


def upload(jit_type, values, dtype):
    """``jit_type`` (e.g. ``mi.Float``) holding ``values`` as a flat ``dtype`` array, in memory
    whose alignment does not change from call to call."""
    a = np.asarray(values, dtype=dtype).ravel()
    buf = np.empty(a.nbytes + _ALIGN, dtype=np.uint8)
    start = -buf.ctypes.data % _ALIGN
    out = buf[start:start + a.nbytes].view(dtype)
    out[:] = a
    arr = jit_type(out)
    dr.make_opaque(arr)  # one element would otherwise become a literal, baked into the kernel
    return arr
