"""The backend's upload: host arrays in Dr.Jit's own memory, so kernels do not depend on NumPy's heap."""
from __future__ import annotations

import numpy as np
import pytest

from dyngi.backend import dr, mi, upload


def _downstream_hash(x) -> str:
    """Hash of the kernel that loads ``x`` directly (``x * 3 + 1``, evaluated alone)."""
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history()
        y = x * 3 + 1
        dr.eval(y)
        return [k["hash"] for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT][-1]
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)


def _at_offset(values: np.ndarray, offset: int) -> np.ndarray:
    """``values`` copied into a buffer that starts ``offset`` bytes past a 64-byte boundary."""
    raw = np.empty(values.nbytes + 128, np.uint8)
    skip = (-raw.ctypes.data) % 64 + offset
    out = raw[skip:skip + values.nbytes].view(values.dtype)
    out[:] = values
    return out


@pytest.mark.parametrize("T, dtype", [("Float", np.float32), ("UInt32", np.uint32), ("Int32", np.int32)])
def test_upload_gives_one_kernel_for_any_host_alignment(backend, T, dtype):
    """A kernel reading an uploaded array has one hash whether NumPy's buffer sat on a 64-byte boundary or
    4 / 16 / 32 bytes past one, and the values are copied exactly (a mapped buffer gives two hashes,
    and a steady frame recompiled whenever the heap's alignment differed)."""
    T = getattr(mi, T)
    vals = (np.arange(1000) * 7 % 101 - 50).astype(dtype)
    hashes, arrays = set(), []
    for off in (0, 4, 16, 32):
        host = _at_offset(vals, off)
        assert host.ctypes.data % 64 == off
        x = upload(T, host)
        arrays.append(x)
        hashes.add(_downstream_hash(x))
        np.testing.assert_array_equal(np.asarray(x), vals)
    assert len(hashes) == 1, hashes


def test_upload_many_arrays_in_one_call(backend):
    a, b = np.linspace(-1, 1, 37, dtype=np.float32), np.linspace(3, 4, 37, dtype=np.float32)
    x, y = upload(mi.Float, a, b)
    np.testing.assert_array_equal(np.asarray(x), a)
    np.testing.assert_array_equal(np.asarray(y), b)
    assert np.asarray(upload(mi.Float, np.float32([-0.0])))[0] == 0.0 and \
        np.signbit(np.asarray(upload(mi.Float, np.float32([-0.0])))[0])
