"""Overlays the viewer draws over a technique's frame, where the technique has the data.

* ``probes`` (any technique holding a :class:`~dyngi.probes.volume.ProbeVolume`: ddgi, qddgi,
  probes-reference, adgi, isddgi, ...): the probes as spheres shaded by their stored irradiance,
  drawn with :func:`dyngi.probes.debug.render_probe_view` (the code of ``dyngi probe-view``) and
  composited over the frame with its probe mask; inactive probes are dark red.
* ``vpls`` (``ir``, ``mir``, ``tcas``, ``smcir``): the VPLs of the frame that the camera sees
  (:func:`dyngi.vpl.points.camera_sees`), as 3x3 dots coloured by their flux's chromaticity.
* ``octree`` (``nee-pt`` with an adaptive octree: ``lights=vlc`` or ``directions=cdq``): each pixel's
  primary hit tinted by the octree leaf holding it (a hashed colour) with the leaf borders darkened.
* ``guide`` (``adgi``): where the guide's Metropolis chains stand (the positions of ADGI's static
  chains, which concentrate where the guide's density is high), as cyan dots where the camera sees them.

All overlays work on the tonemapped 8-bit frame (``draw``); each costs one extra camera-ray pass at
most (probe view: ~35 ms at 320x180 once the sphere mesh is built, rebuilt only when probes move).
"""
from __future__ import annotations

import numpy as np

from ..backend import dr, mi
from ..color import luminance
from ..experiments.io import tonemap_srgb
from ..probes.debug import render_probe_view
from ..probes.volume import ProbeVolume
from ..rays import intersect
from ..techniques.vpl_base import VPLTechnique
from ..vpl.points import camera_sees

OVERLAYS = ("none", "probes", "vpls", "octree", "guide")


def probe_volume_of(tech):
    """The technique's probe volume (an attribute, or one level down), or None."""
    v = getattr(tech, "volume", None)
    if isinstance(v, ProbeVolume):
        return v
    for val in list(vars(tech).values()):
        if isinstance(val, ProbeVolume):
            return val
    for val in list(vars(tech).values()):
        if hasattr(val, "__dict__") and not isinstance(val, type):
            for v2 in list(vars(val).values()):
                if isinstance(v2, ProbeVolume):
                    return v2
    return None


def octree_of(tech):
    oc = getattr(tech, "octree", None)
    return oc if oc is not None and hasattr(oc, "host_lookup") else None


def capture_vpls(tech) -> bool:
    """Wrap a VPL technique's ``update_vpls`` so the viewer sees each frame's VPLs (``tech._viewer_vpls``).

    Returns whether the technique is a VPL technique. The wrapper only records the returned arrays."""
    if not isinstance(tech, VPLTechnique):
        return False
    orig = tech.update_vpls

    def update_vpls(frame, timer):
        out = orig(frame, timer)
        tech._viewer_vpls = (np.asarray(out[0]), np.asarray(out[1]), np.asarray(out[2]))
        return out

    tech.update_vpls = update_vpls
    tech._viewer_has_vpls = True
    return True


def guide_chains_of(tech):
    """The positions of a technique's guide chains (ADGI's static Metropolis chains), or None."""
    st = getattr(tech, "static_state", None)
    return getattr(st, "position", None) if st is not None else None


def available(tech) -> list[str]:
    """Overlay names this technique supports (always starting with 'none')."""
    out = ["none"]
    if tech is None:
        return out
    if probe_volume_of(tech) is not None:
        out.append("probes")
    if getattr(tech, "_viewer_has_vpls", False):
        out.append("vpls")
    if octree_of(tech) is not None:
        out.append("octree")
    if guide_chains_of(tech) is not None:
        out.append("guide")
    return out


def draw(name: str, tech, scene, camera, res, frame_u8: np.ndarray, exposure: float = 1.0) -> np.ndarray:
    """``frame_u8`` (H x W x 3 sRGB) with overlay ``name`` drawn on it (a new array)."""
    if name == "probes":
        return _draw_probes(tech, scene, camera, res, frame_u8, exposure)
    if name == "vpls":
        return _draw_vpls(tech, scene, camera, res, frame_u8)
    if name == "octree":
        return _draw_octree(tech, scene, camera, res, frame_u8)
    if name == "guide":
        return _draw_guide(tech, scene, camera, res, frame_u8)
    return frame_u8


def _draw_probes(tech, scene, camera, res, frame_u8, exposure):
    vol = probe_volume_of(tech)
    if vol is None:
        return frame_u8
    img, mask = render_probe_view(scene, vol, camera, res, show_scene=False, return_mask=True)
    out = frame_u8.copy()
    out[mask] = tonemap_srgb(img, exposure)[mask]
    return out


def project(camera, res, pts: np.ndarray):
    """Pixel coordinates (x, y) and depth of world points (:meth:`Camera.project <dyngi.scene.camera.Camera.project>`)."""
    x, y, z = camera.project(res, pts)
    w, h = res
    with np.errstate(invalid="ignore"):
        return 0.5 * (1.0 - x) * w, 0.5 * (1.0 - y) * h, z


def _draw_vpls(tech, scene, camera, res, frame_u8):
    data = getattr(tech, "_viewer_vpls", None)
    if data is None:
        return frame_u8
    pos, nrm, flux = data
    pos, nrm, flux = pos.reshape(-1, 3), nrm.reshape(-1, 3), flux.reshape(-1, 3)
    lum = luminance(flux)
    keep = np.isfinite(lum) & (lum > 0) & np.all(np.isfinite(pos), axis=1)
    pos, nrm, flux = pos[keep], nrm[keep], flux[keep]
    out = frame_u8.copy()
    if not len(pos):
        return out
    seen, _ = camera_sees(scene, camera, res, np.ascontiguousarray(pos, np.float32),
                          np.ascontiguousarray(nrm, np.float32))
    px, py, _ = project(camera, res, pos[seen])
    col = flux[seen] / np.maximum(flux[seen].max(axis=1, keepdims=True), 1e-12)
    col = (80 + 175 * np.clip(col, 0, 1)).astype(np.uint8)
    return _dots(out, px, py, col)


def _draw_guide(tech, scene, camera, res, frame_u8):
    p = guide_chains_of(tech)
    if p is None:
        return frame_u8
    pos = np.asarray(p, np.float32)
    if pos.ndim == 2 and pos.shape[0] == 3 and pos.shape[1] != 3:
        pos = pos.T
    pos = pos.reshape(-1, 3)
    pos = pos[np.all(np.isfinite(pos), axis=1)]
    out = frame_u8.copy()
    if not len(pos):
        return out
    seen, _ = camera_sees(scene, camera, res, np.ascontiguousarray(pos, np.float32), None)
    px, py, _ = project(camera, res, pos[seen])
    col = np.broadcast_to(np.array([0, 230, 255], np.uint8), (len(px), 3))
    return _dots(out, px, py, col)


def _dots(out, px, py, col):
    """3x3 dots with a black ring at pixel positions (px, py) on ``out`` (in place; returned)."""
    h, w = out.shape[:2]
    xi, yi = np.floor(px).astype(int), np.floor(py).astype(int)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            x, y = xi + dx, yi + dy
            ok = (x >= 0) & (x < w) & (y >= 0) & (y < h)
            out[y[ok], x[ok]] = 0 if (dx or dy) else col[ok]
    # centre pixels last so a neighbour's black border never hides a VPL
    ok = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
    out[yi[ok], xi[ok]] = col[ok]
    return out


def _hash_colours(ids: np.ndarray) -> np.ndarray:
    x = (ids.astype(np.uint64) * np.uint64(2654435761)) & np.uint64(0xFFFFFF)
    rgb = np.stack([(x >> np.uint64(16)) & np.uint64(255), (x >> np.uint64(8)) & np.uint64(255),
                    x & np.uint64(255)], axis=-1).astype(np.float32)
    return 64 + rgb * (191 / 255)


def _draw_octree(tech, scene, camera, res, frame_u8):
    oc = octree_of(tech)
    if oc is None:
        return frame_u8
    w, h = res
    idx = dr.arange(mi.UInt32, w * h)
    ray = camera.sample_rays(res, idx, mi.Point2f(0.5, 0.5))
    si = intersect(scene.mi_scene, ray, stage="overlay")
    valid = np.asarray(si.is_valid(), bool)
    p = np.asarray(si.p, np.float32)
    if p.shape == (3, w * h):
        p = p.T
    leaf = np.full(w * h, -1, np.int64)
    if valid.any():
        leaf[valid] = oc.host_lookup(p[valid])
    leaf = leaf.reshape(h, w)
    out = frame_u8.astype(np.float32)
    tint = _hash_colours(np.maximum(leaf, 0))
    has = leaf >= 0
    out[has] = 0.55 * out[has] + 0.45 * tint[has]
    edge = np.zeros((h, w), bool)
    edge[:, 1:] |= leaf[:, 1:] != leaf[:, :-1]
    edge[1:, :] |= leaf[1:, :] != leaf[:-1, :]
    out[edge & has] *= 0.3
    return np.clip(out, 0, 255).astype(np.uint8)
