"""ADGI's cache encoding as Table 3 gives it: irradiance round-down, visibility round-to-nearest.

Table 3 (Datta et al. 2022) writes ADGI's caches as ``floor(R9) floor(G9) floor(B8) - N`` (irradiance,
round-to-lowest, Appendix B: so that a moving average of dark samples reaches zero) and
``[R13][G13] - N`` (visibility, Appendix B's ``[]`` = round-to-nearest). The shared
:class:`dyngi.probes.encoding.ADGIEncoding` floors both; :class:`ADGITable3Encoding` is the same
layout (R9G9B8 + 6-bit count, R13G13 + 6-bit count, Eq. 21 log non-linearity with (beta, gamma) =
(5, 15) and (8, 20), Sec. 4.5-4.6) with the visibility channels rounded to nearest. The technique
``adgi`` uses it for ``encoding='adgi'``, in its warm-up as well.

Round-to-nearest halves the worst quantisation error of the moments (``<= 1/2`` code instead of
``< 1`` code) and removes the low bias of the stored mean distance, which the Chebyshev test reads
as "occluded" (a floored mean distance below the true one darkens probes that see a point).
"""
from __future__ import annotations

import numpy as np

from ...probes.encoding import (COUNT_MAX, IRR_BETA, IRR_GAMMA, SQ_BETA, SQ_GAMMA, ADGIEncoding, _pack,
                                log_quantize)


class ADGITable3Encoding(ADGIEncoding):
    """:class:`~dyngi.probes.encoding.ADGIEncoding` with visibility rounded to nearest (Table 3).

    Device store/load pairs are inherited (they read ``VIS_FLOOR``): ``store_distance`` is inverted by
    ``load_distance``, ``store_irradiance`` by ``load_irradiance``; the NumPy ``encode_distance`` is
    inverted by ``decode_distance``.
    """

    name = "adgi"
    VIS_FLOOR = False

    def encode_distance(self, mom, count, diagonal):
        """NumPy: moments (..., 2) and counts -> words, round-to-nearest. Inverse: :meth:`decode_distance`."""
        mom = np.asarray(mom, np.float64)
        m1 = log_quantize(mom[..., 0] / diagonal, 13, IRR_BETA, IRR_GAMMA, False)
        m2 = log_quantize(mom[..., 1] / diagonal ** 2, 13, SQ_BETA, SQ_GAMMA, False)
        return _pack([m1, m2, np.minimum(count, COUNT_MAX)], self.VIS_BITS)


def adgi_encoding(name: str):
    """The encoding object ``adgi`` stores through: Table 3's for ``'adgi'``, the shared one otherwise."""
    from ...probes.encoding import get_encoding

    return ADGITable3Encoding() if name == "adgi" else get_encoding(name)
