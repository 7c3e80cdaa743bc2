"""Probe volume: encodings, blending, furnace, Monte Carlo convergence, light leaks, states, stability."""
import numpy as np
import pytest

from dyngi.backend import dr, mi
from dyngi.probes import (DiffuseHitShader, HysteresisBlend, ProbeGrid, ProbeQuery, ProbeStates, ProbePipeline,
                          ProbeVolume, UniformSFDirections, blend_matrix, get_encoding)
from dyngi.probes.encoding import (IRR_BETA, IRR_GAMMA, SQ_BETA, SQ_GAMMA, ADGIEncoding, QDDGIEncoding,
                                   log_dequantize, log_quantize, log_requantize_dr, log_step)
from dyngi.sampling.octahedral import border_source_index, texel_directions
from dyngi.scene import Camera, load_scene
from dyngi.scene.builder import SceneBuilder
from dyngi.scene.geometry import box, diffuse, quad
from helpers import assert_steady_state_compiles_nothing


def make_pipeline(scene, counts=None, rays=256, hysteresis=0.97, direct="sky", gamma=5.0, states=True,
                 encoding="fp32", **kw):
    vol = ProbeVolume(ProbeGrid.from_scene(scene, counts), **kw)
    q = ProbeQuery(vol)
    st = ProbeStates() if states else None
    up = ProbePipeline(vol, UniformSFDirections(rays), DiffuseHitShader(direct),
                      HysteresisBlend(hysteresis, irradiance_gamma=gamma, encoding=encoding), st, q)
    return vol, q, up


def run(up, scene, frames, seed=0, start=0):
    for f in range(start, start + frames):
        up.update(scene, f, seed)


# -- encodings ------------------------------------------------------------------

@pytest.mark.parametrize("bits,floor", [(9, True), (10, True), (11, True), (13, True), (16, False)])
def test_log_encoding_round_trip_within_step(bits, floor):
    rng = np.random.default_rng(bits)
    v = np.concatenate([rng.exponential(0.5, 20000), rng.uniform(0, 9, 2000), [0.0, 1e-6, 9.0]])
    code = log_quantize(v, bits, IRR_BETA, IRR_GAMMA, floor)
    assert code.max() < (1 << bits)
    back = log_dequantize(code, bits, IRR_BETA, IRR_GAMMA)
    step = log_step(v, bits, IRR_BETA, IRR_GAMMA)
    err = back - v
    if floor:   # round to lowest (ADGI Appendix B): never above, within one step below
        assert np.all(err <= 1.1e-3 * step + 1e-7) and np.all(-err <= step * 1.001 + 1e-7)   # FLOOR_EPS
    else:
        assert np.all(np.abs(err) <= 0.5 * step * 1.001 + 1e-7)
    # decoded values are fixed points of encode/decode (stable under repeated storage)
    assert np.array_equal(log_quantize(back, bits, IRR_BETA, IRR_GAMMA, floor), code)
    # and the Dr.Jit re-quantisation agrees with the NumPy codec
    dv = np.array(log_requantize_dr(mi.Float(v.astype(np.float32)), bits, IRR_BETA, IRR_GAMMA, floor))
    assert np.mean(np.abs(dv - back) <= 1e-5 + 1e-5 * v) > 0.99
    assert np.all(np.abs(dv - back) <= step * 1.01 + 1e-6)   # float32 may pick the neighbouring code


def test_log_encoding_saturates_and_reaches_zero():
    assert log_dequantize(log_quantize(np.array([1e6]), 9, IRR_BETA, IRR_GAMMA, True), 9, IRR_BETA, IRR_GAMMA)[0] \
        == pytest.approx(np.expm1(IRR_BETA) / IRR_GAMMA, rel=1e-5)
    # round-to-lowest: a tiny value decodes to exactly zero (a dark moving average can go dark)
    assert log_dequantize(log_quantize(np.array([1e-4]), 9, IRR_BETA, IRR_GAMMA, True), 9, IRR_BETA, IRR_GAMMA)[0] == 0


def test_qddgi_and_adgi_packing_round_trip():
    rng = np.random.default_rng(4)
    rgb = rng.exponential(0.4, (500, 3))
    q = QDDGIEncoding()
    w = q.encode_irradiance(rgb)
    assert w.dtype == np.uint32
    dec = q.decode_irradiance(w)
    for c, b in enumerate(q.IRR_BITS):
        assert np.all(np.abs(dec[:, c] - rgb[:, c]) <= log_step(rgb[:, c], b, IRR_BETA, IRR_GAMMA) * 1.001)
    diag = 0.7
    mom = np.stack([rng.uniform(0, 1, 500), rng.uniform(0, 1, 500)], -1)
    mom[:, 1] = mom[:, 0] ** 2 + rng.uniform(0, 0.05, 500)
    dm = q.decode_distance(q.encode_distance(mom, diag), diag)
    assert np.all(np.abs(dm[:, 0] - mom[:, 0]) <= 0.5 * diag * log_step(mom[:, 0] / diag, 16, IRR_BETA, IRR_GAMMA) + 1e-6)
    assert np.all(np.abs(dm[:, 1] - mom[:, 1]) <= 0.5 * diag ** 2 * log_step(mom[:, 1] / diag ** 2, 16, SQ_BETA, SQ_GAMMA) + 1e-6)
    a = ADGIEncoding()
    count = rng.integers(0, 64, 500)
    rgb2, n = a.decode_irradiance(a.encode_irradiance(rgb, count))
    assert np.array_equal(n, count)
    for c, b in enumerate(a.IRR_BITS[:3]):
        e = rgb2[:, c] - rgb[:, c]
        step = log_step(rgb[:, c], b, IRR_BETA, IRR_GAMMA)
        assert np.all(e <= 1.1e-3 * step + 1e-7) and np.all(-e <= step * 1.001)
    m2, n2 = a.decode_distance(a.encode_distance(mom, count, diag), diag)
    assert np.array_equal(n2, count)
    # visibility [R13][G13] rounds to nearest (Table 3): within half a code either way
    assert np.all(np.abs(m2[:, 0] - mom[:, 0]) <= 0.5 * diag * log_step(mom[:, 0] / diag, 13, IRR_BETA, IRR_GAMMA)
                  * 1.01 + 1e-6)


# -- blending -------------------------------------------------------------------

def test_blend_matrix_normalised_and_border_consistent():
    dirs = UniformSFDirections(256).directions(3, 0)
    for T, power in ((8, 1.0), (16, 50.0)):
        W, ok = blend_matrix(dirs, T, power)
        assert ok.all()
        assert np.allclose(W.sum(0), 1.0, atol=1e-4)
        src = border_source_index(T).ravel()
        assert np.array_equal(W[:, src], W)    # border columns equal their source columns


def test_blend_matrix_matches_float64_definition():
    """The float32 per-frame rebuild (cosines cut below the weight floor) equals the float64 definition."""
    dirs = UniformSFDirections(256).directions(5, 1)
    for T, power in ((8, 1.0), (16, 50.0), (16, 7.5)):
        W, ok = blend_matrix(dirs, T, power, interior=True)
        tdirs = texel_directions(T)[1:-1, 1:-1].reshape(-1, 3)
        ref = np.maximum(dirs @ tdirs.T, 0.0) ** power
        ref /= ref.sum(0)
        assert ok.all() and W.dtype == np.float32
        assert np.max(np.abs(W - ref)) < 1e-5 * ref.max()
        assert not np.any((W > 0) & (W < np.finfo(np.float32).tiny))    # no denormals


def test_blend_of_constant_radiance_is_exact():
    """A probe seeing constant radiance 2 and distance 0.3 everywhere stores exactly that."""
    sc = load_scene("furnace")
    vol = ProbeVolume(ProbeGrid.from_scene(sc))
    from dyngi.probes.rays import UniformSFDirections as U
    from dyngi.probes.trace import ProbeRayResults
    plan = U(64).plan(0, 0, np.arange(vol.n_probes, dtype=np.uint32))
    n = vol.n_probes * 64
    res = ProbeRayResults(mi.Color3f(2.0, 1.0, 0.5) + dr.zeros(mi.Color3f, n), mi.Float(0.3) + dr.zeros(mi.Float, n), plan)
    HysteresisBlend().update(vol, res)
    assert np.allclose(vol.state.irradiance, [2.0, 1.0, 0.5], rtol=1e-4)
    assert np.allclose(vol.state.distance[..., 0], 0.3, rtol=1e-4)
    assert np.allclose(vol.state.distance[..., 1], 0.09, rtol=1e-4)


# -- furnace --------------------------------------------------------------------

def test_furnace_probes_converge_to_pi_L():
    """Closed sphere, albedo 0.5, emission 0.5 -> radiance 1: texels store E/pi = 1, the query returns pi."""
    sc = load_scene("furnace")
    vol, q, up = make_pipeline(sc, rays=128, hysteresis=0.5, direct="emissive", states=False)
    run(up, sc, 40)
    irr = vol.state.irradiance
    assert np.all(np.isfinite(irr))
    assert np.max(np.abs(irr - 1.0)) < 0.03, (irr.min(), irr.max())
    # query anywhere inside, any normal
    rng = np.random.default_rng(0)
    p = rng.uniform(-0.45, 0.45, (2000, 3)).astype(np.float32)
    nrm = rng.normal(size=(2000, 3)).astype(np.float32)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    E = np.array(q.irradiance(mi.Point3f(p.T), mi.Vector3f(nrm.T), mi.Vector3f(-nrm.T)))
    assert np.max(np.abs(E - np.pi)) < 0.03 * np.pi


def test_furnace_nee_split_stores_reflected_light_only():
    """With NEE owning the emitter, the probes hold the light reflected at least once: L - Le = 0.5."""
    sc = load_scene("furnace")
    vol, q, up = make_pipeline(sc, rays=128, hysteresis=0.5, direct="nee", states=False, gamma=1.0)
    run(up, sc, 40)
    assert abs(vol.state.irradiance.mean() - 0.5) < 0.02
    assert np.max(np.abs(vol.state.irradiance - 0.5)) < 0.06   # NEE noise (one shadow ray per hit)


# -- convergence to brute-force Monte Carlo ----------------------------------------

def _brute_force_texel(scene, pos, n, spp=1 << 15, seed=5):
    """E(n)/pi at ``pos`` by cosine-weighted path tracing (mean radiance of cosine-distributed rays).

    Returns (total, reflected): ``reflected`` leaves out the emission seen directly from ``pos``.
    """
    from dyngi.sampling.rng import make_sampler
    from dyngi.techniques.path import trace_paths
    sampler = make_sampler(spp, seed, 0, 99)
    wl = mi.warp.square_to_cosine_hemisphere(sampler.next_2d())
    frame = mi.Frame3f(mi.Vector3f(*map(float, n)))
    ray = mi.Ray3f(mi.Point3f(*map(float, pos)), frame.to_world(wl))
    si = scene.mi_scene.ray_intersect(ray)
    Le = si.emitter(scene.mi_scene).eval(si)
    L, _, _ = trace_paths(scene.mi_scene, sampler, ray, mi.Bool(True), 24, 8)
    total = np.array(dr.mean(L, axis=1)).ravel()
    return total, total - np.array(dr.mean(Le, axis=1)).ravel()


def test_cornell_probes_converge_to_monte_carlo():
    sc = load_scene("cornell-static")
    # NEE owns the light: the probes hold the reflected light (DDGI's split); linear blend (no perceptual bias)
    vol, q, up = make_pipeline(sc, counts=(4, 4, 4), rays=256, hysteresis=0.9, gamma=1.0, direct="nee",
                              states=False)
    run(up, sc, 40)
    acc = np.zeros_like(vol.state.irradiance, dtype=np.float64)
    k = 30
    for f in range(40, 40 + k):      # average the (unbiased, lagged) volume over frames to beat its noise
        up.update(sc, f, 0)
        acc += vol.state.irradiance
    acc /= k
    T = vol.irradiance_texels
    tdirs = texel_directions(T)
    pos = vol.positions()
    probes = [vol.grid.probe_index((1, 1, 2)), vol.grid.probe_index((2, 2, 2)), vol.grid.probe_index((1, 2, 1))]
    texels = [(3, 3), (2, 5), (5, 2), (4, 4)]
    errs = []
    for p in probes:
        for (y, x) in texels:
            ref = _brute_force_texel(sc, pos[p], tdirs[y, x])[1]
            est = acc[p, y, x]
            errs.append((est.sum() - ref.sum()) / ref.sum())
    errs = np.array(errs)
    print('relative errors', np.round(errs, 4))
    assert np.max(np.abs(errs)) < 0.07, errs
    assert abs(np.mean(errs)) < 0.025, errs


# -- light leaks ------------------------------------------------------------------

def two_rooms_scene():
    """A sunlit open-roof room (x in [-2, 0]) and a closed dark room (x in [0.5, 2.5]), thick wall between."""
    b = SceneBuilder("two-rooms")
    W = diffuse((0.7, 0.7, 0.7))
    # lit room: floor, three walls, no roof
    b.mesh("lit_floor", quad((-1, 0, 0), (0, 0, 1), (1, 0, 0)), W)
    b.mesh("lit_back", quad((-1, 1, -1), (1, 0, 0), (0, 1, 0)), W)
    b.mesh("lit_front", quad((-1, 1, 1), (0, 1, 0), (1, 0, 0)), W)
    b.mesh("lit_left", quad((-2, 1, 0), (0, 1, 0), (0, 0, 1)), W)
    # thick shared wall (solid box), taller than the rooms
    b.mesh("wall", box((0.0, -0.1, -1.1), (0.5, 2.1, 1.1)), W)
    # dark room: closed box seen from inside
    b.mesh("dark", box((0.5, 0.0, -1.0), (2.5, 2.0, 1.0), inward=True), W)
    b.add("sun", {"type": "directional", "direction": [0.3, -1.0, 0.2],
                  "irradiance": {"type": "rgb", "value": [5.0, 5.0, 5.0]}})
    return b.build(Camera((0, 1, 4), (0, 1, 0)), "two rooms", probe_box=((-1.8, 0.2, -0.8), (2.3, 1.8, 0.8)),
                   probe_counts=(9, 4, 4))


def test_light_does_not_leak_into_the_dark_room():
    sc = two_rooms_scene()
    vol, q, up = make_pipeline(sc, rays=128, hysteresis=0.8)
    run(up, sc, 25)
    rng = np.random.default_rng(1)
    n = 4000

    def floor_E(x0, x1):
        p = np.stack([rng.uniform(x0, x1, n), np.full(n, 1e-3), rng.uniform(-0.9, 0.9, n)], -1).astype(np.float32)
        up_n = mi.Vector3f(0, 1, 0)
        view = dr.normalize(mi.Vector3f(0.0, 1.0, 0.3))
        return np.array(q.irradiance(mi.Point3f(p.T), up_n, view)).mean(axis=1).mean()

    lit = floor_E(-1.9, -0.1)
    dark = floor_E(0.6, 2.4)
    assert lit > 0.3
    assert dark < 0.01 * lit, (dark, lit)
    # and the probes inside the dark room hold (almost) nothing
    pos = vol.positions()
    in_dark = (pos[:, 0] > 0.55) & (vol.state.states == 1)
    assert in_dark.any()
    assert vol.state.irradiance[in_dark].max() < 0.01 * lit


# -- states -------------------------------------------------------------------------

def solid_and_wall_scene():
    """A closed room with a large solid block (probes buried in it) and a thin wall through a probe plane."""
    b = SceneBuilder("states")
    W = diffuse((0.5, 0.5, 0.5))
    b.mesh("room", box((-2, 0, -2), (2, 4, 2), inward=True), W, (0.5, 0.5, 0.5))
    b.mesh("block", box((-1.9, 0.05, -1.9), (-0.1, 1.9, -0.1)), W)      # buries probes deep inside
    b.mesh("wall", box((0.95, 0.0, 0.3), (1.05, 3.0, 1.9)), W)           # slab containing probes at x = 1
    return b.build(Camera((0, 2, 1.9), (0, 2, 0)), "states", probe_box=((-1.5, 0.5, -1.5), (1.5, 3.5, 1.5)),
                   probe_counts=(7, 7, 7))


def test_classification_and_relocation():
    sc = solid_and_wall_scene()
    vol, q, up = make_pipeline(sc, rays=128, direct="emissive")
    base = vol.grid.base_positions()
    buried = np.all((base > [-1.9, 0.05, -1.9]) & (base < [-0.1, 1.9, -0.1]), axis=1)
    deep = buried & np.all((base > [-1.9 + 0.3, 0.05 + 0.3, -1.9 + 0.3]) & (base < [-0.1 - 0.3, 1.9 - 0.3, -0.1 - 0.3]), axis=1)
    in_wall = (np.abs(base[:, 0] - 1.0) < 0.05) & (base[:, 2] > 0.3) & (base[:, 2] < 1.9) & (base[:, 1] < 3.0)
    assert deep.sum() >= 4 and in_wall.sum() >= 4
    run(up, sc, 12)
    st = vol.state
    assert np.all(st.states[deep] == 0), st.states[deep]
    pos = vol.positions()
    still_in_wall = (np.abs(pos[:, 0] - 1.0) < 0.05 + 1e-3) & in_wall
    assert not still_in_wall.any()
    assert np.all(np.abs(st.offsets[in_wall, 0]) > 0.05)
    assert np.all(np.abs(st.offsets) <= 0.45 * vol.grid.spacing_np + 1e-5)
    assert np.all(st.states[in_wall] == 1)
    # probes in open space near surfaces stay active, and the query ignores inactive ones
    assert (st.states == 1).sum() > 0.5 * vol.n_probes


# -- stability ---------------------------------------------------------------------

@pytest.mark.parametrize("name", ["cornell-moving-light", "cornell-moving-box"])
def test_no_nan_over_frames_fast(name):
    sc = load_scene(name)
    vol, q, up = make_pipeline(sc, counts=(5, 5, 5), rays=64, encoding="qddgi" if "box" in name else "fp32")
    for f in range(30):
        sc.at(sc.frame_time(f))
        up.update(sc, f, 0)
    assert vol.state.is_finite()
    assert np.all(vol.state.irradiance >= 0)


def test_steady_state_update_compiles_no_new_kernels():
    sc = load_scene("cornell-moving-light")
    vol, q, up = make_pipeline(sc, counts=(4, 4, 4), rays=64)

    def step(f):
        sc.at(sc.frame_time(f))
        up.update(sc, f, 0)

    # warm-up: first frame, first history, first reclassification
    assert_steady_state_compiles_nothing(step, frames=8, warmup=3)


def test_state_summaries_drjit_match_numpy():
    """The Dr.Jit block reductions of relocation/classification give the NumPy summaries exactly."""
    from dyngi.probes.states import _summaries_drjit, _summaries_numpy

    sc = load_scene("cornell-static")
    vol, _, _ = make_pipeline(sc, counts=(4, 4, 4), rays=64)
    rng = np.random.default_rng(5)
    pid = np.arange(vol.n_probes)
    dirs = rng.normal(size=(64, 3)).astype(np.float32)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    dist = rng.uniform(-0.3, 1.5, size=(len(pid), 64)).astype(np.float32)
    dist[rng.random(dist.shape) < 0.2] = np.inf          # misses
    dist[:3] = np.inf                                     # probes with no hit at all
    a = _summaries_numpy(vol, pid, dirs, dist, True)
    b = _summaries_drjit(vol, pid, dirs, mi.Float(dist.ravel()))()
    for k in ("back_ratio", "t_back", "t_front", "near_any"):
        assert np.allclose(a[k], b[k]), k
    has_b, has_f = np.isfinite(a["t_back"]), np.isfinite(a["t_front"])
    assert np.array_equal(a["i_back"][has_b], b["i_back"][has_b])
    assert np.array_equal(a["i_front"][has_f], b["i_front"][has_f])


# -- device mirror and host copy -------------------------------------------------------

def _gather4_kernel_hash(src) -> str:
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history()
        v = dr.gather(mi.Vector4f, src, dr.arange(mi.UInt32, 16) + dr.opaque(mi.UInt32, 0))
        dr.eval(v)
        return [k["hash"] for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT][-1]
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)


def test_upload_copies_and_does_not_depend_on_numpy_alignment():
    """Device atlases own their memory: host writes do not show through, and the kernel that gathers
    from them is the same whatever the alignment of the NumPy source (else: a recompile per upload)."""
    from dyngi.probes.arrays import upload
    buf = np.arange(4 * 64 + 4, dtype=np.float32)
    hashes = set()
    for off in range(4):
        a = buf[off:off + 4 * 64]
        x = upload(a)
        hashes.add(_gather4_kernel_hash(x))
        a[0] = -1.0
        assert float(x[0]) == float(off)
        buf[off] = float(off)
    assert len(hashes) == 1


def test_host_copy_follows_the_device_after_blends():
    sc = load_scene("cornell-static")
    vol, q, up = make_pipeline(sc, counts=(4, 4, 4), rays=64)
    for f in range(3):
        up.update(sc, f, 0)
        host = vol.state.irradiance          # refreshed lazily from the device atlas
        dev = np.asarray(vol.device.irradiance, np.float32).reshape(host.shape)
        assert np.array_equal(host, dev)
        assert np.array_equal(vol.state.distance,
                              np.asarray(vol.device.distance, np.float32).reshape(vol.state.distance.shape))
    assert host.max() > 0.0


@pytest.mark.parametrize("env", ["", "2"])
def test_blas_threads_limited_beside_drjit(env):
    """By default NumPy's BLAS runs one thread (Dr.Jit owns the cores); DYNGI_BLAS_THREADS overrides."""
    import os
    import subprocess
    import sys
    code = ("import numpy, threadpoolctl, dyngi.backend as b; "
            "print(b.BLAS_THREADS, sorted({i['num_threads'] for i in threadpoolctl.threadpool_info() "
            "if i['user_api'] == 'blas'}))")
    e = {k: v for k, v in os.environ.items() if k not in ("DYNGI_BLAS_THREADS", "OPENBLAS_NUM_THREADS")}
    if env:
        e["DYNGI_BLAS_THREADS"] = env
    out = subprocess.run([sys.executable, "-c", code], env=e, capture_output=True, text=True, check=True).stdout
    want = int(env or 1)
    assert out.split() == [str(want), f"[{want}]"], out


def test_query_symbolic_loop_matches_unrolled():
    sc = load_scene("cornell-static")
    vol, q, up = make_pipeline(sc, counts=(4, 4, 4), rays=64)
    run(up, sc, 3)
    rng = np.random.default_rng(3)
    lo, hi = np.array(sc.mi_scene.bbox().min), np.array(sc.mi_scene.bbox().max)
    p = rng.uniform(lo, hi, (500, 3))
    nrm = rng.normal(size=(500, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    args = (mi.Point3f(p.T), mi.Vector3f(nrm.T), mi.Vector3f(-nrm.T))
    loop = np.array(ProbeQuery(vol, unroll=False).irradiance(*args))
    unrolled = np.array(ProbeQuery(vol, unroll=True).irradiance(*args))
    assert loop.max() > 0.0
    assert np.allclose(loop, unrolled, rtol=1e-5, atol=1e-6)


def test_nee_light_cache_never_serves_a_freed_scene():
    """Scenes loaded one after another often reuse a freed scene's address: the cached NEE sampler
    (with pointers to that scene's emitters) must never be handed to the new scene (it crashed kernels),
    and the cache keeps no older scene alive (their emitters would join every virtual call)."""
    import gc
    from dyngi.probes import trace
    from dyngi.probes.trace import emitter_via_probes_host, nee_lights
    names = ("furnace", "cornell-static", "warehouse-lights")

    def cache():    # the per-scene light-routing cache (named _NEE_CACHE before H1's routing rework)
        return trace._ROUTING_CACHE if hasattr(trace, "_ROUTING_CACHE") else trace._NEE_CACHE

    for i in range(12):
        sc = load_scene(names[i % 3])
        ms = sc.mi_scene
        lights = nee_lights(ms, "sky")
        nee_lights(ms, "nee")
        assert all(e[0] is ms for e in cache().values())
        assert lights.count == sum(not emitter_via_probes_host(e, "sky") for e in ms.emitters())
        assert nee_lights(ms, "sky") is lights            # still a cache
        del sc, ms, lights
        gc.collect()
    assert len(cache()) <= 2


def test_probes_carry_emitters_decides_whether_hits_read_emission():
    """Probe-ray shading skips the emitter lookup exactly when no emitter reaches the probes directly."""
    from dyngi.probes.trace import probes_carry_emitters

    cornell = load_scene("cornell-static").mi_scene          # one area light, no sky
    assert not probes_carry_emitters(cornell, "sky") and not probes_carry_emitters(cornell, "nee")
    assert probes_carry_emitters(cornell, "emissive")        # area lights enter through the probes there
    sky = load_scene("sky-pit").mi_scene                     # sun + sky: the sky reaches the probes in 'sky' mode
    assert probes_carry_emitters(sky, "sky") and not probes_carry_emitters(sky, "nee")
