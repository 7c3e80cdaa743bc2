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
from ..rays import intersect
from ..sampling.diffuse import diffuse_albedo
from ..sampling.octahedral import direction_to_texel_coords
from ..scene.geometry import diffuse, make_mesh, uv_sphere
from .query import bilinear_gather
from .volume import ProbeVolume


def probe_spheres(volume: ProbeVolume, radius: float = 0.15):
    """(Mitsuba scene of one low-poly sphere per probe, triangles per sphere); ``prim_index // tris`` is the
    probe. Kept on the volume and rebuilt only when the probe positions (relocation) or the radius change:
    building the mesh's BVH costs far more than the render (docs/techniques/ddgi.md)."""
    r = float(radius) * volume.grid.min_spacing
    pos = volume.positions()
    key = (r, hash(np.ascontiguousarray(pos, np.float64).tobytes()))
    cached = getattr(volume, "_debug_spheres", None)
    if cached is not None and cached[0] == key:
        return cached[1], cached[2]
    V0, F0 = uv_sphere((0.0, 0.0, 0.0), r, 6, 12)
    P = len(pos)
    V = (V0[None] + pos[:, None]).reshape(-1, 3)
    F = (F0[None] + (np.arange(P) * len(V0))[:, None, None]).reshape(-1, 3)
    probes_scene = mi.load_dict({"type": "scene", "probes": make_mesh("probes", V, F, diffuse((1, 1, 1)))})
    volume._debug_spheres = (key, probes_scene, len(F0))
    return probes_scene, len(F0)


def render_probe_view(scene, volume: ProbeVolume, camera, res, radius: float = 0.15,
                      show_scene: bool = True, return_mask: bool = False):
    """Render the probes as spheres shaded by their stored irradiance (``E/pi`` in the sphere normal's direction).

    ``radius`` is a fraction of the smallest probe spacing. Inactive probes are
    drawn dark red; with ``show_scene`` the scene is drawn in grey (albedo) behind.
    Returns an H x W x 3 float32 image, or (image, H x W bool mask of the probe pixels) with
    ``return_mask`` (the viewer draws the spheres over a technique's frame).
    """
    w, h = res
    n = w * h
    # one mesh of low-poly spheres, one per probe: prim_index // tris -> probe
    probes_scene, tris = probe_spheres(volume, radius)
    idx = dr.arange(mi.UInt32, n)
    ray = camera.sample_rays(res, idx, mi.Point2f(0.5, 0.5))
    si_p = intersect(probes_scene, ray, stage="probe view")
    si_s = intersect(scene.mi_scene, ray, stage="probe view")
    probe = si_p.prim_index // tris
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
    img = np.asarray(dr.ravel(out), np.float32).reshape(h, w, 3)
    if return_mask:
        return img, np.asarray(use_probe, bool).reshape(h, w)
    return img
