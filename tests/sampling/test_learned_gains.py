"""The learned samplers must earn their keep (issue 28): tests that fail if the VLC or the CDQ degrade to the
strategy they replace.

* The VLC keeps a light that is visible from 5% of a leaf's samples once the leaf has the paper's sample
  count (4096 per frame, Sec. 7's split threshold), and keeps it less reliably at our old floor of 512
  (the reason the reproduction must match the paper's samples per leaf).
* ``lights=vlc`` lowers the per-pixel variance of ``nee-pt`` against ``lights=uniform`` on
  ``warehouse-rooms`` by at least :data:`VLC_FACTOR` (3 seeds, one-sided t-test on the log ratio).
* ``directions=cdq`` lowers the per-pixel variance against ``directions=bsdf`` in the sun-lit pit of
  ``sky-pit-sun-disc-2deg`` (sun out of NEE) by at least :data:`CDQ_FACTOR` (3 seeds, one-sided).

Variance: nee-pt is unbiased and the scenes are held still, so the per-pixel sample variance over
``K`` frames after a warm-up estimates the expected squared error of one frame (no reference needed).
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy import stats as sps

from dyngi.backend import mi

VLC_FACTOR = 3.0
"""lights=vlc must have at most 1/3 of lights=uniform's variance on warehouse-rooms (measured ~1/8-1/15 at 48x27)."""
CDQ_FACTOR = 2.0
"""directions=cdq must have at most 1/2 of directions=bsdf's variance over the pit (sky-pit-sun-disc-2deg)."""


def _arr(a, cls):
    a = np.asarray(a, np.float32)
    return cls(a[:, 0], a[:, 1], a[:, 2])


def _presence(samples_per_frame: int, frames: int = 30, seed: int = 0) -> float:
    """Fraction of frames (after the rare light first entered) in which the VLC of the sampled leaf holds it."""
    from dyngi.sampling.emitter_triangles import EmitterTriangles
    from dyngi.sampling.light_select import FrameCtx
    from dyngi.sampling.octree import AdaptiveOctree
    from dyngi.sampling.vlc import VLCSelector
    from sampling.test_vlc import many_lights_scene
    sc = many_lights_scene(3)                     # 18 ceiling lights in a closed 10 x 4 x 10 m room
    tris = EmitterTriangles(sc.mi_scene)
    lo, hi = (np.asarray(b, np.float64) for b in sc.meta.bounds)
    oc = AdaptiveOctree(lo, hi, split_threshold=1 << 30, collapse_threshold=0)    # 8 leaves, fixed
    sel = VLCSelector(tris, octree=oc)
    rare = 8                                      # a light of the middle row
    rng = np.random.default_rng(seed)
    n = samples_per_frame
    held, entered = [], False
    for f in range(frames):
        # floor points of the leaf [0, 5] x [0, 2] x [0, 5]; the rare light is visible from x < 0.25 (5%)
        p = np.c_[5.0 * rng.random(n), np.full(n, 0.01), 5.0 * rng.random(n)]
        P, N = _arr(p, mi.Point3f), mi.Vector3f(0.0, 1.0, 0.0)
        k, _ = sel.sample(P, N, mi.Float(rng.random(n).astype(np.float32)), True)
        kk = k.numpy()
        vis = (kk != rare) | (p[:, 0] < 0.25)
        sel.record(P, N, k, mi.Bool(vis), True)
        oc.place(P, True)
        sel.end_frame()
        oc.adapt()
        sel.begin_frame(FrameCtx(sc.mi_scene, tris, f + 1, 0.0, oc, (lo, hi)))
        leaf = int(oc.host_lookup(np.array([[2.5, 0.01, 2.5]]))[0])
        has = rare in set(sel.host_cache(leaf).tolist())
        entered |= has
        if entered:
            held.append(has)
    assert entered, "the rare light never entered the VLC"
    return float(np.mean(held))


def test_vlc_keeps_a_light_visible_from_5_percent_of_a_leafs_samples(backend):
    """With the paper's 4096 samples per leaf and frame the light stays in >= 90% of the frames after it first
    entered, averaged over 3 seeds; with 512 (the old floor) it is dropped clearly more often."""
    paper = np.mean([_presence(4096, seed=s) for s in range(3)])
    starved = np.mean([_presence(512, seed=s) for s in range(3)])
    assert paper >= 0.9, paper
    assert starved < paper - 0.1, (starved, paper)


def _pixel_variance(scene, spec: str, res, warmup: int, frames: int, seed: int, mask=None) -> float:
    from dyngi.techniques import Frame, create_technique
    tech = create_technique(spec + f":seed={seed}", scene)
    imgs = []
    for i in range(warmup + frames):
        scene.at(0.0)
        r = tech.step(Frame(i, 0.0, scene.camera(0.0), res, seed=1000 * seed + 7))
        if i >= warmup:
            imgs.append(np.asarray(r.image, np.float64) @ np.array([0.2126, 0.7152, 0.0722]))
    v = np.var(np.stack(imgs), axis=0, ddof=1)
    return float(v[mask].mean() if mask is not None else v.mean())


def _one_sided_below(ratios, factor: float, alpha: float = 0.05) -> tuple[bool, float]:
    """One-sided t-test on log ratios: is the mean log(ratio) below log(1/factor)? (reject = pass)."""
    lr = np.log(np.asarray(ratios, np.float64))
    t = (lr.mean() - np.log(1.0 / factor)) / (lr.std(ddof=1) / np.sqrt(len(lr)) + 1e-12)
    p = sps.t.cdf(t, df=len(lr) - 1)
    return bool(p < alpha), float(p)


@pytest.mark.slow
def test_vlc_lowers_variance_against_uniform(backend):
    from dyngi.scene import load_scene
    sc = load_scene("warehouse-rooms")
    ratios = []
    for seed in range(3):
        v_vlc = _pixel_variance(sc, "nee-pt:lights=vlc", (48, 27), 8, 12, seed)
        v_uni = _pixel_variance(sc, "nee-pt:lights=uniform", (48, 27), 8, 12, seed)
        ratios.append(v_vlc / v_uni)
    ok, p = _one_sided_below(ratios, VLC_FACTOR)
    assert ok, f"VLC/uniform variance ratios {ratios} not below 1/{VLC_FACTOR} (one-sided p = {p:.3g})"


@pytest.mark.slow
def test_cdq_lowers_variance_against_bsdf(backend):
    from dyngi.scene import load_scene
    sc = load_scene("sky-pit-sun-disc-2deg")
    res = (48, 27)
    ratios = []
    for seed in range(3):
        v_cdq = _pixel_variance(sc, "nee-pt:directions=cdq", res, 20, 16, seed)
        v_bsdf = _pixel_variance(sc, "nee-pt:directions=bsdf", res, 20, 16, seed)
        ratios.append(v_cdq / v_bsdf)
    ok, p = _one_sided_below(ratios, CDQ_FACTOR)
    assert ok, f"CDQ/BSDF variance ratios {ratios} not below 1/{CDQ_FACTOR} (one-sided p = {p:.3g})"
