"""Octahedral direction maps and the bordered probe-texel layout of DDGI.

The octahedral map (Praun & Hoppe 2003; Cigolle et al., JCGT 2014) sends a
unit direction ``d`` to a point ``p`` of the square [-1, 1]^2:
``p = d.xy / (|d.x| + |d.y| + |d.z|)``, folded over the diagonals when
``d.z < 0``. Each DDGI probe (Majercik et al., JCGT 2019, Sec. 3) stores a
``T x T`` texel square: the ``(T-2) x (T-2)`` interior covers the octahedral
square and a 1-texel border repeats the texels across each (mirrored) edge, so
hardware-style bilinear filtering never reads across the seam.

Conventions
-----------
* Texel ``(x, y)`` of a probe (``x`` column, ``y`` row, both in ``[0, T)``)
  has its centre at continuous coordinate ``(x + 0.5, y + 0.5)``; interior
  texels are ``1 <= x, y <= T-2``; ``p.x = 2 (x - 1 + 0.5) / (T - 2) - 1``.
* Border texel ``(0, y)`` copies interior texel ``(1, T-1-y)``,
  ``(T-1, y)`` copies ``(T-2, T-1-y)``, ``(x, 0)`` copies ``(T-1-x, 1)``,
  ``(x, T-1)`` copies ``(T-1-x, T-2)``; a corner copies the diagonally
  opposite interior corner. This is what mirroring across the octahedral
  edges gives (points ``(1, v)`` and ``(1, -v)`` decode to one direction).

Functions come in pairs: :func:`oct_encode` / :func:`oct_decode` (Dr.Jit) and
:func:`oct_encode_np` / :func:`oct_decode_np` (NumPy), each the inverse of
the other on the unit sphere.
"""
from __future__ import annotations

import numpy as np

from ..backend import dr, mi


# -- Dr.Jit ---------------------------------------------------------------------

def _sign_not_zero(x):
    return dr.select(x >= 0.0, 1.0, -1.0)


def oct_encode(d):
    """Direction (``mi.Vector3f``, any length) -> ``mi.Point2f`` in [-1, 1]^2. Inverse: :func:`oct_decode`.

    The map only depends on the direction, so ``d`` need not be normalised; a
    zero vector maps to the centre (the +z pole) instead of NaN.
    """
    inv_l1 = dr.rcp(dr.maximum(dr.abs(d.x) + dr.abs(d.y) + dr.abs(d.z), 1e-30))
    px, py = d.x * inv_l1, d.y * inv_l1
    fx = (1.0 - dr.abs(py)) * _sign_not_zero(px)
    fy = (1.0 - dr.abs(px)) * _sign_not_zero(py)
    lower = d.z < 0.0
    return mi.Point2f(dr.select(lower, fx, px), dr.select(lower, fy, py))


def oct_decode(p):
    """``mi.Point2f`` in [-1, 1]^2 -> unit ``mi.Vector3f``. Inverse: :func:`oct_encode`."""
    z = 1.0 - dr.abs(p.x) - dr.abs(p.y)
    lower = z < 0.0
    x = dr.select(lower, (1.0 - dr.abs(p.y)) * _sign_not_zero(p.x), p.x)
    y = dr.select(lower, (1.0 - dr.abs(p.x)) * _sign_not_zero(p.y), p.y)
    return dr.normalize(mi.Vector3f(x, y, z))


def direction_to_texel_coords(d, texels: int):
    """Continuous texel coordinates (x, y) in [1, T-1] of direction ``d`` inside one bordered probe square.

    Texel ``k`` spans ``[k, k+1)``; bilinear filtering samples at ``coords - 0.5``
    and reads texels ``floor`` and ``floor + 1``, which stay inside ``[0, T-1]``.
    """
    p = oct_encode(d)
    n = float(texels - 2)
    return mi.Point2f(dr.fma(p.x, 0.5 * n, 0.5 * n + 1.0), dr.fma(p.y, 0.5 * n, 0.5 * n + 1.0))


# -- NumPy ----------------------------------------------------------------------

def _sign_not_zero_np(x):
    return np.where(x >= 0.0, 1.0, -1.0)


def oct_encode_np(d: np.ndarray) -> np.ndarray:
    """(..., 3) unit directions -> (..., 2) points in [-1, 1]^2. Inverse: :func:`oct_decode_np`."""
    d = np.asarray(d, np.float64)
    p = d[..., :2] / np.sum(np.abs(d), axis=-1, keepdims=True)
    folded = (1.0 - np.abs(p[..., ::-1])) * _sign_not_zero_np(p)
    return np.where((d[..., 2] < 0.0)[..., None], folded, p)


def oct_decode_np(p: np.ndarray) -> np.ndarray:
    """(..., 2) points in [-1, 1]^2 -> (..., 3) unit directions. Inverse: :func:`oct_encode_np`."""
    p = np.asarray(p, np.float64)
    z = 1.0 - np.abs(p[..., 0]) - np.abs(p[..., 1])
    folded = (1.0 - np.abs(p[..., ::-1])) * _sign_not_zero_np(p)
    xy = np.where((z < 0.0)[..., None], folded, p)
    d = np.concatenate([xy, z[..., None]], axis=-1)
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def border_source_index(texels: int) -> np.ndarray:
    """(T, T) int array: flat index ``y * T + x`` of the interior texel each texel copies (identity inside)."""
    T = int(texels)
    if T < 3:
        raise ValueError("a bordered octahedral probe needs at least 3x3 texels")
    ys, xs = np.meshgrid(np.arange(T), np.arange(T), indexing="ij")
    sx, sy = xs.copy(), ys.copy()
    left, right, top, bottom = xs == 0, xs == T - 1, ys == 0, ys == T - 1
    # edges (mirror across the edge)
    e = left & ~top & ~bottom
    sx[e], sy[e] = 1, T - 1 - ys[e]
    e = right & ~top & ~bottom
    sx[e], sy[e] = T - 2, T - 1 - ys[e]
    e = top & ~left & ~right
    sx[e], sy[e] = T - 1 - xs[e], 1
    e = bottom & ~left & ~right
    sx[e], sy[e] = T - 1 - xs[e], T - 2
    # corners (diagonally opposite interior corner)
    for (cx, cy), (ox, oy) in {(0, 0): (T - 2, T - 2), (T - 1, 0): (1, T - 2),
                               (0, T - 1): (T - 2, 1), (T - 1, T - 1): (1, 1)}.items():
        sx[cy, cx], sy[cy, cx] = ox, oy
    return sy * T + sx


def texel_directions(texels: int, with_border: bool = True) -> np.ndarray:
    """Directions of the texel centres of one bordered probe square, shape (T, T, 3).

    With ``with_border`` a border texel gets the direction of the interior texel
    it copies (so anything computed per texel from its direction is border-
    consistent by construction); otherwise border entries are NaN.
    """
    T = int(texels)
    n = T - 2
    c = (np.arange(T) - 1 + 0.5) / n * 2.0 - 1.0
    py, px = np.meshgrid(c, c, indexing="ij")
    d = oct_decode_np(np.stack([px, py], -1))
    if with_border:
        d = d.reshape(-1, 3)[border_source_index(T).ravel()].reshape(T, T, 3)
    else:
        inner = np.zeros((T, T), bool)
        inner[1:-1, 1:-1] = True
        d[~inner] = np.nan
    return d


def texel_solid_angles(texels: int, sub: int = 8) -> np.ndarray:
    """Solid angle of each interior texel (T-2, T-2), by midpoint sub-sampling of the map's Jacobian.

    The octahedral map is not equal-area; ``sum == 4 pi`` up to the sub-sampling error.
    """
    n = int(texels) - 2
    m = n * sub
    c = (np.arange(m) + 0.5) / m * 2.0 - 1.0
    py, px = np.meshgrid(c, c, indexing="ij")
    p = np.stack([px, py], -1)
    h = 1e-4
    d0 = oct_decode_np(p)
    dx = (oct_decode_np(p + [h, 0.0]) - oct_decode_np(p - [h, 0.0])) / (2 * h)
    dy = (oct_decode_np(p + [0.0, h]) - oct_decode_np(p - [0.0, h])) / (2 * h)
    jac = np.abs(np.einsum("...i,...i->...", d0, np.cross(dx, dy)))
    area = (2.0 / m) ** 2
    return (jac * area).reshape(n, sub, n, sub).sum(axis=(1, 3))


def bilinear_texel_sample_np(atlas: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Reference NumPy bilinear lookup: ``atlas`` (T, T, C) at directions ``d`` (..., 3) -> (..., C)."""
    T = atlas.shape[0]
    n = T - 2
    p = oct_encode_np(d)
    cx = (p[..., 0] * 0.5 + 0.5) * n + 1.0 - 0.5
    cy = (p[..., 1] * 0.5 + 0.5) * n + 1.0 - 0.5
    x0 = np.clip(np.floor(cx).astype(int), 0, T - 2)
    y0 = np.clip(np.floor(cy).astype(int), 0, T - 2)
    fx, fy = (cx - x0)[..., None], (cy - y0)[..., None]
    a = atlas[y0, x0] * (1 - fx) + atlas[y0, x0 + 1] * fx
    b = atlas[y0 + 1, x0] * (1 - fx) + atlas[y0 + 1, x0 + 1] * fx
    return a * (1 - fy) + b * fy
