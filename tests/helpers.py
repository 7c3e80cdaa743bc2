"""Helpers shared by the tests (non-statistical; statistical ones live in ``stats.py``)."""
from __future__ import annotations

from dyngi.backend import dr


def jit_kernel_hashes() -> set:
    """Hashes of the JIT kernels launched since the last call (reading the history clears it)."""
    return {k["hash"] for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT}


def assert_steady_state_compiles_nothing(step, frames: int, warmup: int, nonempty: bool = False) -> None:
    """Run ``step(f)`` for f = 0..frames-1; from frame ``warmup`` on, every JIT kernel a frame launches
    must be one launched before (kernels compared by hash, not ``cache_hit``: Dr.Jit's on-disk kernel
    cache makes a per-frame recompile a "cache hit"). ``nonempty``: steady frames must launch kernels."""
    seen = set()
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        for f in range(frames):
            dr.kernel_history()   # clears
            step(f)
            hashes = jit_kernel_hashes()
            if f >= warmup:
                assert hashes or not nonempty, f"frame {f} launched no kernels?"
                assert hashes <= seen, f"frame {f} compiled {len(hashes - seen)} new kernels"
            seen |= hashes
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
