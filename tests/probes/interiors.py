"""What the real-interior probe tests share: the technique list, the per-technique settings and the mean
image of a technique's settled frames (a static camera, t = 0)."""
from __future__ import annotations

import numpy as np
import pytest

from dyngi.techniques import Frame, create_technique
from dyngi.techniques.base import probe_technique_names

FAST = ("ddgi", "qddgi")
SETTINGS = {"probes-reference": {"texels": 16, "rays_per_texel": 32},
            "ddgi-secondary": {"emission_attenuation": "none"},
            "ddgi-resampling": {"emission_attenuation": "none"}}
"""``probes-reference`` at fewer texels and rays (its default costs minutes); the DDGI Resampling family
without Sec. 3.3's emission heuristic, a deliberate bias of the paper (tests/probes/test_probe_leaks.py)."""
PROBE_TECHNIQUES = [pytest.param(n, marks=() if n in FAST else pytest.mark.slow) for n in probe_technique_names()]


def settled_mean(name: str, scene, res, frames: int, settled: int, params: dict | None = None) -> np.ndarray:
    """Mean of frames ``settled .. frames-1`` of technique ``name`` (with :data:`SETTINGS`) at t = 0."""
    scene.at(0.0)
    tech = create_technique(name, scene, {**SETTINGS.get(name, {}), **(params or {})})
    cam = scene.camera(0.0)
    imgs = [tech.step(Frame(i, 0.0, cam, res, seed=3, static=i > 0)).image for i in range(frames)]
    img = np.mean(imgs[settled:], 0)
    assert np.all(np.isfinite(img))
    return img
