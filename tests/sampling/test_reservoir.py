"""Reservoirs (dyngi.sampling.reservoir): selection frequencies (chi^2) and unbiased combination."""
from __future__ import annotations

import numpy as np
import pytest
from stats import chi2_uniform

from dyngi.backend import dr, mi
from dyngi.errors import DyngiError
from dyngi.sampling.reservoir import Reservoir, finalize, finalize_single, merge, update

N = 200_000


def _sampler(seed):
    s = mi.load_dict({"type": "independent"})
    s.seed(seed, N)
    return s


def _stream(weights, sampler, offset=0):
    """A reservoir per lane over candidates ``offset + i`` with fixed weights."""
    r = Reservoir.empty((mi.UInt32(0),), N)
    for i, w in enumerate(weights):
        update(r, (dr.full(mi.UInt32, offset + i, N),), dr.full(mi.Float, w, N), dr.full(mi.Float, w, N),
               sampler.next_1d())
    return r


def test_streaming_selection_frequency_is_proportional_to_weight():
    w = np.array([0.5, 3.0, 0.0, 1.0, 2.5, 0.25, 7.0])
    r = _stream(w, _sampler(1))
    counts = np.bincount(np.asarray(r.sample[0]), minlength=len(w))
    assert counts[2] == 0
    ok, p = chi2_uniform(counts, N * w / w.sum())
    assert ok, p
    assert np.allclose(np.asarray(r.w_sum), w.sum()) and np.all(np.asarray(r.M) == len(w))


def test_selection_frequency_after_merges_is_proportional_to_all_weights():
    """Three reservoirs over disjoint candidate sets, merged (with W, M as ReSTIR does and p_hat = w):
    the final sample is any candidate with probability proportional to its weight."""
    s = _sampler(2)
    sets = [np.array([1.0, 2.0, 0.5]), np.array([4.0, 0.3]), np.array([0.7, 0.7, 2.2, 1.1])]
    offs = np.cumsum([0] + [len(x) for x in sets])[:-1]
    rs = [_stream(w, s, o) for w, o in zip(sets, offs)]
    for r in rs:
        finalize_single(r)
    allw = np.concatenate(sets)
    out = Reservoir.empty((mi.UInt32(0),), N)
    for i, r in enumerate(rs):
        merge(out, r, r.p_hat, s.next_1d(), src=i)
    counts = np.bincount(np.asarray(out.sample[0]), minlength=len(allw))
    ok, p = chi2_uniform(counts, N * allw / allw.sum())
    assert ok, p
    assert np.allclose(np.asarray(out.M), len(allw))


def test_wrong_weights_are_detected():
    """The chi^2 test above can fail: frequencies against the wrong weights are rejected."""
    w = np.array([1.0, 2.0, 3.0])
    counts = np.bincount(np.asarray(_stream(w, _sampler(3)).sample[0]), minlength=3)
    assert not chi2_uniform(counts, N * np.array([1.0, 2.0, 3.3]) / 6.3)[0]


def _ris(sampler, p_hat_fn, m, support=None):
    """RIS on [0,1) with uniform candidates and target p_hat_fn; returns a reservoir with sample x."""
    r = Reservoir.empty((mi.Float(0),), N)
    for _ in range(m):
        x = sampler.next_1d()
        ph = p_hat_fn(x)
        update(r, (x,), ph, ph, sampler.next_1d())
    finalize_single(r)
    return r


@pytest.mark.parametrize("combine,unbiased", [("mis", True), ("1/z", True), ("biased", False)])
def test_unbiased_combination_across_domains_with_different_supports(combine, unbiased):
    """Domain 0 targets x^2 on [0,1); domain 1 targets 1 on [0, 0.5) only (zero above). Merging them and
    estimating the integral of f(x) = x^2 by f(y) W: the 1/Z and MIS forms are unbiased; the biased one
    under-estimates (the domain-1 candidates dilute y > 0.5), by a predictable amount."""
    s = _sampler(4)
    p0 = lambda x: x * x                                  # noqa: E731
    p1 = lambda x: dr.select(x < 0.5, 1.0, 0.0)           # noqa: E731
    r0, r1 = _ris(s, p0, 8), _ris(s, p1, 8)
    out = Reservoir.empty((mi.Float(0),), N)
    merge(out, r0, p0(r0.sample[0]), s.next_1d(), src=0)
    merge(out, r1, p0(r1.sample[0]), s.next_1d(), src=1)
    y = out.sample[0]
    finalize(out, combine, [r0.M, r1.M], [p0(y), p1(y)])
    est = np.asarray(y * y * out.W)
    mean, se = est.mean(), est.std() / np.sqrt(N)
    z = (mean - 1.0 / 3.0) / se
    if unbiased:
        assert abs(z) < 4.0, (mean, se)
    else:
        assert z < -10.0, (mean, se)


def test_bad_combination_is_one_clear_error():
    r = Reservoir.empty((mi.Float(0),), 4)
    with pytest.raises(DyngiError, match="mis"):
        finalize(r, "average", [r.M], [r.p_hat])
