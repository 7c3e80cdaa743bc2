"""ADGI's sparse merges (:mod:`dyngi.techniques.adgi.sparse`): the (probe, texel) keys of a pass's samples
compacted and reduced, Algorithm 3 only on the texels that received samples. They must equal the dense
merges they replace -- the probe core's binned estimator and :func:`merge_into_volume` for the visibility
texels (through the ``adgi`` encoding, borders included), a NumPy reference of the batch rule for the radiance
layer -- over several frames of random samples with repeated keys, multiplicities and back faces, on the host
and the device path (a fixed width, no compress)."""
import numpy as np
import pytest

from dyngi.backend import dr, mi


def _plan(rng, P, n, weighted):
    from dyngi.probes import RayPlan
    from dyngi.probes.arrays import upload
    probe = np.sort(rng.integers(0, P, n)).astype(np.uint32)
    ids, counts = np.unique(probe, return_counts=True)
    # directions clustered on a few texels per probe, so that keys repeat
    d = rng.normal(size=(n, 3))
    d[:, 2] = np.abs(d[:, 2]) * np.where(rng.random(n) < 0.3, -1, 1)
    d = (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)
    w = upload(rng.integers(1, 4, n).astype(np.float32)) if weighted else None
    return RayPlan.ragged(ids, counts, mi.Vector3f(*[upload(np.ascontiguousarray(d[:, c])) for c in range(3)]),
                          weight=w)


@pytest.mark.parametrize("device", [False, True])
def test_sparse_merges_equal_the_dense_ones(backend, device):
    from dyngi.probes import ProbeGrid, ProbeVolume, ScatterEstimator
    from dyngi.probes.accumulator import merge_into_volume
    from dyngi.probes.arrays import upload
    from dyngi.probes.encoding import get_encoding
    from dyngi.probes.trace import ProbeRayResults
    from dyngi.techniques.adgi.moving_average import Algorithm3Accumulator
    from dyngi.techniques.adgi.radiance import RadianceUpdate
    from dyngi.techniques.adgi.sparse import SparseKeys, merge_distance_sparse

    grid = ProbeGrid((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), (4, 3, 3))
    enc = get_encoding("adgi")
    dense, sparse = ProbeVolume(grid, 8, 16), ProbeVolume(grid, 8, 16)
    sparse.add_radiance_layer(8)
    P = dense.n_probes
    ru = RadianceUpdate(sparse)
    ru.device = device
    keys = SparseKeys(P * 14 * 14)
    history = dr.zeros(mi.UInt32, P)
    est = ScatterEstimator(mode="bin")
    rng = np.random.default_rng(8)
    ref_v = np.zeros((P, 36, 3))
    ref_n = np.zeros((P, 36), np.int64)
    for frame in range(4):
        n_max = (63, 10)[frame % 2]
        acc = Algorithm3Accumulator(n_max)
        plan = _plan(rng, P, 300, weighted=frame >= 2)
        n = plan.n_rays
        dist = rng.uniform(0.05, 3.0, n).astype(np.float32)
        dist[rng.random(n) < 0.15] *= -0.2                         # back faces
        rad = rng.uniform(0.0, 2.0, (n, 3)).astype(np.float32)
        res = ProbeRayResults(mi.Color3f(*[upload(np.ascontiguousarray(rad[:, c])) for c in range(3)]),
                              upload(dist), plan)
        # -- the distances: dense (estimator + merge_into_volume) vs sparse --
        e = est.distance(dense, res)
        if plan.weight is not None:
            import dataclasses
            e = dataclasses.replace(e, count=mi.UInt32(dr.round(e.weight)))
        merge_into_volume(dense, None, e, acc, enc, plan.probe_ids, plan.counts)
        if device:
            merge_distance_sparse(keys, sparse, res, acc, enc, history, device=True)
            pid = upload(plan.probe_ids.astype(np.uint32), mi.UInt32)
            dr.scatter_reduce(dr.ReduceOp.Add, history, mi.UInt32(1), pid)
        else:
            merge_distance_sparse(keys, sparse, res, acc, enc)
            sparse.state.updates[plan.probe_ids] += 1
        got = np.asarray(sparse.device.distance).reshape(-1, 2)
        want = np.asarray(dense.device.distance).reshape(-1, 2)
        assert np.allclose(got, want, rtol=1e-6, atol=1e-6), frame
        assert np.array_equal(np.asarray(sparse.device.distance_count), np.asarray(dense.device.distance_count))
        # -- the radiance layer: sparse vs a NumPy reference of the batch rule --
        ru.merge(res, n_max)
        tex = np.asarray(sparse.radiance_texel_of(plan.direction))
        pr = np.repeat(plan.probe_ids, plan.counts)
        w = np.ones(n) if plan.weight is None else np.asarray(plan.weight)
        front = dist >= 0.0
        key = pr * 36 + tex
        m = np.bincount(key[front], weights=w[front], minlength=P * 36).reshape(P, 36)
        s = np.stack([np.bincount(key[front], weights=(w * rad[:, c])[front], minlength=P * 36)
                      for c in range(3)], -1).reshape(P, 36, 3)
        hit = m > 0
        nn = ref_n.astype(np.float64)
        below = ref_n < n_max
        j = np.where(below, np.minimum(m, n_max - np.minimum(ref_n, n_max)), np.minimum(m, 1))
        r = np.where(j > 0, nn / np.maximum(nn + j, 1.0), 1.0) * (n_max / (n_max + 1.0)) ** (m - j)
        vbar = s / np.maximum(m, 1.0)[..., None]
        ref_v = np.where(hit[..., None], r[..., None] * ref_v + (1.0 - r[..., None]) * vbar, ref_v)
        ref_n = np.where(hit, np.minimum(ref_n + m.astype(np.int64), n_max), ref_n)
        val, cnt = sparse.radiance_host()
        assert np.allclose(val, ref_v, rtol=1e-4, atol=1e-5), frame
        assert np.array_equal(cnt.astype(np.int64), ref_n), frame
    # the owner table is left clean: every key free again
    assert np.all(np.asarray(keys.owner) == 0xFFFFFFFF)


def test_lazy_outer_cap_equals_the_eager_cap(backend):
    """Sec. 4.8's ``N <- min(N, 16)`` for the probes of V_out - V_in after each frame's updates, applied lazily
    at merge (:class:`~dyngi.techniques.adgi.sparse.LazyCountCap`): over 8 frames of random radiance merges
    (N_max 63, several samples per texel, counts that reach the cap and pass it) and random outer probe sets,
    the radiance layer's values equal a NumPy reference that caps every outer probe's counts at once at the
    end of each frame, and the counts as the merges read them equal the reference's counts."""
    from dyngi.probes import ProbeGrid, ProbeVolume
    from dyngi.probes.arrays import upload
    from dyngi.probes.trace import ProbeRayResults
    from dyngi.techniques.adgi.radiance import RadianceUpdate
    from dyngi.techniques.adgi.sparse import LazyCountCap

    vol = ProbeVolume(ProbeGrid((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), (3, 3, 2)), 8, 16)
    vol.add_radiance_layer(8)
    P = vol.n_probes
    ru = RadianceUpdate(vol)
    lazy = LazyCountCap(P, P * 36, 16)
    rng = np.random.default_rng(21)
    ref_v = np.zeros((P, 36, 3))
    ref_n = np.zeros((P, 36), np.int64)
    n_max = 63
    for frame in range(8):
        plan = _plan(rng, P, 3000, weighted=False)
        n = plan.n_rays
        rad = rng.uniform(0.0, 2.0, (n, 3)).astype(np.float32)
        res = ProbeRayResults(mi.Color3f(*[upload(np.ascontiguousarray(rad[:, c])) for c in range(3)]),
                              upload(np.ones(n, np.float32)), plan)
        ru.merge(res, n_max, lazy_cap=lazy, frame=frame)
        tex = np.asarray(vol.radiance_texel_of(plan.direction))
        key = np.repeat(plan.probe_ids, plan.counts) * 36 + tex
        m = np.bincount(key, minlength=P * 36).reshape(P, 36)
        s = np.stack([np.bincount(key, weights=rad[:, c], minlength=P * 36) for c in range(3)], -1).reshape(P, 36, 3)
        hit = m > 0
        nn = ref_n.astype(np.float64)
        j = np.minimum(m, n_max - np.minimum(ref_n, n_max))
        r = np.where(j > 0, nn / np.maximum(nn + j, 1.0), 1.0) * (n_max / (n_max + 1.0)) ** (m - j)
        ref_v = np.where(hit[..., None], r[..., None] * ref_v + (1.0 - r[..., None]) * (s / np.maximum(m, 1)[..., None]),
                         ref_v)
        ref_n = np.where(hit, np.minimum(ref_n + m, n_max), ref_n)
        outer = np.flatnonzero(rng.random(P) < 0.4)
        lazy.mark_outer(outer, frame)                 # the eager cap: after the frame's updates
        ref_n[outer] = np.minimum(ref_n[outer], 16)
        val, cnt = vol.radiance_host()
        assert np.allclose(val, ref_v, rtol=1e-4, atol=1e-5), frame
        k = dr.arange(mi.UInt32, P * 36)
        seen = np.asarray(lazy.count(mi.UInt32(cnt.ravel()), k, k // 36, mi.Bool(True)))
        assert np.array_equal(seen.reshape(P, 36), ref_n), frame
    assert ref_n.max() > 16 and (ref_n == 16).any()      # the cap bound some texels, others grew past it
