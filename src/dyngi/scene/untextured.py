"""Untextured scenes with average albedos (Hedman et al. 2017, Sec. 5: "In all experiments, we use an
untextured version of the scene for the VPL generation and use average material colors as albedos. The
path traced reference images use the same approximation.").

:func:`make_untextured` replaces, in place, every bitmap texture of the scene (each
``*.data`` tensor that Mitsuba's ``traverse`` exposes for a ``bitmap``) by its average
colour over the texels, so the techniques and the reference then see the same
constant-albedo materials. Our choice: the plain texel mean (the texture's mean over
its uv area, not over the surface area it covers). Built-in scenes have no textures:
for them the mode changes nothing. Returns the number of textures replaced. The scene's
content hash is recomputed, so cached references of the textured scene are not reused.
"""
from __future__ import annotations

import numpy as np

from ..backend import dr, mi


def make_untextured(scene) -> int:
    """Replace every bitmap texture of ``scene`` (a dyngi Scene or an ``mi.Scene``) by its mean colour."""
    mscene = scene.mi_scene if hasattr(scene, "mi_scene") else scene
    params = mi.traverse(mscene)
    n = 0
    for k in list(params.keys()):
        if not k.endswith(".data"):
            continue
        v = params[k]
        if not isinstance(v, mi.TensorXf) or len(v.shape) != 3:
            continue
        a = np.asarray(v, np.float32)
        mean = a.reshape(-1, a.shape[-1]).mean(axis=0)
        params[k] = mi.TensorXf(np.ascontiguousarray(np.broadcast_to(mean, a.shape), np.float32))
        n += 1
    if n:
        params.update()
        if hasattr(scene, "_base_hash"):
            scene._base_hash = None         # the content changed: cached references must not match
        if hasattr(scene, "params"):
            scene.params = mi.traverse(mscene)
            for an in getattr(scene, "animators", []):
                an.bind(scene.params)
        dr.eval()
    return n
