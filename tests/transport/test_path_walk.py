"""The transport layer's path walk (dyngi.transport.path_walk): from a surface interaction it
is the walk from the camera ray that reached it; a terminate hook ends paths as a depth limit does; the
per-vertex NEE/emission hooks partition the estimate (z-test of the parts' sum against the full walk)."""
import numpy as np
import pytest

from stats import z_test_images


def _scene(name):
    from dyngi.scene import load_scene

    sc = load_scene(name)
    sc.at(0.0)
    return sc


def _rays(sc, res, seed, spp=1):
    from dyngi.backend import dr, mi
    from dyngi.sampling.rng import make_sampler

    n = res[0] * res[1] * spp
    sampler = make_sampler(n, seed, 0)
    idx = dr.arange(mi.UInt32, n)
    pix = idx // spp if spp > 1 else idx
    ray = sc.camera(0.0).sample_rays(res, pix, sampler.next_2d())
    return sampler, ray


def _np(x):
    return np.stack([np.asarray(x[i]) for i in range(3)], 1)


@pytest.mark.parametrize("name", ["cornell-static", "light-behind-glass"])
def test_walk_from_surface_is_walk_from_camera_ray(backend, name):
    from dyngi.backend import mi
    from dyngi.transport.path_walk import walk

    sc = _scene(name)
    res = (24, 16)
    s1, ray1 = _rays(sc, res, 7)
    a = walk(sc.mi_scene, s1, ray1, mi.Bool(True), 8, 5, split=True)
    s2, ray2 = _rays(sc, res, 7)
    si = sc.mi_scene.ray_intersect(ray2, ray_flags=mi.RayFlags.All, coherent=True)
    b = walk(sc.mi_scene, s2, ray2, mi.Bool(True), 8, 5, si=si, split=True)
    La, Lb = _np(a.L), _np(b.L)
    assert np.array_equal(La, Lb)
    assert np.array_equal(_np(a.L_ind), _np(b.L_ind))
    assert La.max() > 0.0
    # the camera ray is traced by the walk only when it starts from the camera
    assert np.array_equal(np.asarray(a.n_rays), np.asarray(b.n_rays) + 1)


def test_terminate_hook_is_a_depth_limit(backend):
    """A terminate hook that stops every path at vertex d with no radiance = ``max_depth = d + 1``."""
    from dyngi.backend import mi
    from dyngi.transport.path_walk import walk

    sc = _scene("cornell-static")
    res = (24, 16)
    s1, ray1 = _rays(sc, res, 3)
    a = walk(sc.mi_scene, s1, ray1, mi.Bool(True), 3, 5)
    s2, ray2 = _rays(sc, res, 3)
    b = walk(sc.mi_scene, s2, ray2, mi.Bool(True), 12, 5,
             terminate=lambda si, ray, depth, active: (depth >= 2, mi.Color3f(0.0)))
    assert np.array_equal(_np(a.L), _np(b.L))
    # and the radiance it returns counts with the path throughput, once, at the stopping vertex
    s3, ray3 = _rays(sc, res, 3)
    c = walk(sc.mi_scene, s3, ray3, mi.Bool(True), 12, 5,
             terminate=lambda si, ray, depth, active: (depth >= 1, mi.Color3f(1.0)))
    s4, ray4 = _rays(sc, res, 3)
    d = walk(sc.mi_scene, s4, ray4, mi.Bool(True), 2, 5)
    hit1 = np.asarray(d.n_rays) >= 2                 # lanes whose first bounce was traced
    assert np.all(_np(c.L)[~hit1] == _np(d.L)[~hit1])
    assert np.all(_np(c.L)[hit1].sum(1) > _np(d.L)[hit1].sum(1) - 1e-6)


def _parts(sc, res, spp, seed, emission, nee, max_depth=6):
    from dyngi.backend import dr, mi
    from dyngi.transport.path_walk import walk

    sampler, ray = _rays(sc, res, seed, spp)
    r = walk(sc.mi_scene, sampler, ray, mi.Bool(True), max_depth, 4, emission=emission, nee=nee)
    L = dr.block_reduce(dr.ReduceOp.Add, r.L, spp) / spp
    return _np(L).reshape(res[1], res[0], 3)


@pytest.mark.parametrize("name", ["cornell-static", "light-behind-glass"])
def test_emission_and_nee_hooks_partition_the_estimate(backend, name):
    """Light arriving at vertex d (NEE at d + the emission its BSDF sample reaches at d + 1) goes to part
    A for even d, to part B for odd d (vertex 0's own emission to A): E[A] + E[B] = E[full], z-test over
    independent renders (parts and full with different seeds)."""
    sc = _scene(name)
    res, spp, K = (12, 8), 32, 8

    def em_a(depth, prev_delta):
        return (depth == 0) | ((depth % 2) == 1)

    def em_b(depth, prev_delta):
        return (depth > 0) & ((depth % 2) == 0)

    full = np.stack([_parts(sc, res, spp, 100 + k, None, None) for k in range(K)])
    a = np.stack([_parts(sc, res, spp, 200 + k, em_a, lambda d: (d % 2) == 0) for k in range(K)])
    b = np.stack([_parts(sc, res, spp, 300 + k, em_b, lambda d: (d % 2) == 1) for k in range(K)])
    assert a.mean() > 0.0 and b.mean() > 0.0
    ok, msg = z_test_images(full, a + b)
    assert ok, msg
    # a wrong partition (the light arriving at vertex 1, NEE and emission at vertex 2, in neither part) is detected
    b_bad = np.stack([_parts(sc, res, spp, 300 + k, lambda d, p: em_b(d, p) & (d > 2),
                             lambda d: ((d % 2) == 1) & (d > 1)) for k in range(K)])
    ok_bad, _ = z_test_images(full, a + b_bad)
    assert not ok_bad


def test_unrolled_walk_and_diffuse_stand_in(backend):
    """``unroll=True`` (a Python loop over the vertices) is the symbolic loop bit for bit (same random numbers
    in the same order, Russian roulette included); a ``vertex`` hook's diffuse stand-in is what NEE evaluates:
    with albedo 0.5 x the diffuse reflectance (on the all-diffuse Cornell box) the NEE part of a depth-2 walk
    (emission counted at vertex 0 only) is half the real BSDF's, sample for sample."""
    from dyngi.backend import dr, mi
    from dyngi.directions.base import Vertex
    from dyngi.sampling.diffuse import diffuse_albedo
    from dyngi.transport.path_walk import walk

    sc = _scene("cornell-static")
    res = (24, 16)
    runs = []
    for unroll in (False, True):
        s, ray = _rays(sc, res, 5)
        runs.append(walk(sc.mi_scene, s, ray, mi.Bool(True), 3, 1, split=True, unroll=unroll))
    assert np.array_equal(_np(runs[0].L), _np(runs[1].L)) and _np(runs[0].L).max() > 0.0
    assert np.array_equal(_np(runs[0].L_ind), _np(runs[1].L_ind))
    assert np.array_equal(np.asarray(runs[0].n_rays), np.asarray(runs[1].n_rays))

    def stand_in(scale):
        def hook(c):
            n = mi.Vector3f(dr.select(mi.Frame3f.cos_theta(c.si.wi) >= 0.0, c.si.sh_frame.n, -c.si.sh_frame.n))
            return Vertex(c.si, n, None, scale * diffuse_albedo(c.bsdf, c.si, c.active), None, c.active)
        return hook

    def first(depth, prev_delta):
        return depth == 0

    out = []
    for kw in ({}, {"vertex": stand_in(dr.opaque(mi.Float, 0.5))}, {"vertex": stand_in(dr.opaque(mi.Float, 0.0))}):
        s, ray = _rays(sc, res, 9)
        out.append(_np(walk(sc.mi_scene, s, ray, mi.Bool(True), 2, -1, emission=first, **kw).L))
    real, half, emitted = out    # albedo 0: only vertex 0's emission is left
    assert (real - emitted).max() > 0.0
    assert np.allclose(half, emitted + 0.5 * (real - emitted), rtol=1e-4, atol=1e-6)
