"""Splitting Mitsuba's ``sunsky`` emitter into its sun and its sky.

Mitsuba 3's ``sunsky`` (Hosek-Wilkie sky + a sun disk of angular aperture
``sun_aperture``) is one infinite, non-delta emitter whose radiance is
``sun_scale * L_sun + sky_scale * L_sky``. Real-time GI treats the two very
differently: the sun is a small, very bright source that next-event
estimation samples well (DDGI's "analytic lights"), the sky a dim, wide one
that the probes' miss rays integrate well (Majercik et al. 2019, Sec. 3.1,
"sky"). :func:`split_sunsky` builds the two parts as standalone emitters
with the same sky model, sun position, frame and scales, one with
``sky_scale = 0`` (the sun) and one with ``sun_scale = 0`` (the sky); their
sum equals the original emitter in every direction (tested to float
round-off). The part emitters are given the scene (``set_scene``) so that
their direction samples carry a point ``ds.p`` outside the scene's bounding
sphere, as the scene's own infinite emitters do, and shadow rays to it work
unchanged.

The sun position is read from the emitter's ``sun_direction`` parameter (set
either directly or from date, time and location), the aperture and the
"complex sun" switch from the emitter's description (Mitsuba exposes them
nowhere else).
"""
from __future__ import annotations

import re

import numpy as np

from ..backend import mi
from ..errors import DyngiError


def is_sunsky(emitter) -> bool:
    """Is ``emitter`` (a Python emitter object) Mitsuba's ``sunsky``?"""
    return emitter is not None and emitter.class_name() == "SunskyEmitter"


def _scalar(v) -> float:
    return float(np.asarray(v, np.float64).ravel()[0])


def sunsky_properties(emitter) -> dict:
    """The ``mi.load_dict`` dictionary that rebuilds ``emitter`` (a ``sunsky``), scales included."""
    p = mi.traverse(emitter)
    text = str(emitter)
    ap = re.search(r"Sun aperture = ([0-9.eE+-]+)", text)
    cx = re.search(r"Complex sun model = (\w+)", text)
    if ap is None or cx is None:
        raise DyngiError("cannot read the sun aperture of this Mitsuba version's sunsky emitter")
    albedo = np.asarray(p["albedo.value"], np.float64).ravel()
    albedo = albedo[:3] if albedo.size >= 3 else np.repeat(albedo[:1], 3)
    matrix = np.asarray(p["to_world"].matrix, np.float64).reshape(4, 4)
    return {"type": "sunsky",
            "sun_direction": np.asarray(p["sun_direction"], np.float64).ravel().tolist(),
            "turbidity": _scalar(p["turbidity"]),
            "albedo": {"type": "rgb", "value": albedo.tolist()},
            "sun_scale": _scalar(p["sun_scale"]), "sky_scale": _scalar(p["sky_scale"]),
            "sun_aperture": float(ap.group(1)), "complex_sun": cx.group(1) == "true",
            "to_world": mi.ScalarTransform4f(matrix)}


def split_sunsky(emitter, mi_scene=None):
    """(sun, sky): standalone emitters of the sun part (``sky_scale = 0``) and the sky part
    (``sun_scale = 0``) of a ``sunsky`` emitter; ``None`` for a part whose scale is 0."""
    d = sunsky_properties(emitter)
    parts = []
    for keep, drop in (("sun_scale", "sky_scale"), ("sky_scale", "sun_scale")):
        if d[keep] <= 0.0:
            parts.append(None)
            continue
        e = mi.load_dict({**d, drop: 0.0})
        if mi_scene is not None:
            e.set_scene(mi_scene)
        parts.append(e)
    return tuple(parts)
