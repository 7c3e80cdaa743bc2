"""Luminance: the one weighting of linear RGB used by estimators, records and reports.

``Y = 0.212671 R + 0.715160 G + 0.072169 B``: the relative luminance of linear sRGB / Rec. 709 primaries
(CIE Y row of the sRGB-to-XYZ matrix, IEC 61966-2-1), the weights of Mitsuba's ``mi.luminance``. One
function for Dr.Jit arrays (a ``Color3f``: Mitsuba's own) and NumPy arrays (RGB on the last axis), so
that a device estimate and its host report weigh colour alike.
"""
from __future__ import annotations

import numpy as np

from ..backend import mi

LUMINANCE = np.array([0.212671, 0.715160, 0.072169])
"""Rec. 709 luminance weights of linear R, G, B (Mitsuba's ``mi.luminance``)."""


def luminance(c):
    """Relative luminance of linear RGB ``c``: a Dr.Jit colour (per lane) or a NumPy array ``[..., 3]``."""
    if isinstance(c, np.ndarray):
        return np.asarray(c, np.float64)[..., :3] @ LUMINANCE
    return mi.luminance(mi.Color3f(c))
