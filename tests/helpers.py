"""Helpers shared by the tests (non-statistical; statistical ones live in ``stats.py``)."""
from __future__ import annotations

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
    not only when CI's heap happens to differ (issue 36)."""
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
