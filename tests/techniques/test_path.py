"""The reference path tracer: furnace, agreement with Mitsuba's `path`, determinism, no recompiles."""
import numpy as np
import pytest

from conftest import shared_scene
from stats import z_test_images


def _ours(scene, res, spp, k, max_depth=8, mis="power", t=0.0, seed0=1000, **kw):
    """dyngi's path tracer, independent render number ``k`` (seed ``seed0 + k``); ``kw`` to render_paths."""
    from dyngi.techniques.base import to_image
    from dyngi.techniques.path import render_paths

    scene.at(t)
    L, _ = render_paths(scene, scene.camera(t), res, spp, seed=seed0 + k, frame_index=0, max_depth=max_depth,
                        rr_depth=5, power_heuristic=(mis == "power"), **kw)
    return to_image(L, res)


def _mitsuba(scene, res, spp, k, max_depth=8, t=0.0):
    from dyngi.backend import mi

    scene.at(t)
    sensor = scene.camera(t).to_sensor(res, spp)
    integ = mi.load_dict({"type": "path", "max_depth": max_depth, "rr_depth": 5})
    return np.asarray(mi.render(scene.mi_scene, sensor=sensor, integrator=integ, spp=spp, seed=5000 + k),
                      np.float32)


def _glossy_scene():
    from dyngi.scene.builder import SceneBuilder
    from dyngi.scene.builtin_default import CORNELL_CAMERA, _cornell_shell
    from dyngi.scene.geometry import uv_sphere

    b = SceneBuilder("test-glossy")
    _cornell_shell(b)
    b.mesh("ball", uv_sphere((0.2, 0.45, 0.0), 0.45, 16, 32),
           {"type": "roughplastic", "alpha": 0.08, "diffuse_reflectance": {"type": "rgb", "value": [0.2, 0.3, 0.6]}})
    b.mesh("mirrorish", uv_sphere((-0.5, 0.3, -0.4), 0.3, 12, 24),
           {"type": "roughconductor", "alpha": 0.15, "material": "Au"})
    return b.build(CORNELL_CAMERA, "glossy test scene")


def _many_light_scene():
    from dyngi.scene.builder import SceneBuilder
    from dyngi.scene.camera import Camera
    from dyngi.scene.geometry import box, diffuse, quad

    b = SceneBuilder("test-many-lights")
    b.mesh("floor", quad((0, 0, 0), (0, 0, 3), (3, 0, 0)), diffuse((0.7, 0.7, 0.7)))
    b.mesh("wall", box((-0.2, 0, -0.5), (0.2, 1.2, 0.5)), diffuse((0.5, 0.6, 0.5)))
    rng = np.random.default_rng(3)
    for i in range(24):
        x, z = rng.uniform(-2.5, 2.5, 2)
        col = rng.uniform(0.5, 4.0, 3)
        b.mesh(f"l{i}", quad((x, rng.uniform(0.8, 1.6), z), (0.08, 0, 0), (0, 0, 0.08)),
               diffuse((0, 0, 0)), tuple(col * 6))
    return b.build(Camera((0, 2.5, 4.5), (0, 0.3, 0), (0, 1, 0), 50.0), "many small lights")


def _compare(scene, res=(24, 18), spp=16, k=16, max_depth=8, mis="power"):
    a = np.stack([_ours(scene, res, spp, i, max_depth, mis) for i in range(k)])
    b = np.stack([_mitsuba(scene, res, spp, i, max_depth) for i in range(k)])
    assert np.all(np.isfinite(a)) and np.all(a >= 0)
    ok, info = z_test_images(a, b)
    assert ok, f"dyngi path and Mitsuba path disagree: {info}"
    return a, b


def test_furnace_radiance_one(backend):
    """Closed sphere, albedo 0.5, emission 0.5: L = 0.5 * sum_k 0.5^k = 1 everywhere (unbounded depth)."""
    from dyngi.scene import load_scene

    sc = load_scene("furnace")
    img = _ours(sc, (16, 12), 256, 0, max_depth=-1)
    assert abs(img.mean() - 1.0) < 0.01, img.mean()
    # per-pixel: 256 spp, RR paths; each pixel within 6 sigma of 1 (sigma estimated from the image spread)
    sd = img.std()
    assert sd < 0.1
    assert np.all(np.abs(img - 1.0) < 6 * sd + 1e-3)


def test_furnace_depth_truncation(backend):
    """With max_depth D the furnace gives 0.5 * sum_{k<D} 0.5^k = 1 - 0.5^D: depth semantics match Mitsuba's."""
    from dyngi.scene import load_scene

    sc = load_scene("furnace")
    for d in (2, 3):
        img = _ours(sc, (8, 6), 64, 0, max_depth=d)
        assert abs(img.mean() - (1 - 0.5 ** d)) < 0.01, (d, img.mean())


def test_agrees_with_mitsuba_cornell(backend):
    from dyngi.scene import load_scene

    _compare(load_scene("cornell-static"))


def test_agrees_with_mitsuba_balance_heuristic(backend):
    from dyngi.scene import load_scene

    _compare(load_scene("cornell-moving-light"), mis="balance")


def test_agrees_with_mitsuba_glossy(backend):
    _compare(_glossy_scene())


def test_agrees_with_mitsuba_many_lights(backend):
    _compare(_many_light_scene())


def test_agrees_with_mitsuba_real_scene(backend):
    from dyngi.scene import load_scene

    sc = load_scene(shared_scene("cornell-box/scene_mi3.xml"))
    _compare(sc, res=(20, 20))


def test_deterministic_and_seed_dependent(backend):
    from dyngi.scene import load_scene
    from dyngi.techniques import Frame, create_technique

    sc = load_scene("cornell-moving-light")
    imgs = []
    for seed in (7, 7, 8):
        tech = create_technique("path", sc, {"spp": 2})
        sc.at(0.1)
        imgs.append(tech.step(Frame(0, 0.1, sc.camera(0.1), (24, 18), seed=seed)).image)
    assert np.array_equal(imgs[0], imgs[1])
    assert not np.array_equal(imgs[0], imgs[2])


def test_progressive_accumulation_converges(backend):
    """On a static scene the running mean's error against Mitsuba falls like 1/frames."""
    from dyngi.scene import load_scene
    from dyngi.techniques import Frame, create_technique

    sc = load_scene("cornell-static")
    res = (24, 18)
    ref = np.mean([_mitsuba(sc, res, 256, k) for k in range(4)], axis=0)
    tech = create_technique("path", sc, {"spp": 4, "max_depth": 8})
    errs = []
    for i in range(16):
        r = tech.step(Frame(i, 0.0, sc.camera(0.0), res, seed=3, static=(i > 0)))
        errs.append(np.mean((r.image - ref) ** 2))
    assert r.stats["accumulated_frames"] == 16
    assert errs[-1] < errs[0] / 5, (errs[0], errs[-1])


def test_non_static_frames_restart(backend):
    from dyngi.scene import load_scene
    from dyngi.techniques import Frame, create_technique

    sc = load_scene("cornell-moving-light")
    tech = create_technique("path", sc, {"spp": 1})
    for i in range(3):
        t = i / 30
        sc.at(t)
        r = tech.step(Frame(i, t, sc.camera(t), (16, 12), seed=0, static=False))
    assert r.stats["accumulated_frames"] == 1


def test_steady_state_frame_compiles_no_kernels(backend):
    """A moving light and a new seed each frame must not recompile any kernel."""
    from dyngi.backend import dr
    from dyngi.experiments.runner import run_sequence
    from dyngi.scene import load_scene
    from dyngi.techniques import create_technique

    sc = load_scene("cornell-moving-light")
    tech = create_technique("path", sc, {"spp": 1})
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history()  # clears
        run_sequence(sc, tech, 3, (16, 12), seed=1, keep_images=False)  # warm-up
        seen = {k["hash"] for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT}
        run_sequence(sc, tech, 3, (16, 12), seed=2, t0=0.5, keep_images=False)
        hist = {k["hash"] for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT}
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    assert hist, "no kernels ran?"
    # by hash, not `cache_hit`: the on-disk kernel cache turns a per-frame recompile into a "hit"
    assert hist <= seen, f"{len(hist - seen)} kernels compiled in steady state"


def test_rays_counted(backend):
    from dyngi.scene import load_scene
    from dyngi.techniques import Frame, create_technique

    sc = load_scene("cornell-static")
    tech = create_technique("path", sc, {"spp": 2, "max_depth": 3})
    r = tech.step(Frame(0, 0.0, sc.camera(0.0), (16, 12), seed=0))
    n = 16 * 12 * 2
    # each path: >= 1 camera ray; at most 3 segments + 2 shadow rays
    assert n <= r.stats["rays"]["trace"] <= 5 * n


def test_indirect_only_agrees_with_mitsuba_difference(backend):
    """indirect_only == Mitsuba(max_depth=D) - Mitsuba(max_depth=2) with the same seed (indirect reference)."""
    from dyngi.scene import load_scene

    sc = load_scene("cornell-static")
    res, spp, k = (24, 18), 16, 16
    ours = np.stack([_ours(sc, res, spp, i, 8, seed0=77, indirect_only=True) for i in range(k)])
    theirs = np.stack([_mitsuba(sc, res, spp, i, 8) - _mitsuba(sc, res, spp, i, 2) for i in range(k)])
    full = np.stack([_ours(sc, res, spp, i, 8) for i in range(4)])
    assert ours.mean() < 0.8 * full.mean(), "indirect-only image should be darker than the full one"
    ok, info = z_test_images(ours, theirs)
    assert ok, info


def test_emitter_subset_sampling_is_unbiased_with_mis(backend):
    """The subset light sampler over all emitters (sample + pdf for MIS) still agrees with Mitsuba."""
    from dyngi.lights.emitter_sampling import EmitterSubsetSampling

    sc = _many_light_scene()
    lights = EmitterSubsetSampling(sc.mi_scene, lambda e: True)
    res, spp, k = (24, 18), 16, 16
    a = np.stack([_ours(sc, res, spp, i, 8, seed0=300, lights=lights) for i in range(k)])
    b = np.stack([_mitsuba(sc, res, spp, i, 8) for i in range(k)])
    ok, info = z_test_images(a, b)
    assert ok, info


def test_emitter_subset_sampling_skips_excluded_emitters(backend):
    """Excluding every emitter but one: NEE sees only that one (its pdf is 0 for the others)."""
    from dyngi.backend import dr, mi
    from dyngi.lights.emitter_sampling import EmitterSubsetSampling

    sc = _many_light_scene()
    ems = list(sc.mi_scene.emitters())
    target = ems[3]
    lights = EmitterSubsetSampling(sc.mi_scene, lambda e: e is target or e == target)
    assert lights.count == 1
    n = 4096
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.p = mi.Point3f(0.0, 0.05, 0.0)
    si.n = mi.Normal3f(0, 1, 0)
    si.sh_frame = mi.Frame3f(si.n)
    rng = np.random.default_rng(1)
    u = mi.Point2f(rng.random(n), rng.random(n))
    ds, w = lights.sample(sc.mi_scene, si, u, mi.Bool(True))
    pdf = lights.pdf(sc.mi_scene, si, ds, mi.Bool(True))
    dr.eval(ds, w, pdf)
    p = np.asarray(ds.p).reshape(3, -1).T
    V = np.asarray(mi.traverse(target.get_shape())["vertex_positions"]).reshape(-1, 3)
    assert np.all(p.min(0) >= V.min(0) - 1e-4) and np.all(p.max(0) <= V.max(0) + 1e-4)
    assert np.allclose(np.asarray(pdf), np.asarray(ds.pdf), rtol=1e-4)


@pytest.mark.parametrize("name", ["sky-pit", "maze"])
def test_agrees_with_mitsuba_sun_sky_and_point_lights(backend, name):
    """Directional sun + constant sky (sky-pit) and point + area lights (maze) agree with Mitsuba."""
    from dyngi.scene import load_scene

    sc = load_scene(name)
    _compare(sc, res=(20, 15))


def test_emitter_subset_single_emitter_direct_call_matches_dispatch(backend):
    """One emitter in the subset: the direct call gives the same samples and weights as the dispatch path."""
    from dyngi.backend import dr, mi
    from dyngi.lights.emitter_sampling import EmitterSubsetSampling

    sc = _many_light_scene()
    target = list(sc.mi_scene.emitters())[2]
    lights = EmitterSubsetSampling(sc.mi_scene, lambda e: e is target or e == target)
    assert lights.single is not None
    n = 4096
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    rng = np.random.default_rng(7)
    si.p = mi.Point3f(*(rng.uniform(-0.5, 0.5, (3, n)).astype(np.float32)))
    si.n = mi.Normal3f(0, 1, 0)
    si.sh_frame = mi.Frame3f(si.n)
    u = mi.Point2f(rng.random(n), rng.random(n))
    ds_a, w_a = lights.sample(sc.mi_scene, si, u, mi.Bool(True))
    dr.eval(ds_a, w_a)
    single, lights.single = lights.single, None          # force the general (table + virtual call) path
    ds_b, w_b = lights.sample(sc.mi_scene, si, u, mi.Bool(True))
    lights.single = single
    dr.eval(ds_b, w_b)
    assert np.count_nonzero(np.asarray(w_a)) > n // 10       # the comparison covers lit samples
    for a, b in ((ds_a.p, ds_b.p), (ds_a.pdf, ds_b.pdf), (w_a, w_b)):
        assert np.allclose(np.asarray(a), np.asarray(b), rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("single", [True, False])
def test_emitter_subset_shadow_mask_and_receiver_cull(backend, single):
    """``sample_traced``: the same samples and weights as ``sample`` wherever the receiver faces the
    sample, weight 0 and no shadow ray where it does not, and the mask says which lanes cast a ray."""
    from dyngi.backend import dr, mi
    from dyngi.lights.emitter_sampling import EmitterSubsetSampling, sample_traced

    sc = _many_light_scene()
    emitters = list(sc.mi_scene.emitters())
    keep = emitters[2:3] if single else emitters[:6]
    lights = EmitterSubsetSampling(sc.mi_scene, lambda e: any(e is k or e == k for k in keep))
    assert (lights.single is not None) == single
    n = 4096
    rng = np.random.default_rng(11)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.p = mi.Point3f(*(rng.uniform(-1.5, 1.5, (3, n)) * [[1], [0.5], [1]] + [[0], [0.6], [0]]).astype(np.float32))
    nrm = rng.normal(size=(3, n))
    nrm /= np.linalg.norm(nrm, axis=0)
    si.n = mi.Normal3f(*nrm.astype(np.float32))
    si.sh_frame = mi.Frame3f(si.n)
    u = mi.Point2f(rng.random(n), rng.random(n))
    active = mi.Bool(rng.random(n) < 0.9)
    ds_a, w_a = lights.sample(sc.mi_scene, si, u, active)
    ds_b, w_b, traced = sample_traced(lights, sc.mi_scene, si, u, active, receiver=si.sh_frame.n)
    dr.eval(ds_a, w_a, ds_b, w_b, traced)
    facing = np.asarray(dr.dot(si.sh_frame.n, ds_a.d)) > 0.0
    pdf_ok = np.asarray(ds_a.pdf) != 0.0
    wa, wb = np.asarray(w_a), np.asarray(w_b)
    expect = np.asarray(active) & pdf_ok & facing
    assert np.array_equal(np.asarray(traced), expect)
    assert 0.2 * n < expect.sum() < 0.8 * n            # both cases occur
    assert np.allclose(wb[:, facing], wa[:, facing], rtol=1e-5, atol=1e-7)
    assert np.all(wb[:, ~facing] == 0.0)
    assert np.count_nonzero(wa[:, ~facing]) > 0      # the cull removed lit samples (their cosine is <= 0)
    # without a receiver: the lanes with a nonzero pdf cast a ray, the weights are `sample`'s
    _, w_c, traced_c = sample_traced(lights, sc.mi_scene, si, u, active)
    assert np.array_equal(np.asarray(traced_c), np.asarray(active) & pdf_ok)
    assert np.allclose(np.asarray(w_c), wa, rtol=1e-5, atol=1e-7)


def test_split_render_is_bitwise_the_full_and_the_indirect_only_render(backend):
    """One path loop gives both images: the full one bit-identical to the plain render, the indirect one to
    the ``indirect_only`` render (same random numbers), and indirect <= full per pixel."""
    from dyngi.scene import load_scene
    from dyngi.techniques.base import to_image
    from dyngi.techniques.path import render_paths, render_paths_split

    sc = load_scene("glossy-floor")
    sc.at(0.3)
    cam, res = sc.camera(0.3), (24, 18)
    L, L_ind, rays = render_paths_split(sc, cam, res, 4, 9, 2, 8, 5)
    full, rays_a = render_paths(sc, cam, res, 4, 9, 2, 8, 5)
    ind, rays_b = render_paths(sc, cam, res, 4, 9, 2, 8, 5, indirect_only=True)
    a, ai = to_image(L, res), to_image(L_ind, res)
    assert np.array_equal(a, to_image(full, res)) and np.array_equal(ai, to_image(ind, res))
    assert int(rays[0]) == int(rays_a[0]) == int(rays_b[0])
    assert np.all(ai <= a * (1 + 1e-5) + 1e-7)
    assert 0.05 * a.mean() < ai.mean() < 0.9 * a.mean()


def test_technique_returns_indirect_and_accumulates_it(backend):
    """``path`` returns FrameResult.indirect (on by default), accumulated like the image; off: None."""
    from dyngi.scene import load_scene
    from dyngi.techniques import Frame, create_technique

    sc = load_scene("cornell-static")
    res = (24, 18)
    off = create_technique("path", sc, {"indirect": False}).step(Frame(0, 0.0, sc.camera(0.0), res, seed=1))
    assert off.indirect is None
    tech = create_technique("path", sc, {"spp": 4, "max_depth": 8})
    for i in range(8):
        r = tech.step(Frame(i, 0.0, sc.camera(0.0), res, seed=1, static=i > 0))
    assert r.stats["accumulated_frames"] == 8 and r.indirect is not None
    assert np.all(r.indirect <= r.image * (1 + 1e-5) + 1e-6)
    # 32 spp accumulated vs 16 x 16 spp of the indirect-only estimator: same mean image (z-test)
    ours = np.stack([_ours(sc, res, 16, i, 8, seed0=910, indirect_only=True) for i in range(16)])
    acc = []
    for k in range(8):
        tk = create_technique("path", sc, {"spp": 16, "max_depth": 8})
        acc.append(tk.step(Frame(0, 0.0, sc.camera(0.0), res, seed=500 + k)).indirect)
    ok, info = z_test_images(np.stack(acc), ours)
    assert ok, info


def test_budgeted_first_frame_returns_indirect(backend):
    """With a ray budget, frame 0 mixes a pilot and the trace: the indirect image is mixed the same way."""
    from dyngi.scene import load_scene
    from dyngi.techniques import Frame, create_technique

    sc = load_scene("cornell-static")
    res = (16, 12)
    tech = create_technique("path", sc, {"max_depth": 6})
    r = tech.step(Frame(0, 0.0, sc.camera(0.0), res, seed=2, ray_budget=16 * 12 * 40))
    assert r.stats["spp"] > 1 and r.indirect is not None
    assert np.all(np.isfinite(r.indirect)) and np.all(r.indirect <= r.image * (1 + 1e-5) + 1e-6)
    assert 0.0 < r.indirect.mean() < r.image.mean()


@pytest.mark.slow
def test_frozen_static_frames_are_bit_identical(backend):
    """``freeze`` (dr.freeze on the static frames' trace) renders what the traced frames render, bit for bit,
    also after the camera moved and stopped again (the recording is keyed by the camera and the motion)."""
    from dyngi.scene import Camera, load_scene
    from dyngi.techniques import Frame, create_technique

    sc = load_scene("cornell-static")
    sc.at(0.0)
    cam_a = sc.camera(0.0)
    cam_b = Camera(tuple(np.add(cam_a.origin, (0.3, 0.0, 0.0))), cam_a.target, cam_a.up, cam_a.fov)
    frames = [(cam_a, False), (cam_a, True), (cam_a, True), (cam_b, False), (cam_b, True), (cam_b, True)]

    def run(freeze):
        tech = create_technique("path", sc, {"freeze": freeze, "max_depth": 4})
        return [tech.step(Frame(i, 0.0, cam, (32, 18), seed=3, static=st)).image for i, (cam, st) in enumerate(frames)]

    a, b = run(True), run(False)
    for i, (x, y) in enumerate(zip(a, b)):
        assert np.array_equal(x, y), f"frame {i} differs"
    assert not np.array_equal(a[2], a[5])      # the second camera is seen


def test_learning_samplers_record_every_lane(backend):
    """path's VLC and CDQ learn from every path: the walk's record buffers hold one slot per lane (they were
    sized by the ``active`` mask, a scalar in ``render_paths_split``, so every lane wrote the same two slots and
    the VLC held 8 entries, the CDQ migrated twice). warehouse-rooms, 64x36, 4 frames: the caches hold hundreds
    of (leaf, light) entries (1608 measured) and the CDQ migrates tens of times (53); a one-slot buffer gives
    8 and 2."""
    from dyngi.experiments.runner import run_sequence
    from dyngi.scene.library import make_builtin
    from dyngi.techniques.base import create_technique

    scene = make_builtin("warehouse-rooms")
    tech = create_technique("path:lights=vlc:directions=cdq:max_depth=3:spp=1:progressive=false", scene)
    run_sequence(scene, tech, 0, (64, 36), seed=0, times=[0.0] * 4, keep_images=False)
    entries = int(np.asarray(tech.lights.sampler.host_caches()).sum())
    migrations = int(tech.directions.cdq.stats()["cdq_migrations_total"])
    assert entries > 500, entries
    assert migrations > 10, migrations
