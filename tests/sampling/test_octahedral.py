"""Octahedral maps, bordered texel layout, spherical Fibonacci and random rotations."""
import numpy as np
import pytest
from scipy import stats

from dyngi.backend import dr, mi
from dyngi.sampling.fibonacci import (random_rotation, rotation_for_frame, spherical_fibonacci,
                                      spherical_fibonacci_np)
from dyngi.sampling.octahedral import (bilinear_texel_sample_np, border_source_index, direction_to_texel_coords,
                                       oct_decode, oct_decode_np, oct_encode, oct_encode_np, texel_directions,
                                       texel_solid_angles)


def _random_dirs(n, seed=1):
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    # include the axes and the equator (the fold) explicitly
    extra = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1],
                      [0.6, 0.8, 0.0], [-0.6, 0.8, 0.0], [0.6, -0.8, 0.0]], float)
    return np.concatenate([d, extra])


def test_oct_round_trip_numpy():
    d = _random_dirs(20000)
    p = oct_encode_np(d)
    assert np.all(np.abs(p) <= 1.0 + 1e-12)
    assert np.max(np.abs(oct_decode_np(p) - d)) < 1e-12


def test_oct_round_trip_drjit_matches_numpy():
    d = _random_dirs(5000).astype(np.float32)
    v = mi.Vector3f(d.T)
    p = oct_encode(v)
    p_np = np.array(p).T
    assert np.max(np.abs(p_np - oct_encode_np(d))) < 1e-5
    back = np.array(oct_decode(p)).T
    assert np.max(np.abs(back - d)) < 1e-5
    # decode of arbitrary points of the square is unit length and re-encodes to the same point
    rng = np.random.default_rng(3)
    q = rng.uniform(-1, 1, size=(5000, 2)).astype(np.float32)
    dq = oct_decode(mi.Point2f(q.T))
    assert np.max(np.abs(np.linalg.norm(np.array(dq), axis=0) - 1)) < 1e-5
    assert np.max(np.abs(np.array(oct_encode(dq)).T - q)) < 1e-4


def test_border_copy_matches_mirrored_edges():
    for T in (4, 8, 16):
        src = border_source_index(T)
        inner = np.zeros((T, T), bool)
        inner[1:-1, 1:-1] = True
        assert np.all(src[inner] == np.arange(T * T).reshape(T, T)[inner])
        sy, sx = np.divmod(src[~inner], T)
        assert np.all((sx >= 1) & (sx <= T - 2) & (sy >= 1) & (sy <= T - 2))
        # a border texel's centre, pushed across the edge, decodes close to its source texel's direction
        n = T - 2
        ys, xs = np.nonzero(~inner)
        px = ((xs - 1 + 0.5) / n * 2 - 1)
        py = ((ys - 1 + 0.5) / n * 2 - 1)
        d_border = oct_decode_np(np.clip(np.stack([px, py], -1), -1, 1))
        d_src = texel_directions(T).reshape(-1, 3)[src[~inner]]
        ang = np.arccos(np.clip(np.sum(d_border * d_src, -1), -1, 1))
        assert np.max(ang) < 2.5 * np.pi / n   # within about a texel


def test_bilinear_lookup_is_continuous_across_the_seams():
    T = 16
    f = lambda d: 1.0 + d[..., 0] + 0.5 * d[..., 1] - 0.25 * d[..., 2]   # smooth function of direction
    atlas = f(texel_directions(T))[..., None]
    d = _random_dirs(20000, seed=5)
    err = np.abs(bilinear_texel_sample_np(atlas, d)[..., 0] - f(d))
    assert np.max(err) < 0.15 and np.mean(err) < 0.02
    # directions just either side of the fold z = 0 read (nearly) the same value
    phi = np.linspace(0, 2 * np.pi, 500)
    up = np.stack([np.cos(phi), np.sin(phi), np.full_like(phi, 1e-4)], -1)
    dn = up * [1, 1, -1]
    a = bilinear_texel_sample_np(atlas, up / np.linalg.norm(up, axis=-1, keepdims=True))
    b = bilinear_texel_sample_np(atlas, dn / np.linalg.norm(dn, axis=-1, keepdims=True))
    assert np.max(np.abs(a - b)) < 0.02


def test_texel_coords_drjit_stay_inside_the_probe_square():
    T = 8
    d = _random_dirs(4000).astype(np.float32)
    c = np.array(direction_to_texel_coords(mi.Vector3f(d.T), T))
    assert np.all(c >= 1.0 - 1e-5) and np.all(c <= T - 1.0 + 1e-5)


def test_texel_solid_angles_sum_to_sphere():
    sa = texel_solid_angles(8)
    assert abs(sa.sum() - 4 * np.pi) < 1e-3
    assert sa.min() > 0


def test_spherical_fibonacci_drjit_matches_numpy():
    n = 256
    d_np = spherical_fibonacci_np(n)
    d = np.array(spherical_fibonacci(dr.arange(mi.UInt32, n), n)).T
    assert np.max(np.abs(d - d_np)) < 2e-4   # float32 fraction of i * golden ratio
    assert np.max(np.abs(np.linalg.norm(d_np, axis=1) - 1)) < 1e-12


def _equal_area_chi2(d, n_z=16, n_phi=32):
    """Chi^2 p-value of directions binned into equal-area cells (uniform z bands x phi sectors)."""
    z = np.clip(d[:, 2], -1, 1 - 1e-12)
    phi = np.mod(np.arctan2(d[:, 1], d[:, 0]), 2 * np.pi)
    iz = np.minimum(((z + 1) * 0.5 * n_z).astype(int), n_z - 1)
    ip = np.minimum((phi / (2 * np.pi) * n_phi).astype(int), n_phi - 1)
    counts = np.bincount(iz * n_phi + ip, minlength=n_z * n_phi)
    return stats.chisquare(counts).pvalue


def test_rotated_fibonacci_is_uniform_chi2():
    base = spherical_fibonacci_np(256)
    d = np.concatenate([base @ rotation_for_frame(7, f).T for f in range(400)])
    assert _equal_area_chi2(d) > 0.01
    # a single unrotated set is also equal-area at this cell size (cells hold ~8 points each)
    dense = spherical_fibonacci_np(8192)
    assert _equal_area_chi2(dense) > 0.01
    # the test has power: a set biased towards +z fails it
    rng = np.random.default_rng(0)
    biased = d.copy()
    flip = (biased[:, 2] < 0) & (rng.random(len(d)) < 0.1)
    biased[flip, 2] *= -1
    assert _equal_area_chi2(biased) < 1e-6


def test_random_rotation_is_a_uniform_rotation():
    rng = np.random.default_rng(2)
    poles = []
    for u in rng.random((20000, 3)):
        R = random_rotation(*u)
        assert abs(np.linalg.det(R) - 1) < 1e-9
        poles.append(R @ [0.0, 0.0, 1.0])
    assert np.max(np.abs(R @ R.T - np.eye(3))) < 1e-12
    assert _equal_area_chi2(np.array(poles), 8, 16) > 0.01
