"""DDGI+ probes, the glossy lookup and ``ddgi-primary`` (DDGI Resampling Secs. 3.1-3.4).

* ``test_glossy_furnace_pi_normalisation`` -- Eq. 6's glossy lookup in a furnace
  of constant probe radiance ``L`` returns ``albedo_g x L`` with the divisor
  pi (``albedo_g`` computed independently, by uniform hemisphere sampling of
  ``bsdf.eval``), and the paper's ``2 pi`` fails (half of it);
* ``test_attenuation_ratio_matches_exact_irradiance`` -- the emission
  heuristic decision: a probe between a small square emitter and the floor
  it shades; the floor's exact irradiance (closed-form form factor) is met by
  ``'ratio'`` in the scene and in the scene scaled by 10, ``'none'`` is ~2x too
  bright, ``'inverse-square'`` is off by the squared unit of length;
* ``test_plus_probes_converge_to_path_traced`` -- DDGI+ probe texels in the
  static Cornell box vs the irradiance at the probe centres path-traced by
  Mitsuba's ``path`` integrator (bound recorded); ``test_plus_glossy_term_closes_the_gap``
  the same on the glossy floor, with and without Eq. 6's glossy term at the hits;
* ``test_ddgi_primary_glossy_only_matches_mitsuba`` -- on a scene without a
  diffuse lobe ``ddgi-primary`` is ReSTIR + a glossy path tracer of depth
  ``glossy_depth + 2``: its image mean z-tested against Mitsuba's ``path``;
* ``test_plus_update_steady_state_compiles_nothing`` -- the DDGI+ update compiles no kernel in steady state;
* ``test_radiance_delta_lights_adds_the_sun`` -- the consumer-side NEE of delta lights is exact on a sunlit plane.
"""
from __future__ import annotations

import numpy as np
import pytest
from helpers import assert_steady_state_compiles_nothing

from dyngi.backend import dr, mi
from dyngi.errors import DyngiError
from dyngi.probes.ddgi_plus import DDGIPlusVolume
from dyngi.probes.glossy import glossy_lookup
from dyngi.probes.query import bilinear_gather
from dyngi.sampling.octahedral import direction_to_texel_coords
from dyngi.scene import load_scene
from dyngi.scene.builder import SceneBuilder
from dyngi.scene.builtin_default import _ceiling_light, _floor
from dyngi.scene.camera import Camera
from dyngi.scene.geometry import box, diffuse
from dyngi.techniques import Frame, create_technique


def _frame(sc, i, res=(8, 8), seed=1):
    return Frame(i, 0.0, sc.camera(0.0), res, seed=seed, static=i > 0)


def _mean3(c) -> np.ndarray:
    return np.array([float(np.asarray(c[i], np.float64).mean()) for i in range(3)])


# -- glossy furnace (Eq. 6 normalisation) -----------------------------------------------------------------
GLOSSY_BSDFS = {
    "roughconductor": {"type": "roughconductor", "material": "none", "alpha": 0.3,
                       "specular_reflectance": {"type": "rgb", "value": [0.8, 0.6, 0.4]}},
    "roughplastic": {"type": "roughplastic", "alpha": 0.2, "diffuse_reflectance": {"type": "rgb", "value": [0.0] * 3}},
    "diffuse": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.6, 0.5, 0.3]}},
}


def _plane_scene(bsdf: dict):
    b = SceneBuilder("glossy-plane")
    b.mesh("plane", _floor(-1, 1, -1, 1, 0.0), bsdf)
    return b.build(Camera((0, 1, 1), (0, 0, 0), (0, 1, 0), 40.0), "plane", duration=1.0,
                   probe_box=((-1, 0.1, -1), (1, 1.1, 1)), probe_counts=(3, 3, 3))


def _hits(sc, wo_world, n):
    """n surface interactions at the plane's centre seen from direction ``wo_world``."""
    w = [float(x) for x in np.asarray(wo_world, np.float64) / np.linalg.norm(wo_world)]
    o = dr.zeros(mi.Point3f, n) + mi.Point3f(*[2.0 * x for x in w])
    ray = mi.Ray3f(o, dr.zeros(mi.Vector3f, n) - mi.Vector3f(*w))
    si = sc.mi_scene.ray_intersect(ray)
    return si, -ray.d


def _albedo_uniform(bsdf_obj, si, n, sampler, glossy_only: bool) -> np.ndarray:
    """Independent estimate of the (glossy) albedo: uniform hemisphere sampling of ``bsdf.eval``."""
    ctx = mi.BSDFContext()
    if glossy_only:
        ctx.type_mask = int(mi.BSDFFlags.GlossyReflection)
    if glossy_only is None:     # the diffuse lobe only
        ctx.type_mask = int(mi.BSDFFlags.DiffuseReflection)
    wi = mi.warp.square_to_uniform_hemisphere(sampler.next_2d())
    f = bsdf_obj.eval(ctx, si, wi, si.is_valid())
    return _mean3(f / mi.warp.square_to_uniform_hemisphere_pdf(wi))


@pytest.mark.parametrize("kind", sorted(GLOSSY_BSDFS))
def test_glossy_furnace_pi_normalisation(kind):
    sc = _plane_scene(GLOSSY_BSDFS[kind])
    vol = DDGIPlusVolume(sc, {"probe_counts": "3", "relocate": False, "classify": False})
    L = np.array([1.0, 2.0, 0.5], np.float32)
    st = vol.volume.state
    st.irradiance[:] = L                  # texels hold E / pi: a furnace of radiance L
    st.distance[..., 0] = 100.0
    st.distance[..., 1] = 100.0 ** 2
    vol.volume.sync()
    n = 1 << 16
    for theta in (20.0, 60.0):
        wo = np.array([np.sin(np.radians(theta)), np.cos(np.radians(theta)), 0.0])
        big = 1 << 20      # the uniform estimate needs many samples for a narrow lobe
        si, wo_w = _hits(sc, wo, big)
        smp = mi.load_dict({"type": "independent"})
        smp.seed(5, big)
        si.wi = si.to_local(wo_w)
        albedo = _albedo_uniform(si.bsdf(), si, big, smp, glossy_only=kind != "diffuse")
        si, wo_w = _hits(sc, wo, n)
        smp = mi.load_dict({"type": "independent"})
        smp.seed(7, n)
        assert albedo.min() > 0.02
        up = mi.Vector3f(0.0, 1.0, 0.0)
        got = _mean3(vol.radiance(si, wo_w, smp.next_2d(), si.is_valid(), glossy=True, u1=smp.next_1d()))
        # L_DDGI+ in the furnace: albedo x L (the diffuse plane: its diffuse term rho/pi * E, E = pi L)
        np.testing.assert_allclose(got, albedo * L, rtol=0.03)
        if kind == "diffuse":
            continue
        # the paper's 2 pi divisor returns half of it: the furnace rejects it
        half = _mean3(glossy_lookup(vol.query, si, up, wo_w, smp.next_1d(), smp.next_2d(), si.is_valid(),
                                    normalisation=2.0 * np.pi))
        assert np.all(np.abs(half / (albedo * L) - 1.0) > 0.4)


# -- the emission attenuation decision (Sec. 3.3) -----------------------------------------------------------
LIGHT_HALF, LIGHT_H, LIGHT_L = 0.3, 2.0, 10.0


def _emitter_scene(s: float):
    """A 0.6 x 0.6 emitter facing down at height 2 over a floor, probes at heights 0.6 and 1.6 (x ``s``)."""
    b = SceneBuilder("attenuation")
    b.mesh("floor", _floor(-3 * s, 3 * s, -3 * s, 3 * s, 0.0), diffuse((0.5, 0.5, 0.5)))
    b.mesh("light", _ceiling_light(0.0, LIGHT_H * s, 0.0, LIGHT_HALF * s), diffuse((0, 0, 0)), (LIGHT_L,) * 3)
    return b.build(Camera((0, s, 2.5 * s), (0, 0, 0), (0, 1, 0), 60.0), "attenuation", duration=1.0,
                   probe_box=((-s, 0.6 * s, -s), (s, 1.6 * s, s)), probe_counts=(3, 2, 3))


def _square_irradiance(half: float, h: float, L: float) -> float:
    """Exact irradiance below the centre of a square emitter (side 2 half, radiance L) at distance h:
    four corner rectangles' differential form factors (parallel planes)."""
    a = half / h
    f = 2.0 * a / np.sqrt(1 + a * a) * np.arctan(a / np.sqrt(1 + a * a)) / (2 * np.pi)
    return float(np.pi * L * 4 * f)


def test_attenuation_ratio_matches_exact_irradiance():
    exact = _square_irradiance(LIGHT_HALF, LIGHT_H, LIGHT_L)
    got = {}
    for s in (1.0, 10.0):
        sc = _emitter_scene(s)
        for att in ("ratio", "none", "inverse-square"):
            vol = DDGIPlusVolume(sc, {"rays_per_probe": 1024, "warmup": 0, "hysteresis": 0.95,
                                      "irradiance_gamma": 1.0, "emission_attenuation": att,
                                      "relocate": False, "classify": False})
            for i in range(60):
                vol.update(_frame(sc, i))
            # the floor point below the centre column of probes: its query reads the probe 0.6 s above it
            E = vol.irradiance(mi.Point3f(0.0, 0.0, 0.0), mi.Vector3f(0.0, 1.0, 0.0), True)
            got[(s, att)] = float(np.asarray(E[0])[0])
    # measured (2026-12-02): ratio 0.857 at both scales vs exact 0.874 (-2%); none 1.75; inverse-square
    # 0.44 (s = 1) and 0.0044 (s = 10)
    for s in (1.0, 10.0):
        assert abs(got[(s, "ratio")] / exact - 1.0) < 0.08, got
        assert got[(s, "none")] / exact > 1.6, got        # the probe-centre value: too bright (Sec. 3.3)
    assert abs(got[(1.0, "inverse-square")] / exact - 1.0) > 0.3, got
    assert got[(1.0, "inverse-square")] / got[(10.0, "inverse-square")] > 50.0, got   # not scale invariant


# -- DDGI+ probes converge to the path-traced irradiance ----------------------------------------------------
def _reference_probe_irradiance(sc, pos: np.ndarray, dirs: np.ndarray, n_rays: int, seed: int = 3):
    """E/pi at probe positions ``pos`` (P, 3) around normals ``dirs`` (D, 3) by Mitsuba's ``path``
    integrator (cosine-sampled rays, unbounded depth): (P, D, 3)."""
    P, D = len(pos), len(dirs)
    n = P * D * n_rays
    idx = dr.arange(mi.UInt32, n)
    smp = mi.load_dict({"type": "independent"})
    smp.seed(seed, n)
    pd = idx // n_rays
    o = dr.gather(mi.Point3f, mi.Point3f(*[mi.Float(np.repeat(pos[:, k], D).astype(np.float32)) for k in range(3)]), pd)
    nrm = dr.gather(mi.Vector3f, mi.Vector3f(*[mi.Float(np.tile(dirs[:, k], P).astype(np.float32))
                                               for k in range(3)]), pd)
    local = mi.warp.square_to_cosine_hemisphere(smp.next_2d())
    d = mi.Frame3f(nrm).to_world(local)
    integ = mi.load_dict({"type": "path", "max_depth": -1, "rr_depth": 5})
    L, _, _ = integ.sample(sc.mi_scene, smp, mi.Ray3f(o, d))
    out = np.stack([np.asarray(L[c], np.float64).reshape(P * D, n_rays).mean(1) for c in range(3)], -1)
    return out.reshape(P, D, 3)


def _plus_vs_path(name: str, glossy: bool = True):
    """(relative error of the mean, per-texel |relative error|) of DDGI+ probe texels (6 axis directions,
    every probe of a 4^3 grid, 40 updates) against the path-traced irradiance at the probe centres."""
    sc = load_scene(name)
    vol = DDGIPlusVolume(sc, {"probe_counts": "4", "rays_per_probe": 512, "hysteresis": 0.95, "warmup": 8,
                              "irradiance_gamma": 1.0, "emission_attenuation": "none", "relocate": False,
                              "classify": False, "probe_glossy": glossy})
    for i in range(40):
        vol.update(_frame(sc, i))
    pos = vol.volume.positions()
    dirs = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], np.float64)
    P, D = len(pos), len(dirs)
    probe = mi.UInt32(np.repeat(np.arange(P), D).astype(np.uint32))
    dd = mi.Vector3f(*[mi.Float(np.tile(dirs[:, k], P).astype(np.float32)) for k in range(3)])
    T = vol.volume.irradiance_texels
    tex = bilinear_gather(vol.volume.device.irradiance, probe, direction_to_texel_coords(dd, T), T, 3)
    got = np.stack([np.asarray(tex[c], np.float64) for c in range(3)], -1).reshape(P, D, 3)
    ref = _reference_probe_irradiance(sc, pos, dirs, 2048)
    lum = np.array([0.2126, 0.7152, 0.0722])
    g, r = got @ lum, ref @ lum
    rel = np.abs(g - r) / np.maximum(r, 1e-3 * r.mean())
    print(f"DDGI+ probes vs path traced ({name}, glossy={glossy}): mean {g.mean() / r.mean() - 1:+.3f}, "
          f"median |rel| {np.median(rel):.3f}, 90% {np.quantile(rel, 0.9):.3f}")
    return g.mean() / r.mean() - 1.0, rel


def test_plus_probes_converge_to_path_traced():
    """Static Cornell box (diffuse): the probes hold the total irradiance of Eq. 5. Measured 2026-12-02:
    mean +0.1%, median per-texel |rel| 0.104, 90% quantile 0.40 (texels near walls, spatial interpolation
    at the hits)."""
    mean_err, rel = _plus_vs_path("cornell-static")
    assert abs(mean_err) < 0.04
    assert np.median(rel) < 0.15


def test_plus_glossy_term_closes_the_gap():
    """glossy-floor (rough-plastic floor, GGX alpha 0.04): with Eq. 6's glossy term at the probe-ray hits the
    probes meet the path-traced irradiance (measured: mean -0.4%, median |rel| 0.019); without it they miss
    the floor's glossy reflection (mean -5.7%, median 0.053)."""
    with_g, rel_g = _plus_vs_path("glossy-floor", glossy=True)
    without, rel_0 = _plus_vs_path("glossy-floor", glossy=False)
    assert abs(with_g) < 0.02 and np.median(rel_g) < 0.04
    assert without < -0.035 and without < with_g - 0.03


# -- ddgi-primary's glossy recursion vs Mitsuba ------------------------------------------------------------
def _metal_box_scene():
    """A closed box of rough metal (no diffuse lobe anywhere) lit by one ceiling light, a metal block inside."""
    b = SceneBuilder("metal-box")
    metal = {"type": "roughconductor", "material": "none", "alpha": 0.25,
             "specular_reflectance": {"type": "rgb", "value": [0.7, 0.6, 0.5]}}
    b.mesh("shell", box((-1, 0, -1), (1, 2, 1), inward=True), metal)
    b.mesh("block", box((-0.4, 0.0, -0.4), (0.2, 0.7, 0.2)),
           {"type": "roughconductor", "material": "none", "alpha": 0.1,
            "specular_reflectance": {"type": "rgb", "value": [0.8, 0.8, 0.8]}})
    b.mesh("light", _ceiling_light(0.0, 1.99, 0.0, 0.3), diffuse((0, 0, 0)), (8.0, 8.0, 8.0))
    return b.build(Camera((0.0, 1.0, 0.95), (0.0, 0.6, -1.0), (0, 1, 0), 70.0), "metal box", duration=1.0,
                   probe_box=((-0.9, 0.1, -0.9), (0.9, 1.9, 0.9)), probe_counts=(3, 3, 3))


def test_ddgi_primary_glossy_only_matches_mitsuba():
    sc = _metal_box_scene()
    res = (32, 24)
    G = 3
    tech = create_technique("ddgi-primary", sc, {"glossy_depth": G, "temporal": False, "probe_counts": "3",
                                                 "rays_per_probe": 16, "warmup": 0, "candidates": 8})
    means = []
    for i in range(24):
        r = tech.step(Frame(i, 0.0, sc.camera(0.0), res, seed=11, static=i > 0))
        means.append(r.image.mean(axis=(0, 1)))
    means = np.array(means)
    cam = sc.camera(0.0)
    refs = []
    for seed in (1, 2):
        img = mi.render(sc.mi_scene, sensor=cam.to_sensor(res, 256),
                        integrator=mi.load_dict({"type": "path", "max_depth": G + 2}), seed=seed, spp=256)
        refs.append(np.asarray(img, np.float64).reshape(-1, 3).mean(0))
    refs = np.array(refs)
    ref = refs.mean(0)
    se = np.sqrt(means.var(0, ddof=1) / len(means) + refs.var(0, ddof=1) / 2 + 1e-12)
    z = (means.mean(0) - ref) / se
    print("ddgi-primary (metal box)", means.mean(0), "mitsuba", ref, "z", z)
    assert np.all(np.abs(z) < 4.0), (means.mean(0), ref, z)
    assert np.all(np.abs(means.mean(0) / ref - 1.0) < 0.05)
    # the recursion matters: without it the image is darker than the reference
    tech0 = create_technique("ddgi-primary", sc, {"glossy_depth": 0, "temporal": False, "probe_counts": "3",
                                                  "rays_per_probe": 16, "warmup": 0, "candidates": 8})
    m0 = np.mean([tech0.step(Frame(i, 0.0, cam, res, seed=11)).image.mean() for i in range(4)])
    assert m0 < 0.9 * ref.mean()


# -- interface -------------------------------------------------------------------------------------------
def test_volume_interface_and_errors():
    sc = load_scene("cornell-static")
    vol = DDGIPlusVolume(sc, {"probe_counts": "3", "rays_per_probe": 16, "warmup": 1})
    assert vol.probe_spacing.shape == (3,) and np.all(vol.probe_spacing > 0)
    st = vol.update(_frame(sc, 0))
    assert st["rays"]["trace probes"] > 0 and "warmup" in st["ms"]
    with pytest.raises(DyngiError, match="emission_attenuation"):
        DDGIPlusVolume(sc, {"emission_attenuation": "cubic"})
    with pytest.raises(DyngiError, match="unknown DDGI\\+ volume parameter"):
        DDGIPlusVolume(sc, {"nope": 1})
    with pytest.raises(DyngiError, match="mode"):
        DDGIPlusVolume(sc, {}, mode="other")


def test_plus_update_steady_state_compiles_nothing():
    """DDGI+ mode (area light, glossy floor, sky): after the first updates no update compiles a kernel."""
    sc = load_scene("glossy-floor")
    vol = DDGIPlusVolume(sc, {"probe_counts": "3", "rays_per_probe": 16, "warmup": 1})
    assert_steady_state_compiles_nothing(lambda f: vol.update(Frame(f, sc.frame_time(f), sc.camera(sc.frame_time(f)),
                                                                    (8, 8), seed=2)), frames=20, warmup=12,
                                         nonempty=True)


def test_radiance_delta_lights_adds_the_sun():
    """``radiance(..., delta_lights=True)`` adds NEE of the light the probes cannot carry: on a diffuse plane
    under a directional sun, with empty probes, exactly ``rho / pi * E_sun * cos``."""
    b = SceneBuilder("sun-plane")
    b.mesh("plane", _floor(-1, 1, -1, 1, 0.0), diffuse((0.5, 0.4, 0.3)))
    d = np.array([-0.5, -1.0, 0.2])
    d /= np.linalg.norm(d)
    b.add("sun", {"type": "directional", "direction": d.tolist(), "irradiance": {"type": "rgb", "value": [3.0] * 3}})
    sc = b.build(Camera((0, 1, 1), (0, 0, 0), (0, 1, 0), 40.0), "sun plane", duration=1.0,
                 probe_box=((-1, 0.1, -1), (1, 1.1, 1)), probe_counts=(3, 3, 3))
    vol = DDGIPlusVolume(sc, {"probe_counts": "3"})
    assert vol.nee_lights.count == 1
    n = 256
    si, wo = _hits(sc, np.array([0.3, 1.0, 0.1]), n)
    smp = mi.load_dict({"type": "independent"})
    smp.seed(1, n)
    got = _mean3(vol.radiance(si, wo, smp.next_2d(), si.is_valid(), sampler=smp, delta_lights=True))
    expect = np.array([0.5, 0.4, 0.3]) / np.pi * 3.0 * (-d[1])
    np.testing.assert_allclose(got, expect, rtol=1e-4)
    assert np.all(_mean3(vol.radiance(si, wo, smp.next_2d(), si.is_valid())) == 0.0)   # the probes are empty
