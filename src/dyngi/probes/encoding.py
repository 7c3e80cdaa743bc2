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

Each encoding is one Dr.Jit **store/load pair** per atlas, inverses of each
other: ``store_irradiance(rgb, count, old=None)`` -> the stored texel (packed
UInt32 word(s) and the count), ``load_irradiance(stored)`` -> ``(rgb, count)``;
likewise ``store_distance`` / ``load_distance`` (moments normalised by the cell
diagonal). The temporal accumulators (:mod:`.accumulator`) write
``load(store(x))`` into the volume's device atlases and count arrays, so what
:class:`~dyngi.probes.query.ProbeQuery` reads is exactly the stored value (and
quantisation feeds back into the next blend, as on a GPU). ``old`` enables the
minimum-step rule (:func:`log_code_dr`). The NumPy ``encode_*`` / ``decode_*``
pairs are the same codecs on the host, for inspection and tests.
"""
from __future__ import annotations

import numpy as np

from ..backend import dr, mi
from ..errors import unknown_choice

IRR_BETA, IRR_GAMMA = 5.0, 15.0          # Eq. 21 parameters for irradiance and mean distance
SQ_BETA, SQ_GAMMA = 8.0, 20.0            # Eq. 21 parameters for the mean squared distance
COUNT_MAX = 63                           # 6-bit sample count (ADGI words)
SEPARATE_COUNT_MAX = (1 << 16) - 1       # cap of counts kept beside the texel (fp32, Q-DDGI; our choice)
FLOOR_EPS = 1e-3                         # code units: re-encoding a decoded value returns the same code
MIN_STEP_EPS = 0.05                      # code units: smallest change the minimum-step rule acts on


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


def log_code_dr(v, bits: int, beta: float, gamma: float, floor: bool, old=None):
    """Dr.Jit: the ``bits``-bit code (UInt32) of ADGI Eq. 21 for ``v``. Inverse: :func:`log_decode_dr`.

    **Minimum-step rule** (ours; issue 11 item 2): with ``old`` (the decoded
    value the texel held), a value that differs from ``old`` moves the code at
    least one step towards it. Rounding to the lowest code (or to the nearest)
    otherwise swallows every hysteresis step smaller than one code (or half of
    one): at h = 0.94 a texel rising towards a constant input stalls up to
    ~1/(1-h) = 16 steps below it, and round-down storage drifts low. With the
    rule a constant input is reached to within one step; a noisy input makes
    the code follow the sign of each frame's change for changes below one step
    (a median-like bias of at most a step or two for skewed noise).
    """
    levels = float((1 << bits) - 1)
    u = dr.minimum(dr.log(dr.fma(dr.maximum(v, 0.0), gamma, 1.0)), beta) * (levels / beta)
    q = dr.floor(u + FLOOR_EPS) if floor else dr.round(u)
    if old is not None:
        uo = dr.minimum(dr.log(dr.fma(dr.maximum(old, 0.0), gamma, 1.0)), beta) * (levels / beta)
        qo = dr.round(uo)          # ``old`` is a decoded value: its code is the nearest integer
        up = u > qo + MIN_STEP_EPS          # a change of less than MIN_STEP_EPS codes is float noise
        down = u < qo - MIN_STEP_EPS         # (e.g. of the perceptual blend's gamma round trip)
        q = dr.select(up, dr.maximum(q, dr.minimum(qo + 1.0, levels)),
                      dr.select(down, dr.minimum(q, dr.maximum(qo - 1.0, 0.0)), q))
    return mi.UInt32(dr.clip(q, 0.0, levels))


def log_decode_dr(code, bits: int, beta: float, gamma: float):
    """Dr.Jit: codes of :func:`log_code_dr` -> values ``(exp(beta u) - 1) / gamma``."""
    return (dr.exp(mi.Float(code) * (beta / float((1 << bits) - 1))) - 1.0) * (1.0 / gamma)


def _pack_dr(fields, widths):
    """Dr.Jit: UInt32 fields -> one UInt32 word, first field in the lowest bits. Inverse: :func:`_unpack_dr`."""
    out, shift = mi.UInt32(0), 0
    for f, w in zip(fields, widths):
        out = out | ((mi.UInt32(f) & ((1 << w) - 1)) << shift)
        shift += w
    return out


def _unpack_dr(word, widths):
    """Dr.Jit: one UInt32 word -> its fields. Inverse: :func:`_pack_dr`."""
    out, shift = [], 0
    for w in widths:
        out.append((word >> shift) & ((1 << w) - 1))
        shift += w
    return out


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
    """RGB32F irradiance, RG32F moments: ``store`` and ``load`` are the identity (no quantisation).

    Counts are not part of the texel words; the volume keeps them beside the
    atlases, capped at :data:`SEPARATE_COUNT_MAX` (our choice).
    """

    name = "fp32"
    count_max = SEPARATE_COUNT_MAX

    def store_irradiance(self, rgb, count, old=None):
        """Dr.Jit: (Color3f, UInt32 count) -> the stored texel ``(rgb, count)``. Inverse: :meth:`load_irradiance`."""
        return rgb, dr.minimum(count, self.count_max)

    def load_irradiance(self, stored):
        """Dr.Jit: stored texel -> ``(rgb, count)``. Inverse: :meth:`store_irradiance`."""
        return stored

    def store_distance(self, mom, count, diagonal, old=None):
        """Dr.Jit: (Vector2f moments, UInt32 count) -> stored texel. Inverse: :meth:`load_distance`."""
        return mom, dr.minimum(count, self.count_max)

    def load_distance(self, stored, diagonal):
        """Dr.Jit: stored texel -> ``(moments, count)``. Inverse: :meth:`store_distance`."""
        return stored

    def roundtrip_irradiance(self, rgb, count, old=None):
        """``load(store(rgb, count, old))``: the value and count a texel holds after storing (Dr.Jit)."""
        return self.load_irradiance(self.store_irradiance(rgb, count, old))

    def roundtrip_distance(self, mom, count, diagonal, old=None):
        return self.load_distance(self.store_distance(mom, count, diagonal, old), diagonal)


class QDDGIEncoding(Fp32Encoding):
    """Q-DDGI: R11G11B10 log-nonlinear irradiance (floor), RG16 log-nonlinear visibility (nearest).

    Device words: irradiance ``R | G << 11 | B << 22``, visibility ``m1 | m2 << 16``
    (one UInt32 each); the count is kept beside the word (Q-DDGI has no count bits).
    Storing with ``old`` (the value the texel held) applies the minimum-step rule
    of :func:`log_code_dr`.
    """

    name = "qddgi"
    IRR_BITS = (11, 11, 10)
    VIS_BITS = (16, 16)
    IRR_FLOOR, VIS_FLOOR = True, False

    def store_irradiance(self, rgb, count, old=None):
        """Dr.Jit: (Color3f, count[, old Color3f]) -> (UInt32 word, UInt32 count). Inverse: :meth:`load_irradiance`."""
        codes = [log_code_dr(rgb[c], b, IRR_BETA, IRR_GAMMA, self.IRR_FLOOR, None if old is None else old[c])
                 for c, b in enumerate(self.IRR_BITS)]
        return _pack_dr(codes, self.IRR_BITS), dr.minimum(count, self.count_max)

    def load_irradiance(self, stored):
        """Dr.Jit: (word, count) -> (Color3f, count). Inverse: :meth:`store_irradiance`."""
        word, count = stored
        f = _unpack_dr(word, self.IRR_BITS)
        return mi.Color3f(*[log_decode_dr(q, b, IRR_BETA, IRR_GAMMA) for q, b in zip(f, self.IRR_BITS)]), count

    def _vis_codes(self, mom, diagonal, old, bits):
        d2 = diagonal * diagonal
        o1 = None if old is None else old.x / diagonal
        o2 = None if old is None else old.y / d2
        return [log_code_dr(mom.x / diagonal, bits, IRR_BETA, IRR_GAMMA, self.VIS_FLOOR, o1),
                log_code_dr(mom.y / d2, bits, SQ_BETA, SQ_GAMMA, self.VIS_FLOOR, o2)]

    def _vis_values(self, f, diagonal, bits):
        return mi.Vector2f(log_decode_dr(f[0], bits, IRR_BETA, IRR_GAMMA) * diagonal,
                           log_decode_dr(f[1], bits, SQ_BETA, SQ_GAMMA) * (diagonal * diagonal))

    def store_distance(self, mom, count, diagonal, old=None):
        """Dr.Jit: (Vector2f moments, count, cell diagonal[, old]) -> (word, count). Inverse: :meth:`load_distance`."""
        return (_pack_dr(self._vis_codes(mom, diagonal, old, self.VIS_BITS[0]), self.VIS_BITS),
                dr.minimum(count, self.count_max))

    def load_distance(self, stored, diagonal):
        """Dr.Jit: (word, count) -> (Vector2f moments, count). Inverse: :meth:`store_distance`."""
        word, count = stored
        return self._vis_values(_unpack_dr(word, self.VIS_BITS), diagonal, self.VIS_BITS[0]), count

    # -- NumPy codec (host inspection and tests) --
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


class ADGIEncoding(QDDGIEncoding):
    """ADGI as Table 3 gives it (Datta et al. 2022): ``floor(R9) floor(G9) floor(B8) - N`` irradiance
    (round-down, Appendix B: a moving average of dark samples reaches zero) and ``[R13][G13] - N``
    visibility (Appendix B's ``[]``: round-to-nearest), Eq. 21's log non-linearity with (beta, gamma) =
    (5, 15) and (8, 20) (Sec. 4.5-4.6).

    Device words: irradiance ``R | G << 9 | B << 18 | n << 26``, visibility
    ``m1 | m2 << 13 | n << 26``; the count lives in the word (ADGI Appendix B),
    so it saturates at :data:`COUNT_MAX` = 63 (what caps ADGI's moving average).
    Round-to-nearest visibility halves the worst quantisation error of the moments and removes the low
    bias of a floored mean distance, which the Chebyshev test reads as "occluded". ``VIS_FLOOR = True``
    in a subclass floors the moments too (the one "adgi" encoding: ``ddgi``'s ``encoding='adgi'`` and
    the ``adgi`` technique store through this class).
    """

    name = "adgi"
    IRR_BITS = (9, 9, 8, 6)
    VIS_BITS = (13, 13, 6)
    IRR_FLOOR, VIS_FLOOR = True, False
    count_max = COUNT_MAX

    def store_irradiance(self, rgb, count, old=None):
        """Dr.Jit: (Color3f, count[, old]) -> UInt32 word, the count in its top 6 bits.
        Inverse: :meth:`load_irradiance`."""
        codes = [log_code_dr(rgb[c], b, IRR_BETA, IRR_GAMMA, True, None if old is None else old[c])
                 for c, b in enumerate(self.IRR_BITS[:3])]
        return _pack_dr(codes + [dr.minimum(mi.UInt32(count), self.count_max)], self.IRR_BITS)

    def load_irradiance(self, stored):
        """Dr.Jit: word -> (Color3f, UInt32 count). Inverse: :meth:`store_irradiance`."""
        *f, n = _unpack_dr(stored, self.IRR_BITS)
        return mi.Color3f(*[log_decode_dr(q, b, IRR_BETA, IRR_GAMMA) for q, b in zip(f, self.IRR_BITS)]), n

    def store_distance(self, mom, count, diagonal, old=None):
        """Dr.Jit: (moments, count, diagonal[, old]) -> UInt32 word (13-13 + 6-bit count).
        Inverse: :meth:`load_distance`."""
        codes = self._vis_codes(mom, diagonal, old, 13)
        return _pack_dr(codes + [dr.minimum(mi.UInt32(count), self.count_max)], self.VIS_BITS)

    def load_distance(self, stored, diagonal):
        """Dr.Jit: word -> (Vector2f moments, UInt32 count). Inverse: :meth:`store_distance`."""
        *f, n = _unpack_dr(stored, self.VIS_BITS)
        return self._vis_values(f, diagonal, 13), n

    # -- NumPy codec --
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
        m1 = log_quantize(mom[..., 0] / diagonal, 13, IRR_BETA, IRR_GAMMA, self.VIS_FLOOR)
        m2 = log_quantize(mom[..., 1] / diagonal ** 2, 13, SQ_BETA, SQ_GAMMA, self.VIS_FLOOR)
        return _pack([m1, m2, np.minimum(count, COUNT_MAX)], self.VIS_BITS)

    def decode_distance(self, word, diagonal):
        m1, m2, n = _unpack(word, self.VIS_BITS)
        mom = np.stack([log_dequantize(m1, 13, IRR_BETA, IRR_GAMMA) * diagonal,
                        log_dequantize(m2, 13, SQ_BETA, SQ_GAMMA) * diagonal ** 2], -1).astype(np.float32)
        return mom, n


ENCODINGS = {"fp32": Fp32Encoding, "qddgi": QDDGIEncoding, "adgi": ADGIEncoding}


def get_encoding(name: str):
    if name not in ENCODINGS:
        raise unknown_choice("encoding", name, ENCODINGS)
    return ENCODINGS[name]()
