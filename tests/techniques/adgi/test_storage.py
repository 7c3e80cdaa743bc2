"""ADGI storage and budgets: the 6-10-10 heuristics word (Sec. 4.3), Table 3's visibility rounding, the
guide's coarser mip (Sec. 4.8), relocation/classification after the warm-up, and the equal-time budget
scaling the chain counts (our budget rule)."""
import numpy as np
import pytest

from dyngi.scene import load_scene
from dyngi.techniques import Frame, create_technique

RES = (32, 24)


@pytest.fixture()
def adgi(backend):
    from dyngi.techniques.adgi import technique  # noqa: F401  (registers 'adgi')
    from dyngi.techniques.adgi import heuristics
    return heuristics


def test_heuristics_word_round_trip(adgi):
    """pack/unpack: f_v within half a 6-bit step (round to nearest), f_s and f_d at most one 10-bit step
    above (round up: non-zero stays non-zero), zero stays zero, the V_in flag survives, and the fields do
    not overlap (bits 26-31 hold only the flag)."""
    from dyngi.backend import mi
    h = adgi
    rng = np.random.default_rng(1)
    n = 4000
    fv = rng.random(n).astype(np.float32)
    fs = (rng.random(n) * fv).astype(np.float32)
    fd = (rng.random(n) ** 4 * 37.0).astype(np.float32)
    fd[::7] = 0.0
    fs[::11] = 0.0
    fd[5] = 1e-5                                   # far below one step of the max: still > 0
    vin = rng.random(n) < 0.5
    word, F = h.pack_heuristics(mi.Float(fv), mi.Float(fs), mi.Float(fd), mi.Float(vin.astype(np.float32)))
    w = np.asarray(word, np.uint64)
    assert np.all((w >> 27) == 0) and np.array_equal(((w >> 26) & 1) == 1, vin)
    dv, ds, dd, flag = (np.asarray(x) for x in h.unpack_heuristics(word, F))
    F = float(np.asarray(F)[0])
    assert np.isclose(F, fd.max())
    assert np.all(np.abs(dv - fv) <= 0.5 / 63 + 1e-6)
    assert np.all(ds >= fs - 1e-6) and np.all(ds - fs <= 1.0 / 1023 + 1e-6)
    assert np.all(dd >= fd - 1e-5 * F) and np.all(dd - fd <= F / 1023 * (1 + 1e-5))
    assert np.array_equal(dd > 0, fd > 0) and np.array_equal(ds > 0, fs > 0)
    assert np.array_equal(flag, vin)


def test_table3_encoding_rounds_visibility_to_nearest(adgi):
    """Visibility [R13][G13]: the decoded moments are within half a code of Eq. 21 (the shared floor codec
    is up to a whole code low); irradiance stays round-down (decoded <= value); the device store/load
    pair equals the NumPy codec; counts round-trip."""
    from dyngi.backend import dr, mi
    from dyngi.probes.encoding import ADGIEncoding, IRR_BETA, IRR_GAMMA, log_step

    class FlooredVisibility(ADGIEncoding):      # the floor codec the shared encoding had before Table 3
        VIS_FLOOR = True
    enc, old = ADGIEncoding(), FlooredVisibility()
    rng = np.random.default_rng(2)
    diag = 1.7
    m1 = rng.random(3000) * 2.0 * diag
    mom = np.stack([m1, m1 * m1 * (1 + rng.random(3000))], -1)
    cnt = rng.integers(0, 80, 3000)
    dec, n = enc.decode_distance(enc.encode_distance(mom, cnt, diag), diag)
    assert np.array_equal(n, np.minimum(cnt, 63))
    step = log_step(mom[:, 0] / diag, 13, IRR_BETA, IRR_GAMMA) * diag
    err = dec[:, 0] - mom[:, 0]
    assert np.all(np.abs(err) <= 0.5 * step * 1.01 + 1e-6)
    assert err.min() < 0 < err.max()                          # both signs: nearest, not floor
    dec_old, _ = old.decode_distance(old.encode_distance(mom, cnt, diag), diag)
    assert np.mean(np.abs(err)) < 0.75 * np.mean(np.abs(dec_old[:, 0] - mom[:, 0]))
    # device pair == host codec
    dm = mi.Vector2f(mi.Float(mom[:, 0].astype(np.float32)), mi.Float(mom[:, 1].astype(np.float32)))
    word = enc.store_distance(dm, mi.UInt32(cnt.astype(np.uint32)), dr.opaque(mi.Float, diag))
    back, nd = enc.load_distance(word, dr.opaque(mi.Float, diag))
    host, _ = enc.decode_distance(enc.encode_distance(mom.astype(np.float32), cnt, diag), diag)
    bx = np.asarray(back.x)
    same = np.isclose(bx, host[:, 0], rtol=2e-5, atol=1e-7)
    assert same.mean() > 0.99 and np.all(np.abs(bx - host[:, 0]) <= step * 1.01 + 1e-6)   # ties: fp32 vs fp64
    assert np.array_equal(np.asarray(nd), np.minimum(cnt, 63))
    # irradiance: round-down (Appendix B), inherited
    rgb = rng.random((500, 3)) * 3
    got, _ = enc.decode_irradiance(enc.encode_irradiance(rgb, np.ones(500, int)))
    st = np.stack([log_step(rgb[:, c], b, IRR_BETA, IRR_GAMMA) for c, b in enumerate((9, 9, 8))], -1)
    assert np.all(got <= rgb + 2e-3 * st) and np.all(got >= rgb - 1.01 * st)   # floor (FLOOR_EPS = 1e-3 code)


def test_guide_reads_a_coarser_mip(adgi):
    """``guide_feedback`` is the 2x2-block mean luminance of the 6x6 interior (3x3 per probe at mip 1) of the
    atlas, and ``guide_mip=0`` is the texel itself; both read the atlas as it stands (the previous frame's)."""
    sc = load_scene("cornell-moving-light")
    sc.at(0.0)
    T = 8
    for level, m in ((1, 3), (0, 6), (2, 2)):
        a = create_technique("adgi", sc, {"probe_counts": "3", "static_chains": 64, "dynamic_chains": 0,
                                          "iterations": 4, "burn_in": 1, "warmup": 1, "warmup_rays": 32,
                                          "guide_mip": level})
        a.step(Frame(0, 0.0, sc.camera(0.0), RES, seed=0))
        irr = a.volume.state.irradiance.reshape(-1, T, T, 3)[:, 1:-1, 1:-1]
        lum = irr @ np.array([0.212671, 0.715160, 0.072169])            # (P, 6, 6)
        P = lum.shape[0]
        want = np.zeros((P, m, m))
        cnt = np.zeros((m, m))
        b = 1 << level
        for y in range(6):
            for x in range(6):
                want[:, y // b, x // b] += lum[:, y, x]
                cnt[y // b, x // b] += 1
        want /= cnt
        got = np.asarray(a.guide_feedback()).reshape(P, m, m)
        assert np.allclose(got, want, rtol=1e-4, atol=1e-7), level
        assert want.std() > 0


def test_relocation_and_classification_after_the_warm_up(adgi):
    """With ``warmup=0`` nothing classifies the probes on frame 0; the states pass at frame 8 (every
    ``reclassify_interval`` frames) then deactivates about the probes that ddgi's classification deactivates
    and relocates some; its rays are counted in stage 'states'. ``reclassify_interval=0`` never runs it."""
    sc = load_scene("cornell-moving-light")
    p = {"probe_counts": "5", "static_chains": 128, "dynamic_chains": 0, "iterations": 4, "burn_in": 1,
         "warmup": 0}
    a = create_technique("adgi", sc, p)
    off = create_technique("adgi", sc, dict(p, reclassify_interval=0))
    d = create_technique("ddgi", sc, {"probe_counts": "5", "warmup": 1})
    for f in range(9):
        t = sc.frame_time(f)
        sc.at(t)
        r = a.step(Frame(f, t, sc.camera(t), RES, seed=0))
        off.step(Frame(f, t, sc.camera(t), RES, seed=0))
        if f == 0:
            d.step(Frame(f, t, sc.camera(t), RES, seed=0))
        assert ("states" in r.stats["rays"]) == (f == 8), f
    assert 0 < r.stats["rays"]["states"] <= a.volume.n_probes * 32 and r.stats["rays"]["states"] % 32 == 0
    assert np.all(off.volume.state.states != 0)                       # never classified
    inactive, ref = a.volume.state.states == 0, d.volume.state.states == 0
    jac = (inactive & ref).sum() / max((inactive | ref).sum(), 1)     # ddgi classifies from its own 256 rays
    assert inactive.any() and jac > 0.6, (inactive.sum(), ref.sum(), jac)
    assert np.abs(a.volume.state.offsets).max() > 0


def test_equal_time_budget_scales_the_chain_counts(adgi):
    """``Frame.time_budget_ms``: a budget far below the frame's cost runs fewer static chains than one far
    above it (which runs them all), from the ms per ray measured on the last frame. Timing is noisy on a
    shared CPU: only the order is asserted; the spend ratio is recorded in the figures, not tested."""
    sc = load_scene("cornell-moving-box")
    a = create_technique("adgi", sc, {"probe_counts": "5", "static_chains": 2048, "dynamic_chains": 256,
                                      "iterations": 8, "warmup": 1, "warmup_rays": 32})
    runs = {}
    for f in range(7):
        t = sc.frame_time(f)
        sc.at(t)
        tb = None if f < 2 else (0.5 if f % 2 else 1e6)
        r = a.step(Frame(f, t, sc.camera(t), RES, seed=0, time_budget_ms=tb))
        if tb is not None:
            runs.setdefault(tb, []).append(r.stats["static_chains_run"])
    assert max(runs[0.5]) < 2048 and min(runs[1e6]) == 2048, runs
    assert np.mean(runs[0.5]) < 0.5 * 2048, runs


def test_equal_rays_in_a_static_scene_go_to_the_static_chains(adgi):
    """A frozen scene has f_d = 0 everywhere: the dynamic stage's half is not reserved, so the steady frames
    spend the budget (within one chain's rays, at most 2% under) and never more."""
    sc = load_scene("cornell-moving-light")
    sc.at(0.0)
    a = create_technique("adgi", sc, {"probe_counts": "5", "static_chains": 4096, "dynamic_chains": 256,
                                      "warmup": 1, "warmup_rays": 32})
    budget = 40000
    spent = []
    for f in range(6):
        r = a.step(Frame(f, 0.0, sc.camera(0.0), RES, seed=0, ray_budget=budget if f else None, static=f > 0))
        if f:
            assert r.stats["rays"].get("D", 0) == 0 and r.stats["static_chains_run"] < 4096
            spent.append(r.stats["total_rays"])
    assert max(spent) <= budget and min(spent) > 0.98 * budget, spent


def test_device_convolution_equals_the_numpy_reference(adgi):
    """The radiance-texel -> irradiance convolution on the device (no host read) equals the NumPy
    reference on random radiance, with a third of the texels never sampled (left out, weights
    renormalised), including a probe with no sample at all (ok False everywhere), for R = 16 and R = 8.
    The texels are the volume's radiance layer."""
    from dyngi.backend import mi
    from dyngi.probes import ProbeGrid, ProbeVolume
    from dyngi.techniques.adgi.radiance import RadianceUpdate
    rng = np.random.default_rng(2)
    grid = ProbeGrid((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0), (2, 2, 2))
    for R in (16, 8):
        vol = ProbeVolume(grid, 8, 16, radiance_texels=R)
        rc = RadianceUpdate(vol)
        P = vol.n_probes
        assert rc.n_tex == vol.radiance_interior == (R - 2) ** 2
        val = rng.random(P * rc.n_tex * 3).astype(np.float32)
        cnt = (rng.random(P * rc.n_tex) < 0.66) * rng.integers(1, 40, P * rc.n_tex)
        cnt[rc.n_tex * 2: rc.n_tex * 3] = 0                     # probe 2: never sampled
        vol.device.radiance, vol.device.radiance_count = mi.Float(val), mi.UInt32(cnt.astype(np.uint32))
        ids = np.array([5, 2, 0, 3], np.uint32)
        a, b = rc.irradiance_estimate_device(ids), rc.irradiance_estimate_host(ids)
        ok_a, ok_b = np.asarray(a.ok), np.asarray(b.ok)
        assert np.array_equal(ok_a, ok_b) and not ok_a.reshape(4, -1)[1].any() and ok_a.sum() > 0
        assert np.allclose(np.asarray(a.value), np.asarray(b.value), rtol=2e-5, atol=1e-6)
        assert np.array_equal(np.asarray(a.count), np.asarray(b.count)) and a.n == b.n


def test_the_radiance_layer_is_the_volumes(adgi):
    """The radiance layer is the probe volume's third atlas: allocated (zero) when asked for, the same size
    asked again keeps it, another size raises; the volume's reset zeroes it; its memory is the volume's
    (device only, none without a layer); ADGI's volume holds it and its radiance update writes there."""
    from dyngi.backend import mi
    from dyngi.errors import DyngiError
    from dyngi.probes import ProbeGrid, ProbeVolume

    grid = ProbeGrid((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0), (2, 3, 2))
    vol = ProbeVolume(grid, 8, 16)
    assert vol.radiance_texels is None and vol.radiance_interior == 0 and vol.memory_parts()["radiance_layer"] == []
    vol.add_radiance_layer(6)
    v, c = vol.radiance_host()
    assert v.shape == (12, 16, 3) and c.shape == (12, 16) and not v.any() and not c.any()
    vol.device.radiance_count = mi.UInt32(np.arange(12 * 16, dtype=np.uint32))
    keep = vol.device.radiance_count
    vol.add_radiance_layer(6)
    assert vol.device.radiance_count is keep
    with pytest.raises(DyngiError, match="radiance layer"):
        vol.add_radiance_layer(8)
    parts = vol.memory_parts()["radiance_layer"]
    assert sum(np.asarray(x).nbytes for x in parts) == 12 * 16 * (3 * 4 + 4)
    vol.reset()
    assert vol.radiance_texels == 6 and not vol.radiance_host()[1].any()

    sc = load_scene("cornell-static")
    a = create_technique("adgi", sc, {"probe_counts": "3", "warmup": 1, "radiance_texels": 6,
                                      "static_chains": 64, "dynamic_chains": 0, "iterations": 4, "burn_in": 1})
    assert a.volume.radiance_texels == 6 and a.accumulator.radiance.volume is a.volume
    sc.at(0.0)
    a.step(Frame(0, 0.0, sc.camera(0.0), RES, seed=0))
    assert a.volume.radiance_host()[1].sum() > 0
    assert a.memory_per_probe()["radiance_layer"] == 16 * (3 * 4 + 4)


def test_cache_update_is_algorithm_2_and_3_and_table3_memory(adgi):
    """The default cache update on scripted samples: each sample updates the closest entry of the probe's
    8x8 octahedral map (Algorithm 2; the radiance layer has the irradiance map's layout) with Algorithm 3 in
    its batch form, equal to the sequential updates by the frame's mean per texel, across frames and past
    the static N_max = 63 (reference: the literal scalar Algorithm 3). Memory per probe measured from the
    arrays allocated equals an independent count from the layout; Table 3's words (1312 B) beside it."""
    from dyngi.backend import mi
    from dyngi.probes import RayPlan
    from dyngi.probes.trace import ProbeRayResults
    from dyngi.probes.arrays import upload
    from dyngi.sampling.octahedral import texel_directions
    from dyngi.techniques import create_technique

    sc = load_scene("cornell-static")
    a = create_technique("adgi", sc, {"probe_counts": "3", "warmup": 0})
    rc = a.accumulator.radiance          # ADGI's rules on the volume's radiance layer
    assert rc.R == a.volume.radiance_texels == a.volume.irradiance_texels == 8
    centres = texel_directions(8)[1:-1, 1:-1].reshape(-1, 3)
    rng = np.random.default_rng(5)
    pids = np.array([1, 7], np.uint32)
    ref_v = np.zeros((2, 36))
    ref_n = np.zeros((2, 36), int)
    for frame in range(6):
        m = 40 if frame < 5 else 70              # up to 270 samples a texel: past N_max = 63
        texel = rng.integers(0, 4, size=(2, m))  # texels 0..3 of each probe
        rad = rng.uniform(0.1, 2.0, size=(2, m)).astype(np.float32)
        # a direction near (not at) the texel centre: the closest entry is the texel it falls in
        d = centres[texel].reshape(-1, 3) + rng.normal(0, 0.02, size=(2 * m, 3))
        d = (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)
        dirs = mi.Vector3f(*[upload(d[:, c]) for c in range(3)])
        assert np.array_equal(np.asarray(rc.texel_of(dirs)), texel.ravel())      # the closest entry
        plan = RayPlan.ragged(pids, [m, m], dirs)
        L = upload(rad.ravel())
        rc.merge(ProbeRayResults(mi.Color3f(L, L, L), upload(np.ones(2 * m, np.float32)), plan), 63)
        for p in range(2):
            for t in range(4):
                v = rad[p][texel[p] == t].astype(np.float64)
                if len(v):       # the frame's samples in sequence, each equal to their mean (the batch form)
                    for _ in range(len(v)):
                        ref_v[p, t] = v.mean() / (ref_n[p, t] + 1) + ref_n[p, t] * ref_v[p, t] / (ref_n[p, t] + 1)
                        ref_n[p, t] = min(ref_n[p, t] + 1, 63)
    got = np.asarray(rc.value).reshape(rc.P, rc.n_tex, 3)[pids][..., 0]
    cnt = np.asarray(rc.count).reshape(rc.P, rc.n_tex)[pids]
    assert np.array_equal(cnt, ref_n) and ref_n.max() == 63
    assert np.allclose(got, ref_v, rtol=1e-4, atol=1e-6)
    mem = a.memory_per_probe()
    # measured from the arrays allocated, against an independent count from the layout: fp32 texels and a
    # UInt32 count per texel, each on the host and on the device (the mirror); 8 per-octant fp32 tables of the
    # heuristics + f_c, the pilot stamp and the culling mask per probe; the radiance layer's 6x6 fp32 RGB +
    # UInt32 count (the volume's third atlas, device only). Table 3's packed words (what the paper stores,
    # 1312 B) are reported beside, not measured.
    Ti, Td = 8, 16
    assert mem["irradiance"] == 2 * (Ti * Ti * 3 * 4 + Ti * Ti * 4) == 2048
    assert mem["visibility"] == 2 * (Td * Td * 2 * 4 + Td * Td * 4) == 6144
    assert mem["heuristics"] == 8 * 8 * 4 + 4 * 4             # + the triggers' lazy-decay tick per probe
    # the sparse merges' tables: a UInt32 owner per radiance (36) and distance (196) texel key, the lazy cap's
    # stamp per key and last outer frame per probe, an owner per dynamic proxy entry
    n_entries = 8 * int(np.prod(a.passes.chains.proxies))
    assert np.isclose(mem["merge_tables"], 4 * (36 + 196) * 2 + 2 * 4 + 4 * n_entries / a.volume.n_probes)
    assert mem["radiance_layer"] == 36 * (3 * 4 + 4)
    assert mem["probe_state"] == 3 * 4 + 1 + 4 + 3 * 4 + 4 + 4 * 4
    assert mem["total"] == sum(v for k, v in mem.items() if k not in ("total", "table3"))
    assert mem["table3"] == 8 * 8 * 4 + 16 * 16 * 4 + 8 * 4 == 1312


def test_ray_cap_of_a_budget_fits_a_uint32():
    """An equal-time budget far above a frame's cost converts to more rays than a UInt32 holds: the cap
    saturates instead of overflowing ``dr.opaque`` (it failed the test above on a slow machine)."""
    from dyngi.techniques.adgi.planner import _ray_cap

    assert _ray_cap(1000, 0.5) == 400 and _ray_cap(1e20, 0.5) == 2 ** 32 - 1
    assert _ray_cap(float("inf"), 1.0) == 2 ** 32 - 1
    assert _ray_cap(-3, 1.0) == 0 and _ray_cap(float("nan"), 1.0) == 0
