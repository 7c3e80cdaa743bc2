"""Helpers shared by the tests (non-statistical; statistical ones live in ``stats.py``)."""
from __future__ import annotations

import contextlib

from dyngi.backend import dr


def jit_kernel_hashes() -> set:
    """Hashes of the JIT kernels launched since the last call (reading the history clears it)."""
    return {k["hash"] for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT}


def assert_steady_state_compiles_nothing(step, frames: int, warmup: int, nonempty: bool = False) -> None:
    """Run ``step(f)`` for f = 0..frames-1; from frame ``warmup`` on, every JIT kernel a frame launches
    must be one launched before (kernels compared by hash, not ``cache_hit``: Dr.Jit's on-disk kernel
    cache makes a per-frame recompile a "cache hit"). ``nonempty``: steady frames must launch kernels.
    Between frames the host heap is shifted (a few small NumPy buffers kept alive), so a kernel whose IR
    depends on where NumPy's allocator put a buffer -- Dr.Jit maps a NumPy array without a copy and emits
    ``align 64`` or ``align 1`` loads by its address (:func:`dyngi.backend.upload`) -- fails here every run,
    not only when CI's heap happens to differ."""
    import numpy as np

    seen = set()
    pad = []
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        for f in range(frames):
            # take the freed host chunks of every size and shift the heap's top by 16 * f bytes
            pad.append([np.empty(int(n) + 16 * f, np.uint8) for n in np.geomspace(600, 1 << 20, 64)])
            dr.kernel_history()   # clears
            step(f)
            hashes = jit_kernel_hashes()
            if f >= warmup:
                assert hashes or not nonempty, f"frame {f} launched no kernels?"
                assert hashes <= seen, f"frame {f} compiled {len(hashes - seen)} new kernels"
            seen |= hashes
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)


class HostRead(AssertionError):
    """A Dr.Jit array was read back to the host inside :func:`no_host_reads`."""


@contextlib.contextmanager
def _on_host_reads(hook, element_types=None, truth: bool = True):
    """Call ``hook(array, original_method, *args)`` on every Dr.Jit -> host transfer (NumPy conversion,
    DLPack, ``.numpy()``, ``tolist``, a truth value, an element read) inside the block."""
    from dyngi.backend import mi

    names = ("__array__", "__dlpack__", "numpy", "tolist") + (("__bool__",) if truth else ())
    patched = [(dr.ArrayBase, name) for name in names]
    patched += [(cls, "__getitem__") for cls in (element_types or (mi.Float, mi.UInt32, mi.Int32, mi.Bool,
                                                                   mi.UInt64, mi.Float64))]
    saved = [(cls, name, cls.__dict__[name]) for cls, name in patched if name in cls.__dict__]

    def wrap(fn):
        def reader(self, *a, **k):
            return hook(self, fn, *a, **k)
        return reader
    for cls, name, fn in saved:
        setattr(cls, name, wrap(fn))
    try:
        yield
    finally:
        for cls, name, fn in saved:
            setattr(cls, name, fn)


@contextlib.contextmanager
def no_host_reads(compress: bool = False):
    """Any Dr.Jit -> host transfer raises :class:`HostRead` inside the block; ``compress``: so does
    ``dr.compress`` (its output width is a host sync)."""
    def refuse(*a, **k):
        raise HostRead("a Dr.Jit array was read back to the host")

    saved = dr.compress
    if compress:
        dr.compress = lambda *a, **k: (_ for _ in ()).throw(HostRead("dr.compress (a host sync of its width)"))
    try:
        with _on_host_reads(refuse):
            yield
    finally:
        dr.compress = saved


@contextlib.contextmanager
def count_host_reads(log: list):
    """Append the width of every Dr.Jit -> host transfer inside the block to ``log`` (truth values are not
    counted)."""
    from dyngi.backend import mi

    def record(arr, fn, *a, **k):
        log.append(dr.width(arr))
        return fn(arr, *a, **k)
    with _on_host_reads(record, (mi.Float, mi.UInt32, mi.Int32, mi.Bool), truth=False):
        yield
