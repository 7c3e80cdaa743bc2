"""Weighted reservoirs as Dr.Jit structure-of-arrays state (issue 14, item 2).

A :class:`Reservoir` holds, per lane, one selected sample (any tuple of Dr.Jit
arrays: ReSTIR DI stores ``(emitter index, payload)``,
:mod:`dyngi.lights.candidates`), the weight sum ``w_sum``, the candidate count
``M``, the target value of the sample at its own domain ``p_hat`` and the
unbiased contribution weight ``W`` (an estimate of ``1 / p(y)``), plus ``src``,
the domain index the sample came from (for MIS).

* :func:`update` -- streaming weighted reservoir sampling (Chao 1982; Bitterli
  et al. 2020, Alg. 2): keep the new candidate with probability ``w / w_sum``.
* :func:`merge` -- combine a reservoir from another domain (pixel, frame) as
  one candidate of weight ``p_hat_here(y) * W * M`` that counts ``M``
  candidates (Alg. 4/5).
* :func:`finalize` -- the contribution weight ``W = w_sum / p_hat(y) * m``
  for the selected sample, with ``m`` chosen by ``combine``:

  ``'biased'``  ``m = 1 / sum_i M_i`` (Alg. 5): cheap, **biased** wherever a
                contributing domain cannot produce ``y`` (its ``p_hat_i(y) = 0``:
                ``y`` below a neighbour's surface, behind it, at an occluder
                boundary): those ``M_i`` dilute the estimate and the result is
                *darker* there (geometric edges, normal discontinuities, and
                disocclusions when temporal reuse is on) -- measured in
                ``tests/techniques/test_restir.py``;
  ``'1/z'``     ``m = 1 / Z``, ``Z = sum_i M_i [p_hat_i(y) > 0]`` (Alg. 6):
                unbiased;
  ``'mis'``     ``m = p_hat_c(y) / sum_i M_i p_hat_i(y)`` with ``c`` the domain
                ``y`` was taken from (Sec. 4.3, the balance heuristic over
                domains weighted by their ``M``): unbiased, lower variance than 1/Z.

Both unbiased forms need ``p_hat_i(y)`` of the *final* sample only, at every
contributing domain: one target evaluation per domain, no extra ray (our
targets carry no visibility, so the supports are exact without shadow rays).
"""
from __future__ import annotations

from dataclasses import dataclass

from ..backend import dr, mi
from ..errors import unknown_choice

COMBINE_MODES = ("mis", "1/z", "biased")


@dataclass
class Reservoir:
    sample: tuple
    w_sum: "mi.Float"
    M: "mi.Float"
    p_hat: "mi.Float"
    W: "mi.Float"
    src: "mi.UInt32"

    @staticmethod
    def empty(sample_template: tuple, n: int) -> "Reservoir":
        return Reservoir(tuple(dr.zeros(type(a), n) for a in sample_template), dr.zeros(mi.Float, n),
                         dr.zeros(mi.Float, n), dr.zeros(mi.Float, n), dr.zeros(mi.Float, n),
                         dr.zeros(mi.UInt32, n))

    def arrays(self):
        return (*self.sample, self.w_sum, self.M, self.p_hat, self.W, self.src)

    def gather(self, index, active=True) -> "Reservoir":
        """The reservoirs at lanes ``index`` (zero where not ``active``)."""
        active = mi.Bool(active)
        g = lambda a: dr.gather(type(a), a, index, active)   # noqa: E731
        return Reservoir(tuple(g(a) for a in self.sample), g(self.w_sum), g(self.M), g(self.p_hat), g(self.W),
                         g(self.src))

    def copy(self) -> "Reservoir":
        return Reservoir(tuple(type(a)(a) for a in self.sample), mi.Float(self.w_sum), mi.Float(self.M),
                         mi.Float(self.p_hat), mi.Float(self.W), mi.UInt32(self.src))


def _take(r: Reservoir, mask, sample, p_hat, src):
    r.sample = tuple(dr.select(mask, s, a) for s, a in zip(sample, r.sample))
    r.p_hat = dr.select(mask, p_hat, r.p_hat)
    r.src = dr.select(mask, src, r.src)


def update(r: Reservoir, sample: tuple, w, p_hat, u, active=True, src=0, count=1.0) -> "mi.Bool":
    """Stream one candidate of resampling weight ``w`` (>= 0) into ``r``; returns where it was taken.

    ``u`` is a uniform number per lane; ``count`` is how many candidates it stands for (1, or a merged M)."""
    active = mi.Bool(active)
    w = dr.select(active & (w > 0.0) & dr.isfinite(w), w, 0.0)
    r.w_sum = r.w_sum + w
    r.M = dr.select(active, r.M + count, r.M)
    take = active & (w > 0.0) & (u * r.w_sum < w)
    _take(r, take, sample, p_hat, mi.UInt32(src))
    return take


def merge(r: Reservoir, other: Reservoir, p_hat_here, u, active=True, src=1, m_cap=None) -> "mi.Bool":
    """Merge ``other`` into ``r``; ``p_hat_here`` is ``other``'s sample under ``r``'s target.

    ``m_cap`` clamps ``other.M`` first (temporal reuse: Bitterli et al. 2020, Sec. 6, "20x")."""
    M = other.M if m_cap is None else dr.minimum(other.M, m_cap)
    w = p_hat_here * other.W * M
    return update(r, other.sample, w, p_hat_here, u, active, src, M)


def finalize_single(r: Reservoir) -> None:
    """``W = w_sum / (M p_hat(y))`` for a reservoir of i.i.d. candidates from one domain (RIS)."""
    ok = (r.p_hat > 0.0) & (r.M > 0.0)
    r.W = dr.select(ok, r.w_sum / dr.maximum(r.M * r.p_hat, 1e-30), 0.0)


def finalize(r: Reservoir, combine: str, counts, p_hats, masks=None) -> None:
    """Set ``r.W`` after merges from several domains (see module docstring for ``combine``).

    ``counts[i]``: the (capped) M of domain i as merged (domain 0 = the reservoir's own), ``p_hats[i]``:
    the final sample's target value at domain i, ``masks[i]``: whether domain i took part."""
    if combine not in COMBINE_MODES:
        raise unknown_choice("reservoir combination", combine, COMBINE_MODES)
    n = len(counts)
    masks = masks if masks is not None else [True] * n
    ok = r.p_hat > 0.0
    base = r.w_sum / dr.maximum(r.p_hat, 1e-30)
    if combine == "biased":
        m = dr.rcp(dr.maximum(r.M, 1e-30))
    elif combine == "1/z":
        Z = mi.Float(0.0)
        for c, ph, mk in zip(counts, p_hats, masks):
            Z += dr.select(mi.Bool(mk) & (ph > 0.0), c, 0.0)
        m = dr.select(Z > 0.0, dr.rcp(Z), 0.0)
    else:
        den = mi.Float(0.0)
        num = mi.Float(0.0)
        for i, (c, ph, mk) in enumerate(zip(counts, p_hats, masks)):
            den += dr.select(mi.Bool(mk), c * ph, 0.0)
            num = dr.select(r.src == i, ph, num)
        m = dr.select(den > 0.0, num / dr.maximum(den, 1e-30), 0.0)
    r.W = dr.select(ok, base * m, 0.0)
