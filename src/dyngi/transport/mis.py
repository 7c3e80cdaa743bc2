"""Multiple importance sampling weights (Veach 1997, Ch. 9, Eq. 9.13 balance and 9.14 power heuristic).

One module for every estimator that combines two sampling strategies (BSDF sampling against light
sampling in the path walk; the ReSTIR reservoirs' own MIS lives with them in
:mod:`dyngi.sampling.reservoir`)."""
from __future__ import annotations

from ..backend import dr


def mis_weight(pdf_a, pdf_b, power: bool = True):
    """MIS weight of strategy a against b, one sample each: the power heuristic with beta = 2
    ``pdf_a^2 / (pdf_a^2 + pdf_b^2)`` (Eq. 9.14), or the balance heuristic ``pdf_a / (pdf_a + pdf_b)``
    (Eq. 9.13). Non-finite weights (both pdfs 0) are 0; the weight is detached (no gradient)."""
    if power:
        a2, b2 = pdf_a * pdf_a, pdf_b * pdf_b
        w = a2 / (a2 + b2)
    else:
        w = pdf_a / (pdf_a + pdf_b)
    return dr.detach(dr.select(dr.isfinite(w), w, 0.0))
