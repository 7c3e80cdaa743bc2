"""ADGI's per-frame work follows the chains and the view, not the probe grid (Datta et al. 2022, Sec. 7: "our
adaptive sampling stages have a fixed upper bound on the compute requirement and also decouple sampling from
the number of probes"): the outer count cap applied lazily at merge, the static guide's mip read per chain
sample, the dynamic proxy table evaluated where the chains read it, the heuristics on V_out's bounding box. Tested by the lanes a steady frame's
probe update launches (``dr.kernel_history``) when the grid grows outside the view, and the per-sample reads
against the dense tables they replace."""
import dataclasses

import numpy as np
import pytest

from dyngi.backend import dr, mi
from dyngi.scene import load_scene
from dyngi.techniques import Frame, StageTimer, create_technique

RES = (32, 24)


def _update_lanes(sc, counts, k, frames=5):
    """(lanes of the last frame's probe update, its kernels, the technique) for ``adgi`` on ``sc``."""
    tech = create_technique("adgi", sc, {"probe_counts": ",".join(map(str, counts)), "camera_threshold": k,
                                         "warmup": 1, "warmup_rays": 16})
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        for i in range(frames):
            t = sc.frame_time(i)
            sc.at(t)
            f = Frame(i, t, sc.camera(t), RES, seed=3 + i)
            dr.kernel_history()         # clears
            tt = StageTimer()
            stats = tech.update_probes(f, tt)
            hist = [h for h in dr.kernel_history() if h["type"] == dr.KernelType.JIT]
            tech.finish_frame(tt, stats, *tech._primary(f, tt))
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    return sum(h["size"] for h in hist), hist, tech, stats


def test_steady_frame_lanes_do_not_grow_with_the_grid_outside_the_view(backend):
    """``cornell-moving-box`` (the box moves: P, S and D all run), 9^3 probes, then the probe box grown 2x per
    axis around it at equal spacing (17^3 = 4913 probes: the first grid's probes are among them), Eq. 10's k
    fixed (so f_c, V_in and V_out do not follow the grid), 1024 dynamic and 4096 static chains: the lanes the
    5th frame's probe update launches stay within 1.1x, and no kernel of it spans the grown grid's texels
    (>= 36 lanes per probe: the former outer count cap, the guide's mip, the proxy table were such passes), nor
    any over the grid's probe octants (8 lanes per probe: the heuristics now run on V_out's bounding box).
    Measured (2026-12-06): 3.12M lanes at 729 probes, 2.44M at 4913 (the static chains spread over the larger
    grid draw fewer samples in V_in); before the lazy cap, the per-sample reads and the heuristics' box 4.54M."""
    sc = load_scene("cornell-moving-box")
    lo, hi = (np.asarray(x, np.float64) for x in sc.meta.probe_box)
    k = 4.8                                   # about the default quantile rule's k for this view (fixed here)
    base, _, _, st0 = _update_lanes(sc, (9, 9, 9), k)
    ext = hi - lo
    sc.meta = dataclasses.replace(sc.meta, probe_box=(tuple(lo - ext / 2), tuple(hi + ext / 2)))
    grown, hist, tech, st1 = _update_lanes(sc, (17, 17, 17), k)
    P = tech.volume.n_probes
    print("lanes", base, grown, "v_in", st0["v_in"], st1["v_in"], "largest", sorted(h["size"] for h in hist)[-5:])
    assert abs(st1["v_in"] - st0["v_in"]) <= 0.1 * st0["v_in"]        # the same view (a precondition)
    assert grown <= 1.1 * base, (base, grown)
    assert max(h["size"] for h in hist) < 36 * P
    # nor over the grid's probe octants (the heuristics' triggers, convolution and 6-10-10 words: V_out's box)
    assert not [h["size"] for h in hist if h["size"] >= 8 * P and h["size"] % P == 0]


def test_per_sample_guide_and_proxy_reads_equal_the_dense_tables(backend):
    """The static guide's ``g`` read per sample (:meth:`ADGIChainPlanner.guide_at`) equals the dense mip
    (:meth:`guide_feedback`) at the sample's cell, at mips 0-2 on random irradiance; the dynamic proxy value
    (:meth:`proxy_value`) equals the max over each proxy's 3x3x3 probes in V_in of a random f_d, on a grid
    whose counts are not multiples of 3."""
    from dyngi.probes import ProbeGrid, ProbeVolume
    from dyngi.probes.arrays import upload
    from dyngi.sampling.metropolis import ADGI_DIRECTION_STEP
    from dyngi.techniques.adgi.heuristics import OCTANTS
    from dyngi.techniques.adgi.planner import ADGIChainPlanner
    rng = np.random.default_rng(2)
    vol = ProbeVolume(ProbeGrid((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), (5, 4, 7)), 8, 16)
    P = vol.n_probes
    vol.device.irradiance = mi.Color3f(*[upload(rng.uniform(0, 2, P * 64).astype(np.float32)) for _ in range(3)])
    for level in (0, 1, 2):
        pl = ADGIChainPlanner(vol, {"position_step": 0.5, "direction_step": ADGI_DIRECTION_STEP, "burn_in": 4,
                                    "iterations": 20, "dynamic_position_scale": 3.0, "dynamic_direction_scale": 6.0,
                                    "static_chains": 64, "dynamic_chains": 64, "guide_mip": level,
                                    "dynamic_rays": 0})
        n = 2000
        probe = mi.UInt32(rng.integers(0, P, n).astype(np.uint32))
        d = rng.normal(size=(n, 3)).astype(np.float32)
        w = mi.Vector3f(*[upload(np.ascontiguousarray(d[:, c])) for c in range(3)])
        w = dr.normalize(w)
        mm = pl._mip_n ** 2
        want = dr.gather(mi.Float, pl.guide_feedback(), probe * mm + pl._mip_cell_of(w))
        assert np.allclose(np.asarray(pl.guide_at(probe, w)), np.asarray(want), rtol=1e-5, atol=1e-6), level
    fd = rng.uniform(0, 1, P * OCTANTS).astype(np.float32)
    vin = (rng.random(P) < 0.6).astype(np.float32)
    px, py, pz = pl.proxies
    ent = np.arange(px * py * pz * OCTANTS)
    got = np.asarray(pl.proxy_value(mi.UInt32(ent.astype(np.uint32)), mi.Float(vin), mi.Float(fd)))
    nx, ny, nz = pl.counts
    want = np.zeros(len(ent))
    for e in ent:
        q, o = divmod(int(e), OCTANTS)
        qi, qj, qk = q % px, (q // px) % py, q // (px * py)
        for i in range(3 * qi, min(3 * qi + 3, nx)):
            for j in range(3 * qj, min(3 * qj + 3, ny)):
                for k in range(3 * qk, min(3 * qk + 3, nz)):
                    p = i + nx * (j + ny * k)
                    want[e] = max(want[e], fd[p * OCTANTS + o] * vin[p])
    assert np.allclose(got, want)
