"""DDGI Resampling's core claim (Majercik et al. 2022, Sec. 4, Fig. 8, Table 1): resampling the
secondary vertices jointly with direct light gives a *quieter* frame than one plain BSDF bounce into
the same DDGI+ probes (Secondary DDGI).

The measure: per-frame MAPE against Mitsuba's ``path`` with accumulation off (``progressive=false``),
averaged over the steady frames (probes and reservoirs warmed), per seed; one-sided paired t-test
over seeds that ``ddgi-resampling``'s is below ``ddgi-secondary``'s.

The module also holds the ablation harness the figures on docs/techniques/ddgi-resampling.md come from (:func:`steady_errors`); run
``python tests/techniques/ddgi_resampling/test_claim.py SCENE SPEC [SPEC...] [--seeds N] ...`` to print
mean and spread per spec.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np
import pytest
from scipy import stats as sst

STEADY_FROM = 8
"""First frame counted as steady (probes and reservoirs warmed; our choice for these tests)."""


def steady_errors(scene_name: str, spec: str, seeds, frames: int = 16, res=(64, 36), ref_spp: int = 256,
                  steady_from: int = STEADY_FROM, t: float = 0.0):
    """Per seed, the mean over frames ``steady_from..frames-1`` of the per-frame MAPE and relMSE of
    ``spec`` (accumulation off) on a static view of ``scene_name`` at time ``t``, against one cached
    Mitsuba ``path`` reference of ``ref_spp`` samples. Returns (mape[seeds], relmse[seeds], ms/frame)."""
    from dyngi.experiments.references.path import cached_reference, scene_max_depth
    from dyngi.metrics.image import mape, relmse
    from dyngi.scene import load_scene
    from dyngi.techniques import Frame, create_technique
    from dyngi.techniques.base import parse_spec

    scene = load_scene(scene_name)
    scene.at(t)
    ref, _ = cached_reference(scene, t, res, ref_spp, scene_max_depth(scene))
    sp = parse_spec(spec)
    params = dict(sp.params)
    if "progressive" in type(create_technique(sp.name, scene, params)).PARAMS:
        params["progressive"] = False
    m_all, r_all, ms = [], [], []
    for seed in seeds:
        scene.at(t)
        tech = create_technique(sp.name, scene, params)
        em, er = [], []
        for i in range(frames):
            w0 = time.perf_counter()
            out = tech.step(Frame(i, t, scene.camera(t), tuple(res), seed=int(seed), static=i > 0))
            if i >= steady_from:
                ms.append(1e3 * (time.perf_counter() - w0))
                em.append(mape(out.image, ref))
                er.append(relmse(out.image, ref))
        m_all.append(float(np.mean(em)))
        r_all.append(float(np.mean(er)))
    return np.array(m_all), np.array(r_all), float(np.median(ms))


def steady_images(scene_name: str, spec: str, seeds, frames: int, res, steady_from: int = STEADY_FROM,
                  t: float = 0.0):
    """Per seed, the steady frames' images (``steady_from..frames-1``) of ``spec`` with accumulation off."""
    from dyngi.scene import load_scene
    from dyngi.techniques import Frame, create_technique
    from dyngi.techniques.base import parse_spec

    scene = load_scene(scene_name)
    sp = parse_spec(spec)
    params = dict(sp.params)
    if "progressive" in type(create_technique(sp.name, scene, params)).PARAMS:
        params["progressive"] = False
    out = []
    for seed in seeds:
        scene.at(t)
        tech = create_technique(sp.name, scene, params)
        ims = []
        for i in range(frames):
            r = tech.step(Frame(i, t, scene.camera(t), tuple(res), seed=int(seed), static=i > 0))
            if i >= steady_from:
                ims.append(np.asarray(r.image, np.float64))
        out.append(ims)
    return out


REF_NOISE_FACTOR = 10
"""The claim test's reference is grown until its own noise MAPE is at most 1/10 of the smallest per-frame MAPE
it ranks (as the reproduction's step 1)."""


def grown_reference(scene_name: str, res, images: dict, spp: int = 256, spp_max: int = 1 << 15, t: float = 0.0):
    """Mitsuba's ``path`` as two growing halves (the reproduction's ``_Reference``), doubled until its noise
    MAPE is at most 1/:data:`REF_NOISE_FACTOR` of the smallest mean per-frame MAPE of ``images`` (spec -> per
    seed lists of images) or ``spp_max`` is reached. Returns (reference, {spec: per-seed MAPE array})."""
    from dyngi.experiments.references.path import scene_max_depth
    from dyngi.experiments.reproductions.ddgi_resampling import _Reference
    from dyngi.metrics.image import mape
    from dyngi.scene import load_scene

    scene = load_scene(scene_name)
    scene.at(t)
    R = _Reference(scene, tuple(res), spp, scene_max_depth(scene))
    while True:
        m = {k: np.array([np.mean([mape(im, R.image) for im in ims]) for ims in v]) for k, v in images.items()}
        if R.noise * REF_NOISE_FACTOR <= min(float(x.mean()) for x in m.values()) or R.spp >= spp_max:
            return R, m
        R.double()


CLAIM_SCENES = ("villa-sun", "room-door")
"""The Table 1 analogs where the paper's resampling wins: a thick-walled sunlit villa and a room lit only
through a door (``living-room`` is the paper's exception, not tested here)."""


@pytest.mark.slow
@pytest.mark.parametrize("name", CLAIM_SCENES)
def test_resampled_frame_is_quieter_than_secondary_ddgi(backend, name):
    """Steady per-frame MAPE (accumulation off, frames 8-11, 64x36, 3 seeds each): ``ddgi-resampling``
    below ``ddgi-secondary`` by a one-sided Welch t-test at the 1 % level (same probes, same ReSTIR DI
    settings for the direct light of ``ddgi-secondary``), against a reference grown until its own noise MAPE
    is at most 1/10 of the smaller of the two (:func:`grown_reference`; at 256 spp it was 0.13-0.25, as
    large as the errors ranked)."""
    seeds = range(3)
    res, frames = (64, 36), 12
    imgs = {s: steady_images(name, s, seeds, frames, res) for s in ("ddgi-resampling", "ddgi-secondary")}
    R, m = grown_reference(name, res, imgs)
    a, b = m["ddgi-resampling"], m["ddgi-secondary"]
    assert R.noise * REF_NOISE_FACTOR <= min(a.mean(), b.mean()), (name, R.spp, R.noise, a, b)
    p = float(sst.ttest_ind(a, b, equal_var=False, alternative="less").pvalue)
    assert a.mean() < b.mean() and p < 0.01, (name, R.spp, R.noise, a, b, p)


def _main(argv=None):
    ap = argparse.ArgumentParser(description="steady per-frame MAPE / relMSE of technique specs (ablation rows)")
    ap.add_argument("scene")
    ap.add_argument("specs", nargs="+")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--frames", type=int, default=16)
    ap.add_argument("--steady-from", type=int, default=STEADY_FROM)
    ap.add_argument("--res", default="64x36")
    ap.add_argument("--ref-spp", type=int, default=256)
    a = ap.parse_args(argv)
    from dyngi import backend
    backend.set_device("cpu")
    res = tuple(int(x) for x in a.res.split("x"))
    for spec in a.specs:
        m, r, ms = steady_errors(a.scene, spec, range(a.seeds), a.frames, res, a.ref_spp, a.steady_from)
        print(f"| {a.scene} | `{spec}` | {m.mean():.4f} +- {m.std(ddof=1) if len(m) > 1 else 0:.4f} | "
              f"{r.mean():.4f} +- {r.std(ddof=1) if len(r) > 1 else 0:.4f} | {ms:.0f} |", flush=True)


if __name__ == "__main__":
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "src"))
    _main()
