"""A debug view of a probe volume: the probes drawn as small spheres shaded by their stored irradiance.

Majercik et al. (JCGT 2019, Fig. 4) show probes this way; the layout and
colours here are our choice: each sphere point shows ``E(n)`` read with the
bilinear texel filter of the irradiance atlas in the direction of its normal
``n``; inactive probes are dark red; the scene behind is drawn in grey from its
diffuse albedo (:func:`dyngi.sampling.diffuse.diffuse_albedo`) and the view cosine.
"""
from __future__ import annotations

import numpy as np

from ..backend import dr, mi
from ..sampling.diffuse import diffuse_albedo
from ..sampling.octahedral import direction_to_texel_coords
from ..scene.geometry import diffuse, make_mesh, uv_sphere
from .query import bilinear_gather
from .volume import ProbeVolume


def render_probe_view(scene, volume: ProbeVolume, camera, res, radius: float = 0.15,
                      show_scene: bool = True) -> np.ndarray:
    """Render the probes as spheres shaded by their stored irradiance (``E/pi`` in the sphere normal's direction).

    ``radius`` is a fraction of the smallest probe spacing. Inactive probes are
    drawn dark red; with ``show_scene`` the scene is drawn in grey (albedo) behind.
    Returns an H x W x 3 float32 image.
    """
    w, h = res
    n = w * h
    r = float(radius) * volume.grid.min_spacing
    # one mesh of low-poly spheres, one per probe: prim_index // tris -> probe
    V0, F0 = uv_sphere((0.0, 0.0, 0.0), r, 6, 12)
    pos = volume.positions()
    P = len(pos)
    V = (V0[None] + pos[:, None]).reshape(-1, 3)
    F = (F0[None] + (np.arange(P) * len(V0))[:, None, None]).reshape(-1, 3)
    probes_scene = mi.load_dict({"type": "scene", "probes": make_mesh("probes", V, F, diffuse((1, 1, 1)))})
    idx = dr.arange(mi.UInt32, n)
    ray = camera.sample_rays(res, idx, mi.Point2f(0.5, 0.5))
    si_p = probes_scene.ray_intersect(ray)
    si_s = scene.mi_scene.ray_intersect(ray)
    probe = si_p.prim_index // len(F0)
    center = dr.gather(mi.Point3f, volume.device.positions, probe, si_p.is_valid())
    nrm = dr.normalize(si_p.p - center)
    coords = direction_to_texel_coords(nrm, volume.irradiance_texels)
    irr = bilinear_gather(volume.device.irradiance, probe, coords, volume.irradiance_texels, 3)
    live = dr.gather(mi.UInt32, volume.device.states, probe, si_p.is_valid()) != 0
    col = dr.select(live, irr, mi.Color3f(0.3, 0.0, 0.0))
    bg = mi.Color3f(0.0)
    if show_scene:
        bsdf = si_s.bsdf(ray)
        alb = diffuse_albedo(bsdf, si_s, si_s.is_valid())
        shade = dr.abs(dr.dot(si_s.sh_frame.n, ray.d))
        bg = dr.select(si_s.is_valid(), alb * (0.2 + 0.3 * shade), 0.0)
    use_probe = si_p.is_valid() & (~si_s.is_valid() | (si_p.t <= si_s.t))
    out = dr.select(use_probe, col, bg)
    return np.asarray(dr.ravel(out), np.float32).reshape(h, w, 3)
