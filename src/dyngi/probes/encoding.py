"""Storage encodings of probe texels (replaceable piece #4), all in one place.

* ``fp32``  -- RGB32F irradiance, RG32F distance moments (the reference, ADGI Table 3).
* ``qddgi`` -- Q-DDGI (ADGI Sec. 5, Table 3): irradiance ``floor(R11) floor(G11) floor(B10)``
  after the log non-linearity of ADGI Eq. 21; visibility ``[R16][G16]`` (round to
  nearest) of the log-encoded moments normalised by the cell diagonal.
* ``adgi``  -- ADGI (Sec. 4.5-4.6, Appendix B): irradiance ``floor(R9) floor(G9) floor(B8)``
  + a 6-bit sample count; visibility ``[R13][G13]`` + a 6-bit count, both log-encoded.

ADGI Eq. 21: ``u = min(ln(gamma * v + 1), beta) / beta`` in [0, 1], quantised to
``bits``; decoding inverts it: ``v = (exp(beta * u) - 1) / gamma``. (beta, gamma)
= (5, 15) for irradiance and the mean distance, (8, 20) for the mean squared
distance (Sec. 4.6). Rounding to the lowest code (Appendix B) makes a moving
average of dark samples reach zero; it biases values down by < one step.

Each encoder exposes ``encode_*`` (values -> uint32 codes) and ``decode_*``
(codes -> values), inverse pairs, and ``store_irradiance`` / ``store_distance``,
which a blender calls after each update: they return the decoded values that
the cache will actually hold (so quantisation feeds back into the next blend,
as on a GPU) and keep the packed words in ``state.extra`` for inspection.
"""
from __future__ import annotations

import numpy as np

from ..backend import dr, mi
from ..errors import unknown_choice

IRR_BETA, IRR_GAMMA = 5.0, 15.0          # Eq. 21 parameters for irradiance and mean distance
SQ_BETA, SQ_GAMMA = 8.0, 20.0            # Eq. 21 parameters for the mean squared distance
COUNT_MAX = 63                           # 6-bit sample count
FLOOR_EPS = 1e-3                         # code units: re-encoding a decoded value returns the same code


def log_quantize(v: np.ndarray, bits: int, beta: float, gamma: float, floor: bool) -> np.ndarray:
    """ADGI Eq. 21 then quantise to ``bits`` (floor or round-to-nearest) -> uint32 codes. Inverse: :func:`log_dequantize`."""
    v = np.maximum(np.nan_to_num(np.asarray(v, np.float64), nan=0.0, posinf=1e30), 0.0)
    u = np.minimum(np.log1p(gamma * v), beta) / beta
    q = u * ((1 << bits) - 1)
    q = np.floor(q + FLOOR_EPS) if floor else np.rint(q)
    return q.astype(np.uint32)


def log_dequantize(code: np.ndarray, bits: int, beta: float, gamma: float) -> np.ndarray:
    """Codes of :func:`log_quantize` -> values ``(exp(beta u) - 1) / gamma`` (float32)."""
    u = np.asarray(code, np.float64) / ((1 << bits) - 1)
    return (np.expm1(beta * u) / gamma).astype(np.float32)


def log_step(v: np.ndarray, bits: int, beta: float, gamma: float) -> np.ndarray:
    """Size of the quantisation step of Eq. 21 at value ``v`` (for round-trip tests)."""
    v = np.asarray(v, np.float64)
    return (gamma * v + 1.0) * beta / (((1 << bits) - 1) * gamma)


def log_requantize_dr(v, bits: int, beta: float, gamma: float, floor: bool):
    """Dr.Jit: Eq. 21 quantisation followed by decoding (the value a ``bits``-bit texel would hold)."""
    levels = float((1 << bits) - 1)
    u = dr.minimum(dr.log(dr.fma(dr.maximum(v, 0.0), gamma, 1.0)), beta) * (levels / beta)
    q = dr.floor(u + FLOOR_EPS) if floor else dr.round(u)
    return (dr.exp(q * (beta / levels)) - 1.0) * (1.0 / gamma)


def _pack(fields, widths) -> np.ndarray:
    out = np.zeros(np.shape(fields[0]), np.uint32)
    shift = 0
    for f, w in zip(fields, widths):
        out |= (np.asarray(f, np.uint32) & np.uint32((1 << w) - 1)) << np.uint32(shift)
        shift += w
    return out


def _unpack(word, widths):
    word = np.asarray(word, np.uint32)
    out, shift = [], 0
    for w in widths:
        out.append((word >> np.uint32(shift)) & np.uint32((1 << w) - 1))
        shift += w
    return out


class Fp32Encoding:
    name = "fp32"

    def quantize_irradiance(self, rgb):
        return rgb

    def quantize_distance(self, mom, diagonal):
        return mom

    def store_irradiance(self, values, pid, extra):
        return np.asarray(values, np.float32), extra

    def store_distance(self, values, pid, extra, diagonal):
        return np.asarray(values, np.float32), extra


class QDDGIEncoding:
    """Q-DDGI: R11G11B10 log-nonlinear irradiance (floor), RG16 log-nonlinear visibility (nearest)."""

    name = "qddgi"
    IRR_BITS = (11, 11, 10)
    VIS_BITS = (16, 16)

    def quantize_irradiance(self, rgb):
        """Dr.Jit: decode(encode(rgb)) for Color3f values."""
        return mi.Color3f(*[log_requantize_dr(rgb[c], b, IRR_BETA, IRR_GAMMA, True)
                            for c, b in enumerate(self.IRR_BITS)])

    def quantize_distance(self, mom, diagonal):
        m1 = log_requantize_dr(mom.x / diagonal, 16, IRR_BETA, IRR_GAMMA, False) * diagonal
        m2 = log_requantize_dr(mom.y / (diagonal * diagonal), 16, SQ_BETA, SQ_GAMMA, False) * (diagonal * diagonal)
        return mi.Vector2f(m1, m2)

    def encode_irradiance(self, rgb):
        rgb = np.asarray(rgb)
        f = [log_quantize(rgb[..., c], b, IRR_BETA, IRR_GAMMA, True) for c, b in enumerate(self.IRR_BITS)]
        return _pack(f, self.IRR_BITS)

    def decode_irradiance(self, word):
        f = _unpack(word, self.IRR_BITS)
        return np.stack([log_dequantize(q, b, IRR_BETA, IRR_GAMMA) for q, b in zip(f, self.IRR_BITS)], -1)

    def encode_distance(self, mom, diagonal):
        mom = np.asarray(mom, np.float64)
        m1 = log_quantize(mom[..., 0] / diagonal, 16, IRR_BETA, IRR_GAMMA, False)
        m2 = log_quantize(mom[..., 1] / diagonal ** 2, 16, SQ_BETA, SQ_GAMMA, False)
        return _pack([m1, m2], self.VIS_BITS)

    def decode_distance(self, word, diagonal):
        m1, m2 = _unpack(word, self.VIS_BITS)
        return np.stack([log_dequantize(m1, 16, IRR_BETA, IRR_GAMMA) * diagonal,
                         log_dequantize(m2, 16, SQ_BETA, SQ_GAMMA) * diagonal ** 2], -1).astype(np.float32)

    def store_irradiance(self, values, pid, extra):
        w = self.encode_irradiance(values)
        _store_words(extra, "irradiance_words", pid, w)
        return self.decode_irradiance(w), extra

    def store_distance(self, values, pid, extra, diagonal):
        w = self.encode_distance(values, diagonal)
        _store_words(extra, "distance_words", pid, w)
        return self.decode_distance(w, diagonal), extra


class ADGIEncoding:
    """ADGI: R9G9B8 + 6-bit count irradiance (floor), R13G13 + 6-bit count visibility (floor)."""

    name = "adgi"
    IRR_BITS = (9, 9, 8, 6)
    VIS_BITS = (13, 13, 6)

    def quantize_irradiance(self, rgb):
        """Dr.Jit: decode(encode(rgb)) for Color3f values (the count field does not change values)."""
        return mi.Color3f(*[log_requantize_dr(rgb[c], b, IRR_BETA, IRR_GAMMA, True)
                            for c, b in enumerate(self.IRR_BITS[:3])])

    def quantize_distance(self, mom, diagonal):
        m1 = log_requantize_dr(mom.x / diagonal, 13, IRR_BETA, IRR_GAMMA, True) * diagonal
        m2 = log_requantize_dr(mom.y / (diagonal * diagonal), 13, SQ_BETA, SQ_GAMMA, True) * (diagonal * diagonal)
        return mi.Vector2f(m1, m2)

    def encode_irradiance(self, rgb, count):
        rgb = np.asarray(rgb)
        f = [log_quantize(rgb[..., c], b, IRR_BETA, IRR_GAMMA, True) for c, b in enumerate(self.IRR_BITS[:3])]
        return _pack(f + [np.minimum(count, COUNT_MAX)], self.IRR_BITS)

    def decode_irradiance(self, word):
        *f, n = _unpack(word, self.IRR_BITS)
        rgb = np.stack([log_dequantize(q, b, IRR_BETA, IRR_GAMMA) for q, b in zip(f, self.IRR_BITS)], -1)
        return rgb, n

    def encode_distance(self, mom, count, diagonal):
        mom = np.asarray(mom, np.float64)
        m1 = log_quantize(mom[..., 0] / diagonal, 13, IRR_BETA, IRR_GAMMA, True)
        m2 = log_quantize(mom[..., 1] / diagonal ** 2, 13, SQ_BETA, SQ_GAMMA, True)
        return _pack([m1, m2, np.minimum(count, COUNT_MAX)], self.VIS_BITS)

    def decode_distance(self, word, diagonal):
        m1, m2, n = _unpack(word, self.VIS_BITS)
        mom = np.stack([log_dequantize(m1, 13, IRR_BETA, IRR_GAMMA) * diagonal,
                        log_dequantize(m2, 13, SQ_BETA, SQ_GAMMA) * diagonal ** 2], -1).astype(np.float32)
        return mom, n

    def _counts(self, extra, key, pid, shape):
        old = extra.get(key)
        if old is None:
            return np.ones(shape, np.uint32)
        return np.minimum(_unpack(old[pid], self.IRR_BITS if "irr" in key else self.VIS_BITS)[-1] + 1,
                          COUNT_MAX).astype(np.uint32)

    def store_irradiance(self, values, pid, extra):
        n = self._counts(extra, "irradiance_words", pid, np.shape(values)[:-1])
        w = self.encode_irradiance(values, n)
        _store_words(extra, "irradiance_words", pid, w)
        return self.decode_irradiance(w)[0], extra

    def store_distance(self, values, pid, extra, diagonal):
        n = self._counts(extra, "distance_words", pid, np.shape(values)[:-1])
        w = self.encode_distance(values, n, diagonal)
        _store_words(extra, "distance_words", pid, w)
        return self.decode_distance(w, diagonal)[0], extra


def _store_words(extra: dict, key: str, pid, words) -> None:
    arr = extra.get(key)
    n_total = extra.get("n_probes")
    if arr is None:
        size = max(int(np.max(pid)) + 1, int(n_total or 0))
        arr = np.zeros((size,) + words.shape[1:], np.uint32)
    elif arr.shape[0] <= int(np.max(pid)):
        grown = np.zeros((int(np.max(pid)) + 1,) + arr.shape[1:], np.uint32)
        grown[: arr.shape[0]] = arr
        arr = grown
    arr[pid] = words
    extra[key] = arr


ENCODINGS = {"fp32": Fp32Encoding, "qddgi": QDDGIEncoding, "adgi": ADGIEncoding}


def get_encoding(name: str):
    if name not in ENCODINGS:
        raise unknown_choice("encoding", name, ENCODINGS)
    return ENCODINGS[name]()
