"""Host arrays copied into Dr.Jit's own memory: :func:`upload`, the one copy every probe-volume and
probe-tracing array takes on its way to the device (the volume's atlases, the ray plans, the techniques'
per-frame tables).

It sits below :mod:`dyngi.probes.volume` and :mod:`dyngi.probes.rays` (both call it, neither imports the
other for it).
"""
from __future__ import annotations

import numpy as np

from ..backend import dr, mi


def upload(array: np.ndarray, cls=None):
    """A flat Dr.Jit array holding a *copy* of ``array`` in memory that Dr.Jit allocated.

    ``mi.Float(numpy_array)`` on the LLVM backend aliases the NumPy memory
    (later host writes show through) and, when that memory is not 16-byte
    aligned, Dr.Jit silently falls back from packet gathers to one gather per
    component -- a different kernel, i.e. a recompile, depending on where NumPy
    happened to allocate. Scattering into a Dr.Jit allocation avoids both.
    The copy kernel itself reads the NumPy memory, and its code depends on
    that memory's alignment too (a recompile for small arrays that NumPy put
    at a 16- rather than 64-byte boundary): the data is first staged in a
    64-byte aligned host buffer.
    """
    cls = cls or mi.Float
    a = _aligned(np.ascontiguousarray(array).ravel())
    out = dr.empty(cls, a.size)
    dr.scatter(out, cls(a), dr.arange(mi.UInt32, a.size))
    dr.eval(out)
    return out


HOST_ALIGNMENT = 64   # bytes: the alignment Dr.Jit's LLVM kernels assume for their widest loads


def _aligned(a: np.ndarray) -> np.ndarray:
    """``a`` itself if its data is ``HOST_ALIGNMENT``-aligned, else an aligned copy."""
    if a.ctypes.data % HOST_ALIGNMENT == 0:
        return a
    buf = np.empty(a.nbytes + HOST_ALIGNMENT, np.uint8)
    off = (-buf.ctypes.data) % HOST_ALIGNMENT
    out = buf[off:off + a.nbytes].view(a.dtype)
    out[...] = a
    return out
