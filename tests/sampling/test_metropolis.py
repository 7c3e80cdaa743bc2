"""Persistent Metropolis chains (ADGI, Datta et al. 2022, Algorithms 1 and 5): the visited states after burn-in
follow a known 2D and a known 5D (position x direction) target (chi^2), and a wrong target is rejected."""
import numpy as np
import pytest

from dyngi.backend import dr, mi
from dyngi.errors import DyngiError
from dyngi.sampling.metropolis import ADGI_DIRECTION_STEP, MetropolisChains, reflect_into
from dyngi.sampling.octahedral import oct_encode_np
from dyngi.sampling.fibonacci import spherical_fibonacci_np
from stats import chi2_uniform
from helpers import assert_steady_state_compiles_nothing

SEED = 1234


def _collect(chains, target, n_chains, frames, discard, bin_fn):
    """Run ``frames`` frames; histogram (via ``bin_fn``) the samples of all frames after ``discard``."""
    state = chains.initial_state(n_chains, SEED)
    counts = None
    for f in range(frames):
        state, s = chains.run(state, target, SEED, f)
        if f < discard:
            continue
        p = np.stack([np.asarray(c) for c in s.position], -1)
        w = None if s.direction is None else np.stack([np.asarray(c) for c in s.direction], -1)
        h = bin_fn(p, w)
        counts = h if counts is None else counts + h
    return counts, state


# -- 2D: h(x, y) on [0, 2] x [0, 1] -------------------------------------------------------------

def h2(x, y, bump=1.0):
    return 0.2 + y + bump * np.exp(-(x - 1.3) ** 2 / 0.1)


def h2_dr(p, w):
    return 0.2 + p.y + dr.exp(-dr.square(p.x - 1.3) / 0.1)


def expected_2d(nx, ny, bump=1.0, sub=64):
    xs = (np.arange(nx * sub) + 0.5) / (nx * sub) * 2.0
    ys = (np.arange(ny * sub) + 0.5) / (ny * sub)
    v = h2(xs[:, None], ys[None, :], bump)
    b = v.reshape(nx, sub, ny, sub).sum((1, 3))
    return b / b.sum()


def test_chains_sample_known_2d_target(backend):
    nx, ny = 8, 5
    chains = MetropolisChains((0, 0, 0), (2, 1, 0), (0.5, 0.3, 0.0), direction_step=None, burn_in=15,
                              iterations=16)

    def bins(p, w):
        assert np.all(p[:, 2] == 0.0)                    # a frozen axis stays put
        ix = np.clip((p[:, 0] / 2.0 * nx).astype(int), 0, nx - 1)
        iy = np.clip((p[:, 1] * ny).astype(int), 0, ny - 1)
        return np.bincount(ix * ny + iy, minlength=nx * ny).astype(np.float64)

    counts, _ = _collect(chains, h2_dr, 8192, 26, 6, bins)
    total = counts.sum()
    ok, p = chi2_uniform(counts, expected_2d(nx, ny) * total)
    assert ok, f"chi2 p={p}"
    # power: a target with a 15% smaller bump is rejected by the same histogram
    bad, p_bad = chi2_uniform(counts, expected_2d(nx, ny, bump=0.85) * total)
    assert not bad and p_bad < 1e-6, p_bad


# -- 5D: h(p, w) = a(p) b(w) + c(p) d(w) on [0, 2] x [0, 1] x [0, 1] x S^2 ---------------------

def a_np(x, y, z):
    return 0.5 + x

def c_np(x, y, z):
    return y * z

def b_np(w):
    return 0.1 + np.maximum(w[..., 2], 0.0) ** 2

def d_np(w, k=1.0):
    return k * np.maximum(w[..., 0], 0.0)


def h5_dr(p, w):
    return ((0.5 + p.x) * (0.1 + dr.square(dr.maximum(w.z, 0.0)))
            + p.y * p.z * dr.maximum(w.x, 0.0))


POS_BINS = (4, 2, 2)
DIR_BINS = 4


def _pos_bin_integrals(fn, sub=32):
    nx, ny, nz = POS_BINS
    xs = (np.arange(nx * sub) + 0.5) / (nx * sub) * 2.0
    ys = (np.arange(ny * sub) + 0.5) / (ny * sub)
    zs = (np.arange(nz * sub) + 0.5) / (nz * sub)
    v = fn(xs[:, None, None], ys[None, :, None], zs[None, None, :]) * np.ones((len(xs), len(ys), len(zs)))
    return v.reshape(nx, sub, ny, sub, nz, sub).sum((1, 3, 5)).ravel() / sub ** 3


def _dir_bin(w):
    o = oct_encode_np(w)
    ix = np.clip(((o[:, 0] + 1) * 0.5 * DIR_BINS).astype(int), 0, DIR_BINS - 1)
    iy = np.clip(((o[:, 1] + 1) * 0.5 * DIR_BINS).astype(int), 0, DIR_BINS - 1)
    return ix * DIR_BINS + iy


def _dir_bin_integrals(fn, n=1 << 21):
    w = spherical_fibonacci_np(n)
    return np.bincount(_dir_bin(w), weights=fn(w), minlength=DIR_BINS ** 2) * (4 * np.pi / n)


def expected_5d(k=1.0):
    e = (np.outer(_pos_bin_integrals(a_np), _dir_bin_integrals(b_np))
         + np.outer(_pos_bin_integrals(c_np), _dir_bin_integrals(lambda w: d_np(w, k))))
    return (e / e.sum()).ravel()


def _bins5(p, w):
    nx, ny, nz = POS_BINS
    ix = np.clip((p[:, 0] / 2.0 * nx).astype(int), 0, nx - 1)
    iy = np.clip((p[:, 1] * ny).astype(int), 0, ny - 1)
    iz = np.clip((p[:, 2] * nz).astype(int), 0, nz - 1)
    pb = (ix * ny + iy) * nz + iz
    return np.bincount(pb * DIR_BINS ** 2 + _dir_bin(w), minlength=nx * ny * nz * DIR_BINS ** 2).astype(float)


def test_chains_sample_known_5d_target(backend):
    chains = MetropolisChains((0, 0, 0), (2, 1, 1), (0.5, 0.3, 0.3), direction_step=0.8, burn_in=15,
                              iterations=16)
    counts, state = _collect(chains, h5_dr, 16384, 30, 6, _bins5)
    assert np.allclose(np.linalg.norm(np.stack([np.asarray(c) for c in state.direction], -1), axis=1), 1.0,
                       atol=1e-5)
    total = counts.sum()
    ok, p = chi2_uniform(counts, expected_5d() * total)
    assert ok, f"chi2 p={p}"
    # power: the direction-coupled term 20% weaker is rejected
    bad, p_bad = chi2_uniform(counts, expected_5d(k=0.8) * total)
    assert not bad and p_bad < 1e-6, p_bad


def test_every_iteration_after_burn_in_yields_a_sample(backend):
    """M - K samples per chain per frame; the last one is the chain's new state; the state persists."""
    chains = MetropolisChains((0, 0, 0), (3, 2, 1), 1.0, direction_step=ADGI_DIRECTION_STEP, burn_in=3,
                              iterations=8)
    s0 = chains.initial_state(100, 5)
    s1, smp = chains.run(s0, h5_dr, 5, 0)
    assert smp.n == 100 * 5
    last = np.asarray(smp.position.x)[4 * 100:]
    assert np.array_equal(last, np.asarray(s1.position.x))
    assert np.array_equal(np.asarray(smp.chain)[:100], np.arange(100))
    # the next frame starts from s1 (persistence), and another seed/frame gives other proposals
    s2, smp2 = chains.run(s1, h5_dr, 5, 1)
    assert not np.array_equal(np.asarray(s2.position.x), np.asarray(s1.position.x))
    # determinism: the same (state, seed, frame) gives bit-identical samples
    _, again = chains.run(s0, h5_dr, 5, 0)
    assert np.array_equal(np.asarray(again.position.y), np.asarray(smp.position.y))
    acc = np.asarray(smp.accepted).mean()
    assert 0.2 < acc < 1.0, acc
    # all samples inside the box
    p = np.stack([np.asarray(c) for c in smp.position], -1)
    assert np.all(p >= 0) and np.all(p <= [3, 2, 1])


def test_steady_state_frame_compiles_nothing(backend):
    """A new frame (new opaque seed) launches only kernels seen before (compared by hash)."""
    chains = MetropolisChains((0, 0, 0), (3, 2, 1), 1.0, burn_in=2, iterations=4)
    s = chains.initial_state(64, 1)
    state = [s]

    def step(f):
        state[0], _ = chains.run(state[0], h5_dr, 1, f)

    assert_steady_state_compiles_nothing(step, frames=5, warmup=2, nonempty=True)


def test_reflect_into_box(backend):
    x = mi.Float([-0.5, 0.25, 2.5, 4.5, -3.0])
    r = np.asarray(reflect_into(x, mi.Float(0.0), mi.Float(2.0)))
    assert np.allclose(r, [0.5, 0.25, 1.5, 0.5, 1.0])
    assert np.allclose(np.asarray(reflect_into(x, mi.Float(1.0), mi.Float(1.0))), 1.0)


def test_bad_chain_parameters_raise():
    with pytest.raises(DyngiError, match="burn_in"):
        MetropolisChains((0, 0, 0), (1, 1, 1), 0.1, burn_in=4, iterations=4)
    with pytest.raises(DyngiError, match="lo <= hi"):
        MetropolisChains((0, 0, 0), (-1, 1, 1), 0.1)
