"""Luminance: the one weighting of linear RGB used by estimators, records and reports.

``Y = 0.212671 R + 0.715160 G + 0.072169 B``: the relative luminance of linear sRGB / Rec. 709 primaries
(CIE Y row of the sRGB-to-XYZ matrix, IEC 61966-2-1), the weights of Mitsuba's ``mi.luminance``. One
function for Dr.Jit arrays (a ``Color3f``: Mitsuba's own, in the array's precision) and host arrays
(NumPy or anything array-like, RGB on the last axis, in float64), so that a device estimate and its
host report weigh colour alike. It sits in the bottom layer (with ``errors`` and ``backend``) so that
every layer above, from metrics and samplers to the viewer, calls this one function instead of writing
the weights again (issue 24 item 2, "one luminance"; ``tests/test_color.py`` checks that no other
module spells them out). Mitsuba is imported only for a Dr.Jit argument (our choice), so that
NumPy-only users (the metrics) stay free of the renderer.
"""
from __future__ import annotations

import sys

import numpy as np

LUMINANCE = np.array([0.212671, 0.715160, 0.072169])
"""Rec. 709 luminance weights of linear R, G, B (Mitsuba's ``mi.luminance``), float64."""


def luminance(c):
    """Relative luminance of linear RGB ``c``.

    A Dr.Jit array (a ``Color3f``, or anything ``mi.Color3f`` accepts) gives a Dr.Jit ``Float`` per lane
    (``mi.luminance``); anything else is read as a host array ``[..., 3]`` (extra trailing channels
    ignored) and gives a float64 NumPy array of its leading shape."""
    dr = sys.modules.get("drjit")                # not imported yet: ``c`` cannot be a Dr.Jit array
    if dr is not None and dr.is_array_v(c):
        from .backend import mi
        return mi.luminance(c if isinstance(c, mi.Color3f) else mi.Color3f(c))
    return np.asarray(c, np.float64)[..., :3] @ LUMINANCE
