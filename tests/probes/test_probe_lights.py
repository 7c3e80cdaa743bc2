"""``lights=`` on the probe techniques: a :mod:`dyngi.lights` sampler drives the NEE at
the primary hit (:func:`dyngi.probes.primary.shade_primary`) and at probe-ray hits
(:class:`dyngi.probes.trace.DiffuseHitShader`) through :class:`dyngi.lights.nee.TracedNEE`, its samples
weighted by the ``direct=`` routing (:meth:`dyngi.probes.trace.LightRouting.nee_weight`): a sampler changes
the noise, never the mean. The default ``'scene'`` renders what it rendered before the parameter, bit for
bit (docs/lights.md, "lights= on the probe techniques")."""
from __future__ import annotations

import argparse

import numpy as np
import pytest

from dyngi import lights as light_samplers
from dyngi.errors import DyngiError
from dyngi.scene import load_scene
from dyngi.techniques import Frame, create_technique

PROBE_TECHNIQUES = ("ddgi", "qddgi", "adgi", "isddgi", "probes-reference")


def test_probe_techniques_list_lights_and_unknown_names_list_the_choices(backend, capsys):
    """``dyngi techniques`` shows ``lights = 'scene'`` with every sampler as a choice under each of the five
    probe techniques; an unknown name raises one DyngiError naming the valid ones (before any set-up)."""
    from dyngi.cli import cmd_techniques

    cmd_techniques(argparse.Namespace())
    text = capsys.readouterr().out
    lines = text.splitlines()
    for name in PROBE_TECHNIQUES:
        start = next(i for i, ln in enumerate(lines) if ln.startswith(name + ":"))
        end = next((i for i in range(start + 1, len(lines)) if not lines[i].startswith(" ")), len(lines))
        entry = [ln for ln in lines[start + 1:end] if ln.strip().startswith("lights = ")]
        assert entry and entry[0].strip().startswith("lights = 'scene'"), name
        for kind in light_samplers.names():
            assert kind in entry[0], (name, kind)
    for name in PROBE_TECHNIQUES:      # parameters are checked before the scene is touched
        with pytest.raises(DyngiError, match="lighttree.*power"):
            create_technique(name, None, {"lights": "brightest"})


def _render(sc, cam, spec: str, params: dict, seed: int):
    r = create_technique(spec, sc, params).step(Frame(0, 0.0, cam, (32, 18), seed=seed))
    return r.image, r.indirect


MEAN_TEST = {"probe_counts": "4", "rays_per_probe": 32, "warmup": 2, "direct": "nee", "jitter": False,
             "direct_samples": 32}
"""``ddgi``'s settings of the mean test (and of the table in docs/lights.md)."""


def sampler_runs(scene: str, kinds, seeds, **params) -> dict:
    """kind -> (images K x H x W x 3, indirect images) of ``ddgi`` with :data:`MEAN_TEST` (+ ``params``) and
    ``lights=kind``, one fresh technique per seed, frame 0 at 32x18."""
    sc = load_scene(scene)
    sc.at(0.0)
    cam = sc.camera(0.0)
    out = {}
    for k in kinds:
        runs = [_render(sc, cam, "ddgi", {**MEAN_TEST, **params, "lights": k}, s) for s in seeds]
        out[k] = (np.stack([r[0] for r in runs]), np.stack([r[1] for r in runs]))
    return out


@pytest.mark.slow
def test_light_samplers_render_the_mean_of_the_default(backend):
    """maze (13 lights, area and point), ``ddgi`` with ``direct=nee`` (NEE covers every light, the probes
    only bounced light), 32x18 pixel centres, 32 NEE samples per pixel (fewer leave Mitsuba's emitter
    sampling heavy-tailed at points lit by one of many lights: a per-pixel t-test then rejects the
    reference, not the sampler), a 4^3 grid: 12 independent renders (fresh probes, one seed each) with
    ``lights=power`` and ``lights=lighttree`` against the default (Mitsuba's emitter sampling):
    :func:`stats.z_test_images` (Sidak per pixel, the count of rejections, the image means) on the image,
    and the mean of the indirect part (the probe irradiance, which only the probe-ray NEE feeds; its pixels
    share 64 probes, so only the image mean is an independent sample, Welch's test at 0.01); the same seed
    gives another image (the sampler is in use) and ``ddgi`` hands the same sampler to its probe-ray shader."""
    from stats import z_test_images

    t = create_technique("ddgi", load_scene("maze"), {**MEAN_TEST, "lights": "power"})
    assert t.light_nee is not None and t.shader.lights is t.light_nee
    runs = sampler_runs("maze", ("scene", "power", "lighttree"), range(12))
    ref_img, ref_ind = runs["scene"]
    for kind in ("power", "lighttree"):
        img, ind = runs[kind]
        ok, info = z_test_images(img, ref_img)
        assert ok, (kind, "image", info)
        _, info = z_test_images(ind, ref_ind)
        assert info["p_mean"] >= 0.01, (kind, "indirect", info)
        assert not np.array_equal(img[0], ref_img[0]) and not np.array_equal(ind[0], ref_ind[0]), kind


@pytest.mark.slow
def test_a_general_sampler_keeps_the_direct_routing(backend):
    """``direct=emissive``: NEE owns the delta lights only, and these scenes have none, so every sample of
    ``lights=power`` (triangle lights, and on glossy-floor the sky through Mitsuba's sampling) must get weight
    0 from the routing (its emitter set by :class:`~dyngi.lights.nee.TracedNEE`): with filtered probe-ray
    lookups (the extra selection number changes no other draw) the image is bit-identical to the default's.
    Without the emitter, a triangle light's samples counted twice (NEE and probes). ``hit_lobes='diffuse'``:
    the coated floor's glossy lobe at probe-ray hits (``'layered'``) is drawn after NEE, so the selection
    number shifts its draw (same distribution, not the same bits)."""
    for scene in ("cornell-static", "glossy-floor"):
        sc = load_scene(scene)
        sc.at(0.0)
        cam = sc.camera(0.0)
        p = {"probe_counts": "3", "rays_per_probe": 16, "warmup": 1, "direct": "emissive", "hit_lookup": "filtered",
             "hit_lobes": "diffuse"}
        a = _render(sc, cam, "ddgi", {**p, "lights": "scene"}, 5)
        b = _render(sc, cam, "ddgi", {**p, "lights": "power"}, 5)
        assert a[0].mean() > 0.0, scene
        assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1]), scene


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["lighttree", "vlc"])
def test_steady_frames_with_a_light_sampler_compile_nothing(backend, kind):
    """``ddgi:lights=lighttree|vlc`` on corridor-rooms (14 lights, some switching) at 32x18: after the
    warm-up frames no frame compiles a new kernel (the per-frame seed and the sampler's tables are opaque)."""
    from helpers import assert_steady_state_compiles_nothing

    sc = load_scene("corridor-rooms")
    t = create_technique("ddgi", sc, {"probe_counts": "4", "rays_per_probe": 16, "warmup": 1, "lights": kind})

    def step(f):
        sc.at(f / 30.0)
        t.step(Frame(f, f / 30.0, sc.camera(f / 30.0), (32, 18), seed=1))

    assert_steady_state_compiles_nothing(step, 7, 4, nonempty=True)


def _table(seeds: int = 12) -> None:
    """Prints the z-test table of docs/lights.md ("lights= on the probe techniques"):
    ``python tests/probes/test_probe_lights.py``."""
    import time

    from stats import luminance, z_test_images

    for scene, params, kinds in (("maze", {}, ("power", "lighttree", "vlc", "sll", "uniform")),
                                 ("glossy-floor", {"direct": "sun", "direct_samples": 8}, ("power", "lighttree"))):
        t0 = time.time()
        runs = sampler_runs(scene, ("scene",) + kinds, range(seeds), **params)
        ref_img, ref_ind = runs["scene"]
        print(f"{scene} {params or ''} ({seeds} seeds, {time.time() - t0:.0f} s)")
        print("| sampler | image mean rel. diff | image p (Welch) | pixels rejected / max | min p / Sidak | "
              "indirect mean rel. diff | indirect p | verdict |")
        for k in kinds:
            ok, a = z_test_images(runs[k][0], ref_img)
            _, b = z_test_images(runs[k][1], ref_ind)
            print(f"| {k} | {a['rel_mean_diff']:.4f} | {a['p_mean']:.2f} | {a['rejected']} / {a['max_rejected']} | "
                  f"{a['min_p']:.1e} / {a['sidak_threshold']:.1e} | {b['rel_mean_diff']:.4f} | {b['p_mean']:.2f} | "
                  f"{'pass' if ok and b['p_mean'] >= 0.01 else 'FAIL'} |")
        print("mean luminance (scene):", float(luminance(ref_img).mean()), float(luminance(ref_ind).mean()))


if __name__ == "__main__":
    import os
    import sys

    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    from dyngi import backend as _b

    _b.set_device("cpu")
    _table()
