"""Random-number streams seeded from (seed, frame, index), never from a global RNG.

The frame-varying part of a seed enters kernels as an opaque value
(``dr.opaque``), so a new frame does not recompile anything.
"""
from __future__ import annotations

from ..backend import dr, mi


def mix_seed(seed: int, frame: int, stream: int = 0) -> int:
    """Hash (seed, frame, stream) to a 32-bit integer (splitmix-style, host side)."""
    x = (int(seed) * 0x9E3779B97F4A7C15 + int(frame) * 0xBF58476D1CE4E5B9 + int(stream) * 0x94D049BB133111EB)
    x &= (1 << 64) - 1
    x ^= x >> 30
    x = (x * 0xBF58476D1CE4E5B9) & ((1 << 64) - 1)
    x ^= x >> 27
    x = (x * 0x94D049BB133111EB) & ((1 << 64) - 1)
    x ^= x >> 31
    return x & 0xFFFFFFFF


def make_sampler(n: int, seed: int, frame: int, stream: int = 0) -> "mi.Sampler":
    """An ``independent`` Mitsuba sampler for ``n`` lanes with an opaque per-frame seed."""
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(dr.opaque(mi.UInt32, mix_seed(seed, frame, stream)), n)
    return sampler
