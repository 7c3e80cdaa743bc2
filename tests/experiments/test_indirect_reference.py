"""Indirect-only reference (dyngi's path tracer, first vertex's emission + direct light left out) vs Mitsuba."""
import numpy as np
import pytest

from dyngi.errors import DyngiError
from stats import z_test_images


def _mitsuba(scene, res, spp, seed, max_depth, t=0.0):
    from dyngi.backend import mi

    scene.at(t)
    sensor = scene.camera(t).to_sensor(res, spp)
    integ = mi.load_dict({"type": "path", "max_depth": max_depth, "rr_depth": 5})
    return np.asarray(mi.render(scene.mi_scene, sensor=sensor, integrator=integ, spp=spp, seed=seed),
                      np.float64)[..., :3]


def _plane_scene(light: str):
    """One diffuse plane under a light (and a sky): no point of it sees another, so nothing is indirect."""
    from dyngi.scene.builder import SceneBuilder
    from dyngi.scene.camera import Camera
    from dyngi.scene.geometry import diffuse, quad

    b = SceneBuilder(f"plane-{light}")
    b.mesh("floor", quad((0, 0, 0), (0, 0, 2), (2, 0, 0)), diffuse((0.8, 0.7, 0.6)))
    if light == "area":
        b.mesh("light", quad((0.3, 1.2, 0.0), (0.3, 0, 0), (0, 0, 0.3)), diffuse((0, 0, 0)), (8.0, 8.0, 8.0))
    else:
        b.add("sun", {"type": "directional", "direction": [0.3, -1.0, 0.2],
                      "irradiance": {"type": "rgb", "value": [3.0, 3.0, 3.0]}})
        b.add("sky", {"type": "constant", "radiance": {"type": "rgb", "value": [0.4, 0.5, 0.7]}})
    return b.build(Camera((0, 1.5, 2.5), (0, 0, 0), (0, 1, 0), 50.0), "one plane under a light")


@pytest.mark.parametrize("light", ["area", "sun-sky"])
def test_single_plane_has_no_indirect_light(backend, light):
    from dyngi.experiments.references.indirect import indirect_reference_image

    sc = _plane_scene(light)
    img, noise = indirect_reference_image(sc, 0.0, (24, 18), 16, 8, seed=3)
    assert img.shape == (18, 24, 3) and img.dtype == np.float32
    assert np.all(img == 0.0), float(np.abs(img).max())
    assert noise["mse"] == 0.0 and noise["relmse"] == 0.0
    assert _mitsuba(sc, (24, 18), 16, 1, 8).mean() > 0.05      # the plane is lit (directly)


@pytest.mark.parametrize("name", ["cornell-static", pytest.param("sky-pit", marks=pytest.mark.slow)])  # CI budget
def test_indirect_plus_direct_is_full(backend, name):
    """ours(indirect) + Mitsuba(max_depth=2), independent, estimates Mitsuba(max_depth=8): per-pixel z-test."""
    from dyngi.experiments.references.indirect import indirect_reference_image
    from dyngi.scene import load_scene

    sc = load_scene(name)
    res, spp, k = (24, 18), 16, 16
    ours = np.stack([indirect_reference_image(sc, 0.0, res, spp, 8, seed=100 + i)[0] for i in range(k)])
    direct = np.stack([_mitsuba(sc, res, spp, 2000 + i, 2) for i in range(k)])
    full = np.stack([_mitsuba(sc, res, spp, 3000 + i, 8) for i in range(k)])
    assert ours.mean() > 0.05 * full.mean(), "no indirect light at all?"
    ok, info = z_test_images(ours + direct, full)
    assert ok, info


def test_agrees_with_mitsuba_difference_within_noise(backend):
    """Against Mitsuba full minus Mitsuba max_depth=2 (same seed, a high-spp stand-in for the truth): the MSE
    is what the two images' estimated noise predicts, and the halves' noise estimate is calibrated."""
    from dyngi.experiments.references.indirect import indirect_reference_image
    from dyngi.scene import load_scene

    sc = load_scene("cornell-moving-box")
    t, res = 0.4, (24, 18)
    # Mitsuba's indirect image at 4 x 256 spp; its own noise from the spread of the 4 (same-seed differences)
    mits = np.stack([_mitsuba(sc, res, 256, s, 8, t) - _mitsuba(sc, res, 256, s, 2, t) for s in range(4)])
    assert mits.min() > -1e-4
    truth = mits.mean(0)
    mse_truth = float(np.mean(mits.var(0, ddof=1)) / 4)
    runs = [indirect_reference_image(sc, t, res, 64, 8, seed=40 + i) for i in range(6)]
    for img, noise in runs:
        assert np.all(img >= 0.0) and noise["spp"] == 64 and noise["res"] == [24, 18]
    mse = np.array([np.mean((img - truth) ** 2) for img, _ in runs]) - mse_truth
    est = np.array([noise["mse"] for _, noise in runs])
    ratio = mse.mean() / est.mean()
    assert 0.6 < ratio < 1.6, (ratio, mse, est, mse_truth)
    # the estimate tracks the actual error frame by frame, not only on average
    assert np.all(mse < 3.0 * est), (mse, est)


def test_cache_roundtrip_and_key(backend, tmp_path):
    from dyngi.experiments.references.indirect import cached_indirect_reference, indirect_reference_image
    from dyngi.scene import load_scene

    sc = load_scene("cornell-moving-light")
    img, noise, hit = cached_indirect_reference(sc, 0.2, (16, 12), 8, 6, seed=1, cache_dir=tmp_path)
    assert not hit and noise["relmse"] > 0
    img2, noise2, hit2 = cached_indirect_reference(sc, 0.2, (16, 12), 8, 6, seed=1, cache_dir=tmp_path)
    assert hit2 and np.array_equal(img, img2) and noise2 == noise
    direct, _ = indirect_reference_image(sc, 0.2, (16, 12), 8, 6, seed=1)
    assert np.array_equal(direct, img)                       # the cache stores exactly what is rendered
    _, _, hit3 = cached_indirect_reference(sc, 0.2, (16, 12), 8, 6, seed=2, cache_dir=tmp_path)
    _, _, hit4 = cached_indirect_reference(sc, 0.3, (16, 12), 8, 6, seed=1, cache_dir=tmp_path)
    assert not hit3 and not hit4
    assert len(list(tmp_path.glob("*-indirect-*.exr"))) == 3 and not list(tmp_path.glob(".*tmp*"))
    # a corrupt entry is re-rendered, not returned
    for js in tmp_path.glob("*.json"):
        js.write_text("{")
    _, _, hit5 = cached_indirect_reference(sc, 0.2, (16, 12), 8, 6, seed=1, cache_dir=tmp_path)
    assert not hit5


@pytest.mark.parametrize("kw, what", [
    ({"max_depth": 2}, "max_depth"), ({"max_depth": 0}, "max_depth"), ({"spp": 1}, "spp"),
    ({"res": (0, 4)}, "resolution"), ({"res": "64x48"}, "resolution"), ({"t": float("nan")}, "time"),
    ({"seed": -1}, "seed"),
])
def test_bad_settings(backend, kw, what):
    from dyngi.experiments.references.indirect import cached_indirect_reference, indirect_reference_image
    from dyngi.scene import load_scene

    sc = load_scene("cornell-static")
    args = {"t": 0.0, "res": (8, 6), "spp": 4, "max_depth": 6, "seed": 0, **kw}
    for f in (indirect_reference_image, cached_indirect_reference):
        with pytest.raises(DyngiError, match=what):
            f(sc, args["t"], args["res"], args["spp"], args["max_depth"], args["seed"])


def test_unbounded_depth_furnace(backend):
    """Furnace (albedo 0.5, emission 0.5, L = 1): the indirect part is L - e - a e = 0.25 everywhere."""
    from dyngi.experiments.references.indirect import indirect_reference_image
    from dyngi.scene import load_scene

    img, noise = indirect_reference_image(load_scene("furnace"), 0.0, (16, 12), 256, -1, seed=0)
    assert abs(img.mean() - 0.25) < 0.005, img.mean()
    assert noise["mse"] > 0 and np.sqrt(noise["mse"]) < 0.05


def _builtin_names():
    from dyngi.scene import builtin_names
    return builtin_names()


@pytest.mark.slow
@pytest.mark.parametrize("name", _builtin_names())
def test_agrees_with_mitsuba_difference_on_every_builtin_scene(backend, name):
    """ours vs Mitsuba(12) - Mitsuba(2) (same seed per pair), per-pixel z-test, at a mid-animation frame."""
    from dyngi.experiments.references.indirect import indirect_reference_image
    from dyngi.scene import load_scene

    sc = load_scene(name)
    t = sc.frame_time(17)
    res, spp, k = (24, 18), 16, 12
    ours = np.stack([indirect_reference_image(sc, t, res, spp, 12, seed=700 + i)[0] for i in range(k)])
    theirs = np.stack([_mitsuba(sc, res, spp, 800 + i, 12, t) - _mitsuba(sc, res, spp, 800 + i, 2, t)
                       for i in range(k)])
    ok, info = z_test_images(ours, theirs)
    assert ok, info
