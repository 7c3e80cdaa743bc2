"""Light candidates in each kind's measure (dyngi.lights.candidates): exact pdfs, chi^2 frequencies."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from stats import chi2_uniform

from dyngi.backend import dr, mi  # first: it selects the libLLVM before mitsuba loads drjit
from dyngi.lights.emitter_table import AREA
from dyngi.lights.candidates import EmitterCandidates
from dyngi.scene import load_scene

N = 400_000


def _chi2():
    import mitsuba.chi2 as c   # after dyngi.backend (libLLVM selection)
    return c


def _sampler(seed, n=N):
    s = mi.load_dict({"type": "independent"})
    s.seed(seed, n)
    return s


def _ref_points(p, n):
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.p = mi.Point3f(*[dr.full(mi.Float, float(c), n) for c in p])
    return si


def test_emitter_selection_frequency_matches_pmf():
    c = EmitterCandidates(load_scene("warehouse-lights").mi_scene)
    assert abs(c.pmf_host.sum() - 1.0) < 1e-6
    s = _sampler(1)
    k, _ = c.sample(_ref_points((0, 1, 0), N), s.next_1d(), s.next_2d())
    counts = np.bincount(np.asarray(k), minlength=c.count)
    ok, p = chi2_uniform(counts, N * c.pmf_host)
    assert ok, p


def _quad_light_scene(tmp_path):
    """An irregular planar quad light (two triangles of very different area) in the plane z = 0."""
    import tempfile
    path = Path(tempfile.mkdtemp()) / "quad.obj"    # (Mitsuba aborts on pytest's long tmp_path names)
    path.write_text("v -0.9 -0.8 0\nv 0.9 -0.8 0\nv 0.7 0.9 0\nv -0.6 -0.2 0\nf 1 2 3\nf 1 3 4\n")
    return mi.load_dict({"type": "scene", "light": {"type": "obj", "filename": str(path),
                                                    "emitter": {"type": "area", "radiance": 2.0}}})


def test_area_candidates_are_uniform_per_unit_area_over_mesh_triangles(tmp_path, monkeypatch):
    """pdf = 1/area (integrates to 1 over the emitter) and sampled points follow it (chi^2, Planar)."""
    monkeypatch.chdir(tmp_path)   # ChiSquareTest writes chi2_data.py on failure
    scene = _quad_light_scene(tmp_path)
    c = EmitterCandidates(scene)
    assert c.kinds_host.tolist() == [AREA]
    area = float(scene.shapes()[0].surface_area()[0])
    ref = np.array([0.1, 0.2, 1.0])

    def sample(u):
        n = dr.width(u)
        k = dr.zeros(mi.UInt32, n)
        ev = c.evaluate(_ref_points(ref, n).p, k, mi.Vector3f(u.x, u.y, 0.0))
        return mi.Point2f(ev.p_light.x, ev.p_light.y)

    def pdf(p):
        n = dr.width(p)
        # the emitter's pdf for a point of the plane: 1/area inside the quad, 0 outside
        ray = mi.Ray3f(mi.Point3f(p.x, p.y, 1.0), mi.Vector3f(0, 0, -1))
        hit = scene.ray_intersect(ray).is_valid()
        return dr.select(hit, 1.0 / area, 0.0)

    c2 = _chi2()
    t = c2.ChiSquareTest(c2.PlanarDomain(mi.ScalarBoundingBox2f([-1, -1], [1, 1])), sample, pdf, sample_dim=2,
                         sample_count=N,
                      res=21, ires=32)   # fine quadrature: the pdf is discontinuous at the edges
    assert t.run(), t.messages
    ev = c.evaluate(_ref_points(ref, 8).p, dr.zeros(mi.UInt32, 8), mi.Vector3f(0.3, 0.6, 0.0))
    assert np.allclose(np.asarray(ev.pdf), 1.0 / area, rtol=1e-5)


def _envmap_scene():
    h, w = 16, 32
    yy, xx = np.mgrid[0:h, 0:w]
    img = (0.2 + 3.0 * np.exp(-((xx - 20) ** 2 + (yy - 5) ** 2) / 6.0))[..., None].repeat(3, -1)
    return mi.load_dict({"type": "scene", "env": {"type": "envmap", "bitmap": mi.Bitmap(img.astype(np.float32))}})


@pytest.mark.parametrize("which", ["constant", "envmap"])
def test_environment_candidates_follow_their_solid_angle_pdf(which, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    scene = _envmap_scene() if which == "envmap" else mi.load_dict({"type": "scene",
                                                                    "env": {"type": "constant"}})
    c = EmitterCandidates(scene)
    ref = np.array([0.0, 0.0, 0.0])

    def sample(u):
        n = dr.width(u)
        k, pl = c.sample(_ref_points(ref, n), dr.zeros(mi.Float, n), u)
        return c.evaluate(_ref_points(ref, n).p, k, pl).wi

    def pdf(d):
        n = dr.width(d)
        return c.evaluate(_ref_points(ref, n).p, dr.zeros(mi.UInt32, n), d).pdf

    c2 = _chi2()
    t = c2.ChiSquareTest(c2.SphericalDomain(), sample, pdf, sample_dim=2, sample_count=N, res=31)
    assert t.run(), t.messages
    # the pdf integrates to 1 over the sphere (uniform-direction quadrature)
    s = _sampler(5, 1 << 18)
    d = mi.warp.square_to_uniform_sphere(s.next_2d())
    integral = float(np.mean(np.asarray(pdf(d)))) * 4.0 * np.pi
    assert abs(integral - 1.0) < 0.01


@pytest.mark.parametrize("name", ["maze", "sky-pit", "glossy-floor", "warehouse-lights"])
def test_mixed_kinds_estimate_direct_light_like_mitsuba(name):
    """Lg cos / pdf over all candidate kinds (area, point, directional, environment) has the same mean
    as Mitsuba's own emitter sampling: the pdfs of the different measures are consistent."""
    scene = load_scene(name)
    ms = scene.mi_scene
    c = EmitterCandidates(ms)
    cam = scene.camera(0.0)
    hit = ms.ray_intersect(cam.sample_rays((1, 1), dr.zeros(mi.UInt32, 1), mi.Point2f(0.5, 0.5)))
    nrm = np.asarray(hit.n).ravel()
    si = _ref_points(np.asarray(hit.p).ravel() + 1e-3 * nrm, N)
    nv = mi.Vector3f(*[float(x) for x in nrm])
    s = _sampler(7)
    k, pl = c.sample(si, s.next_1d(), s.next_2d())
    ev = c.evaluate(si.p, k, pl)
    a = np.asarray(dr.select(ev.pdf > 0, ev.Lg * dr.maximum(dr.dot(ev.wi, nv), 0.0) / ev.pdf, 0.0)).sum(0)
    ds, spec = ms.sample_emitter_direction(si, s.next_2d(), False)
    b = np.asarray(spec * dr.maximum(dr.dot(ds.d, nv), 0.0)).sum(0)
    z = (a.mean() - b.mean()) / np.sqrt(a.var() / N + b.var() / N)
    assert abs(z) < 4.0, (a.mean(), b.mean())
