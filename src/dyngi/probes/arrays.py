"""Host arrays copied into Dr.Jit's own memory: :func:`upload`, the one copy every probe-volume and
probe-tracing array takes on its way to the device (the volume's atlases, the ray plans, the techniques'
per-frame tables).

It sits below :mod:`dyngi.probes.volume` and :mod:`dyngi.probes.rays` (both call it, neither imports the
other for it).
"""
from __future__ import annotations

import numpy as np

from ..backend import mi
from ..backend import upload as backend_upload


def upload(array: np.ndarray, cls=None):
    """A flat Dr.Jit array (``cls``, default ``mi.Float``) holding a *copy* of ``array`` in memory that Dr.Jit
    allocated: :func:`dyngi.backend.upload` on the flattened array (one copy rule for every layer).

    ``mi.Float(numpy_array)`` on the LLVM backend aliases the NumPy memory (later host writes show through),
    and the kernels that read it depend on that memory's alignment (a recompile, depending on where NumPy
    happened to allocate); the backend's copy avoids both."""
    cls = cls or mi.Float
    a = np.ascontiguousarray(array).ravel()
    return backend_upload(cls, a) if a.size else cls()
