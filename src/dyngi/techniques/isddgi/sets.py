"""IS-DDGI's direction sets and the sampling its planner draws from (Liu et al., I3D 2023, supplement).

The set geometry (Sec. 2.1: each probe's 16x16 octahedral tile, set ``ds_ij`` = texel ``(j mod 16,
j / 16)``, its solid angle), Algorithm 1's jittered directions from a per-ray hash, the per-probe random
shift, the uniform cell layout and its rotation (Fig. 1: :func:`uniform_keys`), the allocation pdf over
(probe, set) pairs and its sampling (Secs. 4.3-4.4), the per-set merge of uniform and importance rays
(:func:`merge_keys`) and the device side of a plan (:func:`device_rays`: directions, ``Omega_j / n_ij``
weights and shading keys from one upload). :mod:`.planner` (the :class:`~.planner.ISDDGIPlanner`)
describes the choices; "ours" marks what the supplement leaves open.
"""
from __future__ import annotations

import numpy as np

from ...backend import dr, mi
from ...errors import DyngiError
from ...probes.arrays import upload
from ...sampling.octahedral import oct_decode, oct_decode_np, texel_solid_angles
from ...sampling.rng import mix_seed

SETS_PER_SIDE = 16
N_SETS = SETS_PER_SIDE * SETS_PER_SIDE      # 256 direction sets per probe
RAYS_LIMIT = 4                              # rays per set per frame (Multi-Rays), inferred from Table 1
VARIANTS = ("multi-rays", "one-ray")
LUMINANCE_FLOOR = 1e-3                      # Y_floor of the change measure (ours)
PROBE_MEAN_SHARE = 0.25                     # share of the probe's mean luminance in Y_floor (ours)
CHANGE_EPS = 0.05                           # F_i below this (f_ij below a tenth of it) is 0 (ours)
SHIFT_STREAM = 0x15DD61                     # hash stream of the per-probe random shift
NEIGHBOUR_SHARE = 0.25                      # share of a set's measured change given to its 8 neighbours (ours)
_NB = np.array([(dx, dy) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if dx or dy], np.int64)
BUDGET_REDRAWS = 4                          # redraws of importance rays over a set's limit (budgets)
CELL_STREAM = 0x15DD64                      # hash stream of the per-cell offsets (random ray shifting)
SHADE_STREAM = 0xA511E9B3                   # hash stream of the per-ray shading keys


def set_solid_angles() -> np.ndarray:
    """(256,) float64 solid angle of each direction set (octahedral texel of the 16x16 tile), sums to 4 pi."""
    om = texel_solid_angles(SETS_PER_SIDE + 2, sub=16).ravel()
    return om * (4.0 * np.pi / om.sum())


def set_directions() -> np.ndarray:
    """(256, 3) centre direction of each set (row-major ``j = y * 16 + x``)."""
    c = (np.arange(SETS_PER_SIDE) + 0.5) / SETS_PER_SIDE * 2.0 - 1.0
    py, px = np.meshgrid(c, c, indexing="ij")
    return oct_decode_np(np.stack([px, py], -1)).reshape(-1, 3)


def _hash_u32(x: np.ndarray) -> np.ndarray:
    """Vectorised 32-bit integer hash (lowbias32, Chris Wellons), uint64 in -> uint64 in [0, 2^32)."""
    x = np.asarray(x, np.uint64) & np.uint64(0xFFFFFFFF)
    x ^= x >> np.uint64(16)
    x = (x * np.uint64(0x7FEB352D)) & np.uint64(0xFFFFFFFF)
    x ^= x >> np.uint64(15)
    x = (x * np.uint64(0x846CA68B)) & np.uint64(0xFFFFFFFF)
    x ^= x >> np.uint64(16)
    return x


def ray_hash(probe, dset, k, key) -> np.ndarray:
    """(n,) uint64 hash in [0, 2^32) of (probe, set, ray-in-set, key); ``key`` a scalar or (n,) array."""
    key = np.asarray(key, np.uint64)
    h = _hash_u32(np.asarray(probe, np.uint64) * np.uint64(N_SETS * RAYS_LIMIT)
                  + np.asarray(dset, np.uint64) * np.uint64(RAYS_LIMIT) + np.asarray(k, np.uint64) + key)
    return _hash_u32(h ^ key)


def _noise_from_hash(h: np.ndarray) -> np.ndarray:
    """(n, 2) in [0, 1)^2 from the ray hash: the top 24 bits of ``h`` and of a second hash (24 bits: the same
    values in float32 on the device, :func:`device_rays`)."""
    h = np.asarray(h, np.uint64)
    h2 = _hash_u32(h + np.uint64(0x9E3779B9))
    return np.stack([h >> np.uint64(8), h2 >> np.uint64(8)], -1).astype(np.float64) * (1.0 / 16777216.0)


def noise2d(probe, dset, k, frame: int, seed: int) -> np.ndarray:
    """Algorithm 1's ``noiseFunction(i, j, t)``: (n, 2) float64 in [0, 1)^2 from a hash of
    (probe, set, ray-in-set, frame, seed)."""
    return _noise_from_hash(ray_hash(probe, dset, k, mix_seed(seed, frame, 0x1DD61)))


def _dirs_from_noise(dset, u: np.ndarray) -> np.ndarray:
    dset = np.asarray(dset, np.int64)
    x = (dset % SETS_PER_SIDE + u[:, 0]) / SETS_PER_SIDE * 2.0 - 1.0
    y = (dset // SETS_PER_SIDE + u[:, 1]) / SETS_PER_SIDE * 2.0 - 1.0
    return oct_decode_np(np.stack([x, y], -1))


def jittered_directions(probe, dset, k, frame: int, seed: int) -> np.ndarray:
    """Algorithm 1: (n, 3) unit directions inside the octahedral texels of sets ``dset``."""
    return _dirs_from_noise(dset, noise2d(probe, dset, k, frame, seed))


def probe_shift(probe_ids) -> np.ndarray:
    """Random ray shifting: a per-probe hash of the probe index (uint64)."""
    return _hash_u32(np.asarray(probe_ids, np.uint64) + np.uint64(SHIFT_STREAM))


def uniform_mask(x: np.ndarray, frame: int, shift: np.ndarray) -> np.ndarray:
    """(P, 256) bool: the sets that get a uniform ray in ``frame`` (Fig. 1 cell layout and rotation; the dense
    form of :func:`uniform_keys`, which see)."""
    x = np.asarray(x, np.int64)
    m = np.zeros(len(x) * N_SETS, bool)
    m[uniform_keys(x, frame, shift)] = True
    return m.reshape(len(x), N_SETS)


def allocation_pdf(F: np.ndarray, f: np.ndarray, eps: float, cond: np.ndarray | None = None) -> np.ndarray:
    """(P, 256) float64 allocation pdf over (probe, set) pairs (module docstring); all zero without change.
    ``cond``: :func:`conditional_pdf` of ``f`` if already computed."""
    F = np.maximum(np.asarray(F, np.float64), 0.0)
    tot = F.sum()
    if not tot > 0.0:
        return np.zeros(f.shape, np.float64)
    return (F / tot)[:, None] * (conditional_pdf(f, eps) if cond is None else cond)


def conditional_pdf(f: np.ndarray, eps: float) -> np.ndarray:
    """(P, 256) ``p_f(j | i) = (1 - eps) f_ij / sum_j f_ij + eps / 256`` (uniform where a probe has no f)."""
    f = np.maximum(np.asarray(f, np.float64), 0.0)
    s = f.sum(1, keepdims=True)
    base = np.where(s > 0.0, f / np.where(s > 0.0, s, 1.0), 1.0 / N_SETS)
    return (1.0 - eps) * base + eps / N_SETS


def sample_allocation(pdf: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """(P, 256) int64 counts of ``n`` i.i.d. draws from ``pdf`` (inverse CDF)."""
    return np.bincount(sample_indices(pdf, n, rng), minlength=pdf.size).reshape(pdf.shape)


def _hash_u32_dr(x):
    """:func:`_hash_u32` on the device (UInt32 arithmetic wraps as the host's masked uint64 does)."""
    x = x ^ (x >> 16)
    x = x * 0x7FEB352D
    x = x ^ (x >> 15)
    x = x * 0x846CA68B
    return x ^ (x >> 16)


def rays_from_hash(h, dset, npair, omega):
    """Algorithm 1's jittered direction in set ``dset``'s octahedral texel, the weight ``Omega_j / n_ij`` and the
    shading key of each ray, from its hash ``h`` (UInt32), set ``dset`` and rays of its pair ``npair`` (UInt32,
    0 counts as 1) on the device: the same values in float32 as the host's :func:`_dirs_from_noise`. The one
    decode of a ray hash (the host planner's plans, :func:`device_rays`, and the device planner's)."""
    if not dr.width(h):
        return mi.Vector3f(), mi.Float(), mi.UInt32()
    h2 = _hash_u32_dr(h + 0x9E3779B9)
    scale = 1.0 / 16777216.0
    u0 = mi.Float(h >> 8) * scale
    u1 = mi.Float(h2 >> 8) * scale
    px = (mi.Float(dset & 15) + u0) * (2.0 / SETS_PER_SIDE) - 1.0
    py = (mi.Float(dset >> 4) + u1) * (2.0 / SETS_PER_SIDE) - 1.0
    direction = dr.normalize(oct_decode(mi.Point2f(px, py)))
    weight = dr.gather(mi.Float, omega, dset) / mi.Float(dr.maximum(npair, 1))
    key = _hash_u32_dr(h ^ SHADE_STREAM)
    dr.eval(direction, weight, key)
    return mi.Vector3f(direction), weight, key


def device_rays(info, omega_dr):
    """(direction Vector3f, weight Float, shading key UInt32) of the plan's rays, computed on the device from
    one upload per frame of (ray hash, set | (rays of its pair - 1) << 8) (:func:`rays_from_hash`): Algorithm 1's
    jitter in the set's octahedral texel, ``Omega_j / n_ij`` and the shading key, all as
    :class:`ISDDGIPlanInfo`'s host copies."""
    R = len(info.ray_set)
    if not R:
        return mi.Vector3f(), mi.Float(), mi.UInt32()
    meta = (info.ray_set.astype(np.uint64) | ((np.maximum(info.ray_npair, 1) - 1).astype(np.uint64) << np.uint64(8)))
    buf = upload(np.concatenate([info.ray_hash, meta]).astype(np.uint32), mi.UInt32)
    i = dr.arange(mi.UInt32, R)
    h = dr.gather(mi.UInt32, buf, i)
    m = dr.gather(mi.UInt32, buf, i + dr.opaque(mi.UInt32, R))
    return rays_from_hash(h, m & 255, (m >> 8) + 1, omega_dr)


def uniform_keys(x: np.ndarray, frame: int, shift: np.ndarray) -> np.ndarray:
    """Sorted pair keys ``slot * 256 + j`` of the uniform rays in ``frame`` (Fig. 1 cell layout and rotation).

    ``x`` (P,) uniform rays per probe (powers of two <= 256): cells of ``K = 256 / x`` consecutive row-major
    texels; in cell ``c`` texel ``(frame + shift + perm(shift, c)) mod K``: the rotation moves every cell's
    ray one texel per frame (wrapping inside the cell), so every set is visited once every ``K`` frames.
    ``perm`` (ours) is a hash of the probe's random shift and the cell: the supplement's "random ray
    shifting ... permute the predefined ray allocation pattern differently for every probe" read as a
    per-probe offset of every cell. With one common offset per probe (our first version) a frame's rays lie
    on ``x / 16`` columns of the tile, the per-frame texel estimates are far noisier than ddgi's at equal
    rays, and the gamma-5 blend turns that noise into a low bias (Jensen; measured: isddgi at 16 uniform
    rays 0.913 of ddgi-256, ddgi at 16 rays 0.982, static Cornell box)."""
    x = np.asarray(x, np.int64)
    if np.any((x < 1) | (x > N_SETS) | (x & (x - 1) != 0)):
        raise DyngiError(f"uniform ray counts must be powers of two in [1, {N_SETS}]")
    S = len(x)
    K = N_SETS // x
    slot = np.repeat(np.arange(S), x)
    c = np.arange(int(x.sum())) - np.repeat(np.cumsum(x) - x, x)
    sh = np.asarray(shift, np.uint64)[slot]
    perm = _hash_u32(sh * np.uint64(0x9E3779B1) + c.astype(np.uint64) + np.uint64(CELL_STREAM))
    off = ((np.uint64(frame) + sh + perm) % K[slot].astype(np.uint64)).astype(np.int64)
    return slot * N_SETS + K[slot] * c + off


def sample_indices(pdf: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Sorted flat indices of ``n`` i.i.d. draws from ``pdf`` (inverse CDF; :func:`sample_allocation`'s draws)."""
    flat = pdf.ravel()
    if n <= 0 or not flat.sum() > 0.0:
        return np.zeros(0, np.int64)
    cdf = np.cumsum(flat)
    cdf /= cdf[-1]
    # sorted needles: the same multiset of draws, found ~5x faster (cache-friendly binary searches)
    return np.minimum(np.searchsorted(cdf, np.sort(rng.random(int(n))), side="right"), flat.size - 1)


def merge_keys(ukey: np.ndarray, ikey: np.ndarray, limit: int):
    """Merge sorted uniform and importance pair keys: ``(keys, k, is_uniform, dropped)`` of the rays kept,
    sorted by pair, the uniform ray first in its pair (``k`` = ray index inside the pair, < ``limit``)."""
    allk = np.concatenate([ukey, ikey])
    if not len(ikey):
        return ukey, np.zeros(len(ukey), np.int64), np.ones(len(ukey), bool), 0
    order = np.argsort(allk, kind="stable")          # stable: a pair's uniform ray stays first
    sk = allk[order]
    start = np.r_[True, sk[1:] != sk[:-1]]
    first = np.maximum.accumulate(np.where(start, np.arange(len(sk)), 0))
    k = np.arange(len(sk)) - first
    keep = k < limit
    return sk[keep], k[keep], (order < len(ukey))[keep], int((~keep).sum())
