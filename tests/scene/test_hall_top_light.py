"""``hall-top-light``: DDGI on a two-storey hall lit from the top, against Mitsuba's ``path``.

The analog of the real staircase hall where ``ddgi`` drew whole regions black
(-16% to -36% image mean). Diagnosed causes, both at the primary hit: glass
shaded as an opaque black surface (Mitsuba sees through it), and an area
light with a mirroring to_world whose emission was masked off by the
geometric-normal "front" test. Before the fix this file failed: mean ratio
0.36, 4.1% of the lit pixels black; after it: 1.01 (0.94 without the pixels
that see the light), 0.03% black, frame-to-frame mean change 0.3% (measured,
64x48). The remaining -6% is mostly the glass panel stopping probe rays.
"""
import numpy as np
import pytest

from dyngi.backend import mi
from dyngi.scene import builtin_names, load_scene
from dyngi.techniques.base import Frame, create_technique

RES = (64, 48)
FRAMES = 40
SETTLED = 20          # frames from which the image counts as converged (hysteresis 0.97, 8 warm-up updates)
LIGHT = 5.0           # luminance above which a reference pixel shows the top light itself (radiance ~28)


@pytest.fixture(scope="module")
def hall():
    sc = load_scene("hall-top-light")
    sc.at(0.0)          # the static part (the light dims after t = 1 s)
    sensor = sc.camera(0.0).to_sensor(RES, 512)
    integ = mi.load_dict({"type": "path", "max_depth": 32, "rr_depth": 8})
    ref = np.asarray(mi.render(sc.mi_scene, sensor=sensor, integrator=integ, spp=512, seed=17), np.float32)
    # pixel centres (no jitter: the visible light's edge coverage would move the mean by ~5% per frame) and
    # 4 NEE samples per pixel (1 leaves ~0.7% frame-to-frame noise in the mean at this small resolution)
    tech = create_technique("ddgi", sc, {"jitter": False, "direct_samples": 4})
    images = [tech.step(Frame(f, 0.0, sc.camera(0.0), RES, seed=2)).image for f in range(FRAMES)]
    return sc, ref, np.stack(images), tech


def test_hall_is_a_registered_builtin_static_until_the_light_dims():
    assert "hall-top-light" in builtin_names()
    sc = load_scene("hall-top-light")
    assert len(sc.meta.emitters) == 1
    assert sc.signature(0.0) == sc.signature(0.9) != sc.signature(1.5) != sc.signature(2.0)
    assert sc.signature(2.0) == sc.signature(4.0)


def test_ddgi_hall_mean_within_10_percent_of_mitsuba(hall):
    _, ref, images, _ = hall
    img = images[SETTLED:].mean(0)
    assert np.all(np.isfinite(img))
    ratio = img.mean() / ref.mean()
    assert abs(ratio - 1.0) < 0.10, ratio         # measured 1.01 (0.36 before the fix)
    # the same without the pixels that see the light itself: the light in the hall, mostly indirect
    lum = ref.mean(-1)
    keep = lum < LIGHT
    assert 0.8 < keep.mean() < 1.0
    ratio_gi = img[keep].mean() / ref[keep].mean()
    assert abs(ratio_gi - 1.0) < 0.10, ratio_gi


def test_ddgi_hall_has_no_black_where_the_reference_is_lit(hall):
    """Fraction of lit reference pixels that ddgi draws below 5% of the reference (0.03% measured; 4.1% before:
    the glass panel with the gallery behind it, and the top light)."""
    _, ref, images, _ = hall
    img = images[SETTLED:].mean(0)
    r, d = ref.mean(-1), img.mean(-1)
    lit = r > 0.1 * np.median(r)
    black = lit & (d < 0.05 * r)
    assert black.sum() / lit.sum() < 0.005, black.sum() / lit.sum()
    # the light is seen (Mitsuba: emits on its shading normal's side) and the glass lets the gallery through
    top = r > LIGHT     # (edge pixels: the reference box-filters the light's edge, ddgi reads pixel centres)
    assert top.sum() >= 10 and np.mean(d[top] > 0.5 * r[top]) > 0.8


def test_ddgi_hall_mean_is_stable_after_convergence(hall):
    """Static scene: the image mean changes by less than 1% from frame to frame (measured: 0.3%)."""
    _, _, images, _ = hall
    m = images[SETTLED:].mean(axis=(1, 2, 3))
    assert np.max(np.abs(np.diff(m))) / m.mean() < 0.01, m
