"""Flicker of the paper's IR baseline against SMC-IR on a static-light sequence (Hedman et al. 2017,
Table 1 and Sec. 5.1): ``ir`` draws a new photon set every frame ("no special consideration
for temporal coherence"), so its |E'| (Eq. 10) exceeds ``smcir``'s, whose VPLs persist (at most
M_max = 16 move per frame); ``ir:photons=fixed`` (one photon set for the sequence) is a different,
temporally coherent baseline and flickers less than the per-frame one."""
from __future__ import annotations

import numpy as np
import pytest

from dyngi.metrics.temporal import temporal_errors
from dyngi.scene import load_scene
from dyngi.techniques import Frame, create_technique

RES, FRAMES, SEEDS = (32, 18), 6, (0, 1, 2)


def _indirect(spec, params, sc, seed, times):
    tech = create_technique(spec, sc, params)
    out = []
    for i, t in enumerate(times):
        sc.at(t)
        out.append(tech.step(Frame(i, t, sc.camera(t), RES, seed=seed)).indirect)
    return out


def test_ir_photon_modes_and_bad_value(backend):
    from dyngi.errors import DyngiError

    sc = load_scene("cornell-static")
    a = _indirect("ir", {"vpls": 64}, sc, 0, [0.0, 0.0])
    b = _indirect("ir", {"vpls": 64, "photons": "fixed"}, sc, 0, [0.0, 0.0])
    assert not np.array_equal(a[0], a[1])          # per-frame (default): a new photon set
    assert np.array_equal(b[0], b[1])              # fixed: the same set every frame
    with pytest.raises(DyngiError, match="photons"):
        create_technique("ir", sc, {"photons": "sometimes"})


@pytest.mark.slow
def test_per_frame_ir_flickers_more_than_smcir_on_static_lights(backend):
    """maze (13 static lights, walking camera), indirect only, 512 VPLs, 6 frames at 32x18, 3 seeds.
    One-sided, every seed: |E'|(ir) > |E'|(smcir), and |E'|(ir) > |E'|(ir:photons=fixed). The reference
    (path, 3 bounces, 256 spp) is shared by all, so its own noise adds the same floor to each."""
    sc = load_scene("maze")
    times = [sc.frame_time(i) for i in range(FRAMES)]
    ref = _indirect("path", {"spp": 256, "max_depth": 5}, sc, 99, times)
    got = {}
    for seed in SEEDS:
        for label, spec, params in (("ir", "ir", {}), ("fixed", "ir", {"photons": "fixed"}),
                                    ("smcir", "smcir", {"warmup": 20})):
            imgs = _indirect(spec, params, sc, seed, times)
            got[(label, seed)] = temporal_errors(imgs, ref, exposure="auto")["E_prime"]
    for seed in SEEDS:
        assert got[("ir", seed)] > got[("smcir", seed)], got
        assert got[("ir", seed)] > got[("fixed", seed)], got
