"""Spherical Fibonacci point sets and random rotations.

DDGI (Majercik et al., JCGT 2019, Sec. 3.1) traces the rays of every probe
along one spherical-Fibonacci set (Keinert et al. 2015) of ``n`` directions,
re-oriented every frame by a fresh uniformly random rotation so that, over
frames, the directions cover the sphere densely.

Point ``i`` of ``n``: ``z_i = 1 - (2 i + 1) / n``, ``phi_i = 2 pi frac(i (phi_g - 1))``
with the golden ratio ``phi_g``; each point stands for the solid angle
``4 pi / n`` (the set is equal-area by construction).

The uniform random rotation comes from three uniforms (Arvo, "Fast random
rotation matrices", Graphics Gems III, 1992): a rotation about the pole by
``2 pi u1`` followed by a Householder reflection that sends the pole to a
uniformly distributed direction chosen by ``(u2, u3)``.
"""
from __future__ import annotations

import numpy as np

from ..backend import dr, mi
from .octahedral import oct_encode_np

GOLDEN_FRACTION = (np.sqrt(5.0) + 1.0) * 0.5 - 1.0


def spherical_fibonacci_np(n: int) -> np.ndarray:
    """(n, 3) float64 spherical-Fibonacci directions (unit vectors)."""
    i = np.arange(int(n), dtype=np.float64)
    phi = 2.0 * np.pi * np.mod(i * GOLDEN_FRACTION, 1.0)
    cos_t = 1.0 - (2.0 * i + 1.0) / n
    sin_t = np.sqrt(np.clip(1.0 - cos_t * cos_t, 0.0, 1.0))
    return np.stack([np.cos(phi) * sin_t, np.sin(phi) * sin_t, cos_t], -1)


def _part1by1(x: np.ndarray) -> np.ndarray:
    """Spread the low 16 bits of ``x`` to the even bit positions (2-D Morton codes)."""
    x = x.astype(np.uint64) & 0xFFFF
    x = (x | (x << 8)) & 0x00FF00FF
    x = (x | (x << 4)) & 0x0F0F0F0F
    x = (x | (x << 2)) & 0x33333333
    return (x | (x << 1)) & 0x55555555


def coherent_order(dirs: np.ndarray, bits: int = 10) -> np.ndarray:
    """Permutation of (n, 3) unit directions along a Morton curve on the octahedral map.

    The order of a direction set does not change what a probe update
    estimates, but rays are traced in SIMD packets of consecutive indices:
    along the curve, the rays of one packet leave a probe in nearby
    directions, so they traverse similar BVH nodes and hit nearby points
    whose multi-bounce lookups touch the same probes and texels (measured in
    docs/techniques/ddgi.md). The spherical-Fibonacci index order, in contrast,
    jumps by the golden angle in azimuth from one ray to the next.
    """
    q = np.clip(((oct_encode_np(dirs) * 0.5 + 0.5) * (1 << bits)).astype(np.int64), 0, (1 << bits) - 1)
    return np.argsort(_part1by1(q[:, 0]) | (_part1by1(q[:, 1]) << 1), kind="stable")


def spherical_fibonacci(index, n: int):
    """Dr.Jit version: direction ``index`` (UInt32) of an ``n``-point spherical-Fibonacci set."""
    i = mi.Float(index)
    s = i * GOLDEN_FRACTION
    phi = 2.0 * dr.pi * (s - dr.floor(s))
    cos_t = 1.0 - (2.0 * i + 1.0) * (1.0 / n)
    sin_t = dr.safe_sqrt(1.0 - cos_t * cos_t)
    sp, cp = dr.sincos(phi)
    return mi.Vector3f(cp * sin_t, sp * sin_t, cos_t)


def random_rotation(u1: float, u2: float, u3: float) -> np.ndarray:
    """3x3 uniformly distributed rotation matrix from three uniforms in [0, 1) (Arvo 1992)."""
    theta = 2.0 * np.pi * u1       # rotation about the pole
    phi = 2.0 * np.pi * u2         # direction to deflect the pole towards
    z = u3                         # amount of pole deflection
    r = np.sqrt(z)
    v = np.array([np.cos(phi) * r, np.sin(phi) * r, np.sqrt(1.0 - z)])
    st, ct = np.sin(theta), np.cos(theta)
    R = np.array([[ct, st, 0.0], [-st, ct, 0.0], [0.0, 0.0, 1.0]])
    return (2.0 * np.outer(v, v) - np.eye(3)) @ R   # minus a Householder reflection: a proper rotation


def rotation_for_frame(seed: int, frame: int, stream: int = 0) -> np.ndarray:
    """The per-frame rotation of the ray-direction set, from an RNG seeded with (seed, frame, stream)."""
    rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, int(frame) & 0xFFFFFFFF, int(stream), 0xDD61])
    return random_rotation(*rng.random(3))
