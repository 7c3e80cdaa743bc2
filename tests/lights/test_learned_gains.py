"""The learned samplers must earn their keep: tests that fail if the VLC or the CDQ degrade to the
strategy they replace.

* The VLC keeps a light that is visible from 5% of a leaf's samples once the leaf has the paper's sample
  count (4096 per frame, Sec. 7's split threshold), and keeps it less reliably at our old floor of 512
  (the reason the reproduction must match the paper's samples per leaf).
* ``lights=vlc`` lowers the MSE of ``nee-pt`` against the paper's baselines, the PVS light lists
  (``lights=sll``) and the light tree (``lights=lighttree``), on ``storage-cells`` (the scene where light
  selection limits the error: 512 triangle lights in every PVS list, about 3 visible from a point) by at
  least :data:`VLC_FACTOR` (5 seeds, one-sided t-test on the log ratio).
* ``directions=cdq`` lowers the MSE against ``directions=bsdf`` in a closed room lit by the sky through one
  small skylight (the environment is out of NEE) by at least :data:`CDQ_FACTOR` (3 seeds, one-sided).

MSE: the mean over frames after a warm-up of each frame's MSE against Mitsuba's path (depth 3), the scene
held at t = 0. Not the per-pixel variance over frames: a BSDF run that never hits the small sun in a few
frames has a small sample variance but a large error (measured: one seed's variance ratio CDQ/BSDF was 1e5).
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy import stats as sps

from dyngi.backend import mi

VLC_FACTOR = {"sll": 1.5, "lighttree": 1.25}
"""lights=vlc must have at most 1/1.5 of lights=sll's and 1/1.25 of lights=lighttree's MSE on storage-cells at 64x36
(5 seeds: the VLC's per-seed spread, 0.29-0.50 against SLL over 3 seeds, leaves 3 seeds no power at these factors),
frames 2-11 (reduced scale: 4608 records per frame, octree thresholds scaled down to 576 / 288; the claim's is
320x180 at the paper's 4096 / 2048). Measured there (3 seeds, 16384-spp reference): VLC 0.00226 / 0.00138 /
0.00229, SLL 0.00452 / 0.00477 / 0.00456, LH 0.00372 / 0.00381 / 0.00374 (VLC/SLL 0.29-0.50, VLC/LH 0.36-0.61);
the oracle lists 0.00125-0.00173."""
STORAGE_REF_SPP = 16384
"""Reference spp on storage-cells: Mitsuba's path samples its 512 triangle lights by power, about 1 in 100 of its
NEE samples is unoccluded (its reference noise must stay far below the VLC's 1-spp MSE)."""
CDQ_FACTOR = 2.0
"""directions=cdq must have at most 1/2 of directions=bsdf's MSE in :func:`skylight_room` at 96x72 (measured 0.40,
0.38, 0.37 over 3 seeds; 0.57 at 64x48 and ~1.0 at 32x24: coarse octree leaves blur the guide). Not on the
sky pit: at test sizes its 1-spp MSE is all tail (a BSDF run that never hits the 2-degree sun in 10 frames scores
0.1, a CDQ run that hits it once 437; measured ratios 528, 0.08, 2847 over 3 seeds)."""


def _arr(a, cls):
    a = np.asarray(a, np.float32)
    return cls(a[:, 0], a[:, 1], a[:, 2])


def _presence(samples_per_frame: int, frames: int = 30, seed: int = 0) -> float:
    """Fraction of frames (after the rare light first entered) in which the VLC of the sampled leaf holds it."""
    from dyngi.lights.emitter_table import EmitterTable
    from dyngi.lights.base import FrameCtx
    from dyngi.directions.octree import AdaptiveOctree
    from dyngi.lights.vlc import VLCSelector
    from tests.lights.test_vlc import many_lights_scene
    sc = many_lights_scene(3)                     # 18 ceiling lights in a closed 10 x 4 x 10 m room
    tris = EmitterTable(sc.mi_scene)
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


def _frame_mse(scene, spec: str, res, warmup: int, frames: int, seed: int, ref_spp: int = 256, mask=None) -> float:
    """Mean over ``frames`` frames (after ``warmup``) of the MSE against Mitsuba's path (depth 3, ``ref_spp``
    spp), the scene held at t = 0: the expected squared error of one frame (rare missed hits included);
    ``mask``: over those pixels only."""
    from dyngi.experiments.references.path import reference_image
    from dyngi.techniques import Frame, create_technique
    ref = reference_image(scene, 0.0, res, ref_spp, 3).astype(np.float64)
    tech = create_technique(spec + f":seed={seed}", scene)
    mse = []
    for i in range(warmup + frames):
        scene.at(0.0)
        r = tech.step(Frame(i, 0.0, scene.camera(0.0), res, seed=1000 * seed + 7))
        if i >= warmup:
            e = ((np.asarray(r.image, np.float64) - ref) ** 2).mean(-1)
            mse.append(float(e.mean() if mask is None else e[mask].mean()))
    return float(np.mean(mse))


def _mse_ratios(scene, spec: str, baseline: str, res, warmup: int, frames: int, seeds=range(3), **kw) -> list:
    """Per seed, ``spec``'s mean frame MSE over ``baseline``'s (:func:`_frame_mse`, same frames and seed)."""
    return [_frame_mse(scene, spec, res, warmup, frames, s, **kw) / _frame_mse(scene, baseline, res, warmup, frames,
                                                                                s, **kw)
            for s in seeds]


def _one_sided_below(ratios, factor: float, alpha: float = 0.05) -> tuple[bool, float]:
    """One-sided t-test on log ratios: is the mean log(ratio) below log(1/factor)? (reject = pass)."""
    lr = np.log(np.asarray(ratios, np.float64))
    t = (lr.mean() - np.log(1.0 / factor)) / (lr.std(ddof=1) / np.sqrt(len(lr)) + 1e-12)
    p = sps.t.cdf(t, df=len(lr) - 1)
    return bool(p < alpha), float(p)


@pytest.mark.slow
@pytest.mark.parametrize("baseline", ("sll", "lighttree"))
def test_vlc_lowers_variance_against_sll_and_lh_where_selection_limits_the_error(backend, baseline):
    from dyngi.scene import load_scene
    sc = load_scene("storage-cells")
    ratios = _mse_ratios(sc, "nee-pt:lights=vlc", f"nee-pt:lights={baseline}", (64, 36), 2, 10, seeds=range(5),
                         ref_spp=STORAGE_REF_SPP)
    ok, p = _one_sided_below(ratios, VLC_FACTOR[baseline])
    assert ok, f"VLC/{baseline} MSE ratios {ratios} not below 1/{VLC_FACTOR[baseline]} (one-sided p = {p:.3g})"


def skylight_room():
    """A closed 6 x 3 x 6 m room under a bright constant sky (not NEE'd: nee-pt's NEE ignores the environment)
    whose only opening is a 1 x 1 m skylight: every surface is lit through a small solid angle that BSDF
    sampling rarely finds and a guide learns (a moderate-tail stand-in for the sun-lit pit)."""
    from dyngi.scene.builder import SceneBuilder
    from dyngi.scene.camera import Camera
    from dyngi.scene.geometry import box, diffuse, merge

    b = SceneBuilder("cdq-test-skylight")
    W, H, t = 6.0, 3.0, 0.2
    shell = [box((-t, -t, -t), (W + t, 0, W + t)), box((-t, 0, -t), (0, H, W + t)), box((W, 0, -t), (W + t, H, W + t)),
             box((0, 0, -t), (W, H, 0)), box((0, 0, W), (W, H, W + t)),
             # the roof with a 1 x 1 m hole over (2.5..3.5, 2.5..3.5)
             box((-t, H, -t), (2.5, H + t, W + t)), box((3.5, H, -t), (W + t, H + t, W + t)),
             box((2.5, H, -t), (3.5, H + t, 2.5)), box((2.5, H, 3.5), (3.5, H + t, W + t))]
    b.mesh("shell", merge(shell), diffuse((0.6, 0.6, 0.6)))
    b.mesh("block", box((0.8, 0.0, 0.8), (2.0, 1.2, 2.0)), diffuse((0.5, 0.45, 0.4)))
    b.add("sky", {"type": "constant", "radiance": {"type": "rgb", "value": [4.0, 4.0, 4.0]}})
    return b.build(Camera((0.5, 1.6, 5.5), (3.5, 0.4, 2.0), (0, 1, 0), 80.0), "skylight room", duration=1.0)


@pytest.mark.slow
def test_cdq_lowers_variance_against_bsdf(backend):
    sc = skylight_room()
    # ~83k recording vertices per frame: above 8 x 4096, so the octree runs at the paper's thresholds (4096 /
    # 2048 records per leaf; nee-pt's leaf_scaling) with nee-pt's evidence rule (cdq_min_records). At 96x72
    # (~20k records, thresholds scaled to records / 8) the same defaults measured ratios 0.73-0.83 (seeds 0-2),
    # 0.48-0.54 with cdq_min_records=0; at this size 0.42-0.43 (2026-12-06)
    res = (192, 144)
    ratios = _mse_ratios(sc, "nee-pt:directions=cdq", "nee-pt:directions=bsdf", res, 20, 10)
    ok, p = _one_sided_below(ratios, CDQ_FACTOR)
    assert ok, f"CDQ/BSDF MSE ratios {ratios} not below 1/{CDQ_FACTOR} (one-sided p = {p:.3g})"
