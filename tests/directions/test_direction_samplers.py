"""The one direction-sampler interface (dyngi.directions): every sampler's directions
follow the pdf it reports (chi^2 on the sphere with Mitsuba's harness, pbrt/Mitsuba's BSDF test), for a
real BSDF, the diffuse stand-in and the CDQ/BSDF mixture with a learned CDQ; unknown names raise."""
import numpy as np
import pytest

from dyngi.backend import dr, mi


class _FakeOctree:
    def __init__(self, n):
        self.leaf_count = n
        self.prev_leaf = mi.UInt32(np.arange(n, dtype=np.uint32))


def _learned_cdq():
    """A CDQ whose leaf 0 learned a narrow lobe (tests/sampling/test_cdq.py's scripted peak)."""
    from dyngi.directions import cdq
    g = cdq.CDQDirections(_FakeOctree(2), bits=64)
    peak = np.array([0.3, 0.5, 0.81])
    peak /= np.linalg.norm(peak)
    rng = np.random.default_rng(0)
    n = 20_000
    leaf = mi.UInt32(np.zeros(n, np.uint32))
    for _ in range(6):
        g.begin_frame()
        d, pdf = g.sample(leaf, mi.Point2f(rng.random(n), rng.random(n)), True)
        L = dr.exp(8.0 * (d.x * peak[0] + d.y * peak[1] + d.z * peak[2] - 1.0))
        g.record(leaf, d, L / pdf, True)
        g.end_frame()
    return g


def _vertex(material, wi=(0.3, -0.2, 0.93)):
    from dyngi.directions import Vertex
    bsdf = mi.load_dict(material) if material is not None else None
    si = dr.zeros(mi.SurfaceInteraction3f)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    si.n = mi.Normal3f(0, 0, 1)
    w = np.asarray(wi) / np.linalg.norm(wi)
    si.wi = mi.Vector3f(*(float(x) for x in w))
    si.p = mi.Point3f(0.0)
    albedo = mi.Color3f(0.5) if bsdf is None else None
    return Vertex(si, mi.Vector3f(0, 0, 1), bsdf, albedo, mi.UInt32(0), True)


CASES = {
    "bsdf-diffuse-standin": ("bsdf", None),
    "bsdf-roughplastic": ("bsdf", {"type": "roughplastic", "alpha": 0.2}),
    "cdq-mixture-diffuse-standin": ("cdq", None),
    "cdq-mixture-roughconductor": ("cdq", {"type": "roughconductor", "alpha": 0.3}),
    "cdq-mixture-0.8-roughplastic": ("cdq", {"type": "roughplastic", "alpha": 0.2}, 0.8),   # nee-pt cdq_fraction
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_directions_follow_their_pdf_chi2(backend, case):
    from mitsuba.chi2 import ChiSquareTest, SphericalDomain
    from dyngi import directions
    name, material, *frac = CASES[case]
    opts = {"fraction": frac[0]} if frac else {}
    f = frac[0] if frac else 0.5
    ds = directions.make(name, guide=_learned_cdq() if name == "cdq" else None, **opts)
    v = _vertex(material)

    def sample(s):
        n = dr.width(s)
        vv = _vertex(material)
        vv.si = dr.gather(mi.SurfaceInteraction3f, v.si, dr.zeros(mi.UInt32, n))
        vv.leaf = dr.zeros(mi.UInt32, n)
        vv.active = mi.Bool(True)
        if vv.albedo is not None:
            vv.albedo = mi.Color3f(0.5)
        u1 = dr.select(s.x < f, s.x / f, (s.x - f) / (1.0 - f))    # independent of the component choice
        d = ds.sample(vv, s.x, u1, mi.Point2f(s.y, s.z), mi.Bool(True))
        return d.wo, dr.select(d.ok, mi.Float(1.0), mi.Float(0.0))      # failed samples carry no mass

    def pdf(wo):
        n = dr.width(wo)
        vv = _vertex(material)
        vv.si = dr.gather(mi.SurfaceInteraction3f, v.si, dr.zeros(mi.UInt32, n))
        vv.leaf = dr.zeros(mi.UInt32, n)
        vv.active = mi.Bool(True)
        if vv.albedo is not None:
            vv.albedo = mi.Color3f(0.5)
        return ds.pdf(vv, wo, mi.Bool(True))

    test = ChiSquareTest(domain=SphericalDomain(), sample_func=sample, pdf_func=pdf, sample_dim=3,
                         sample_count=400_000, res=61, ires=8, seed=3)
    assert test.run(0.01, len(CASES)), f"{case}: directions disagree with the pdf\n{test.messages}"


def test_unknown_direction_sampler_raises(backend):
    from dyngi import directions
    from dyngi.errors import DyngiError
    assert set(directions.names()) == {"bsdf", "cdq"}
    with pytest.raises(DyngiError):
        directions.make("nope")
    with pytest.raises(DyngiError):
        directions.make("cdq")          # the mixture needs a learned CDQ


@pytest.mark.slow   # CI budget (10-30 s on a cold cache); runs in CI's slow subset
def test_path_with_cdq_directions_is_unbiased(backend):
    """path:directions=cdq (the walk with the CDQ/BSDF mixture, learning over the frames) against path."""
    import os
    import sys
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "techniques"))
    from stats import z_test_images
    from test_path import _glossy_scene, _ours
    from dyngi.directions.walk import WalkDirections
    sc = _glossy_scene()
    res, spp, K = (16, 12), 8, 12

    class F:
        time = 0.0

    wd = WalkDirections(sc, "cdq", bits=64)
    a = []
    for i in range(K):
        F.index = i
        wd.begin_frame(sc, F, 2 * res[0] * res[1] * spp)
        a.append(_ours(sc, res, spp, i, 4, directions=wd))
        wd.end_frame()
    assert wd.stats()["cdq_migrations_total"] > 0          # it learned something
    b = np.stack([_ours(sc, res, spp, i, 4, seed0=9000) for i in range(K)])
    a = np.stack(a)
    assert np.all(np.isfinite(a)) and a.mean() > 0
    ok, info = z_test_images(a, b)
    assert ok, f"path:directions=cdq disagrees with path: {info}"


class _Uniforms:
    """A sampler that hands out given uniform numbers (the chi^2 harness's sample points)."""

    def __init__(self, s):
        self.s = s

    def next_1d(self):
        return self.s.x

    def next_2d(self):
        return mi.Point2f(self.s.y, self.s.z)


@pytest.mark.parametrize("material", [{"type": "roughplastic", "alpha": 0.2},
                                      {"type": "roughconductor", "alpha": 0.3}])
def test_lobe_directions_follow_their_pdf_chi2(backend, material):
    """The walk's lobe-restricted strategy (directions/lobes.py: the DDGI Resampling family's glossy
    recursion) samples the glossy lobes with the density its ``pdf`` reports."""
    from mitsuba.chi2 import ChiSquareTest, SphericalDomain
    from dyngi.directions.lobes import LobeDirections
    lobes = LobeDirections(mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.DeltaReflection)
    v = _vertex(material)

    def vertex(n):
        vv = _vertex(material)
        vv.si = dr.gather(mi.SurfaceInteraction3f, v.si, dr.zeros(mi.UInt32, n))
        return vv

    def sample(s):
        d = lobes.sample(vertex(dr.width(s)), _Uniforms(s), mi.Bool(True))
        return d.wo, dr.select(d.ok, mi.Float(1.0), mi.Float(0.0))

    def pdf(wo):
        return lobes.pdf(vertex(dr.width(wo)), wo, mi.Bool(True))

    test = ChiSquareTest(domain=SphericalDomain(), sample_func=sample, pdf_func=pdf, sample_dim=3,
                         sample_count=200_000, res=61, ires=8, seed=5)
    assert test.run(0.01, 2), f"lobes: directions disagree with the pdf\n{test.messages}"


@pytest.mark.slow
def test_restir_pt_with_cdq_directions_is_unbiased(backend):
    """restir-pt:directions=cdq (the path after ReSTIR's primary vertex with the learned CDQ/BSDF mixture)
    against restir-pt: K independent non-progressive frames of the glossy test scene, per-pixel z-test."""
    import os
    import sys
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "techniques"))
    from stats import z_test_images
    from test_path import _glossy_scene
    from dyngi.techniques import Frame, create_technique
    sc = _glossy_scene()
    res, K = (16, 12), 16

    def frames(extra, seed0):
        tech = create_technique("restir-pt", sc, dict(max_depth=4, progressive=False, temporal=False, spatial=0,
                                                      candidates=4, **extra))
        imgs = np.stack([tech.step(Frame(i, 0.0, sc.camera(0.0), res, seed=seed0 + i)).image for i in range(K)])
        return imgs, tech

    a, tech = frames({"directions": "cdq"}, 100)
    b, _ = frames({}, 500)
    assert tech.directions.stats()["cdq_migrations_total"] > 0          # it learned something
    assert np.all(np.isfinite(a)) and a.mean() > 0
    ok, info = z_test_images(a, b)
    assert ok, f"restir-pt:directions=cdq disagrees with restir-pt: {info}"
