"""Blending probe-ray results into the texels (replaceable piece #3: accumulation).

DDGI (Majercik et al., JCGT 2019, Sec. 3.2) updates texel ``t`` of a probe
from that probe's ``N`` rays ``(w_r, L_r, d_r)`` of this frame:

* irradiance: ``E_t/pi = sum_r max(0, n_t . w_r) L_r / sum_r max(0, n_t . w_r)``;
* distance moments: ``sum_r max(0, n_t . w_r)^p (d_r, d_r^2) / sum_r max(0, n_t . w_r)^p``
  with the sharp power ``p`` (50), distances clamped to ``max_distance``;
* hysteresis: ``new = lerp(blend, old, h)``, ``h = 0.97`` by default.

Faster reaction (Majercik et al., JCGT 2021, Sec. 6, and the RTXGI reference
conventions): irradiance is blended in a perceptual space ``E^(1/gamma)``
(gamma 5); when any channel of a texel moves by more than
``change_threshold`` (0.25) in that space the hysteresis of that texel drops
by 0.75, and a brightening step whose luminance exceeds
``brightness_threshold`` is scaled by 0.25 to suppress fireflies (RTXGI uses 0.1;
the ``ddgi`` technique turns it off by default, see its parameter).
Probes without history (first update) take the new value directly.

When every probe traced the same direction set (DDGI's shared rotated
spherical-Fibonacci set), the weights form one matrix ``W[N x T^2]`` shared
by all probes and the blend is a dense matrix product
``radiance[P x N] @ W`` (NumPy/BLAS) -- see DESIGN.md for the measurements.
Border texels get the direction of the interior texel they copy, so the
matrix fills them consistently with no separate border pass.
"""
from __future__ import annotations

import functools

import numpy as np

from ..backend import dr, mi
from ..sampling.octahedral import border_source_index, texel_directions
from .encoding import get_encoding
from .trace import ProbeRayResults, vector_to_numpy
from .volume import ProbeVolume

LUMINANCE = np.array([0.2126, 0.7152, 0.0722], np.float32)
CHANGE_HYSTERESIS_DROP = 0.75
BRIGHTNESS_DAMPING = 0.25
MIN_BLEND_WEIGHT = 1e-12


def blend_matrix(ray_dirs: np.ndarray, texels: int, power: float,
                 interior: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Normalised blend weights (N, T*T) float32 and a (T*T,) mask of texels that received weight.

    ``W[r, t] = max(0, n_t . w_r)^power / sum_r' max(0, n_t . w_r')^power``.
    With ``interior`` only the ``(T-2)^2`` interior texels are columns (the
    border texels copy them; see :func:`interior_source_index`).

    Rebuilt every frame (the rays rotate), so it is computed in float32 with
    cosines below ``MIN_BLEND_WEIGHT^(1/power)`` set to 0 first: their weights
    would be cut anyway, and no float32 denormal (slow in the power and in the
    BLAS products) can arise.
    """
    tdirs = _texel_directions_table(int(texels), bool(interior))
    c = np.asarray(ray_dirs, np.float32) @ tdirs.T
    cut = MIN_BLEND_WEIGHT ** (1.0 / power) if power > 1.0 else 0.0
    c[c <= cut] = 0.0
    w = _power(c, power)
    s = w.sum(axis=0, dtype=np.float64)
    ok = s > 0.0
    w[:, ok] *= (1.0 / s[ok]).astype(np.float32)
    w[w < MIN_BLEND_WEIGHT] = 0.0
    return w, ok


@functools.lru_cache(maxsize=None)
def _texel_directions_table(texels: int, interior: bool) -> np.ndarray:
    """(T*T or (T-2)^2, 3) float32 texel directions (read-only, shared)."""
    tdirs = texel_directions(texels, with_border=not interior)
    tdirs = (tdirs[1:-1, 1:-1] if interior else tdirs).reshape(-1, 3).astype(np.float32)
    tdirs.flags.writeable = False
    return tdirs


def _power(c: np.ndarray, p: float) -> np.ndarray:
    """``c ** p``; integer powers by repeated squaring (the per-frame matrix rebuild is ~4x faster)."""
    if p == 1.0:
        return c
    if p != int(p) or p < 1 or p > 1024:
        return c ** np.float32(p)
    n, out, sq = int(p), None, c
    while n:
        if n & 1:
            out = sq.copy() if out is None else np.multiply(out, sq, out=out)
        n >>= 1
        if n:
            sq = sq * sq
    return out


def interior_source_index(texels: int) -> np.ndarray:
    """(T*T,) uint32: index ``(y-1) * (T-2) + (x-1)`` of the interior texel that each bordered texel copies."""
    T = int(texels)
    src = border_source_index(T).ravel()
    sy, sx = src // T, src % T
    return ((sy - 1) * (T - 2) + (sx - 1)).astype(np.uint32)


class HysteresisBlend:
    """DDGI's per-texel exponential blend; see the module docstring.

    Parameters
    ----------
    hysteresis : float = 0.97
    distance_power : float = 50
    irradiance_gamma : float = 5    perceptual blending space (1: linear)
    change_threshold : float = 0.25 per-channel change (in that space) that lowers the hysteresis
    brightness_threshold : float = 0.1  luminance of a brightening step that gets damped (inf: off)
    encoding : str = 'fp32'         storage encoding applied after each blend (see :mod:`.encoding`)
    """

    def __init__(self, hysteresis: float = 0.97, distance_power: float = 50.0, irradiance_gamma: float = 5.0,
                 change_threshold: float = 0.25, brightness_threshold: float = 0.1, encoding: str = "fp32"):
        self.hysteresis = float(hysteresis)
        self.distance_power = float(distance_power)
        self.irradiance_gamma = float(irradiance_gamma)
        self.change_threshold = float(change_threshold)
        self.brightness_threshold = float(brightness_threshold)
        self.encoding = get_encoding(encoding)
        self._cache_key = None
        self._cache = None

    # -- weights ----------------------------------------------------------------
    def _matrices(self, dirs: np.ndarray, volume: ProbeVolume):
        key = (dirs.shape, dirs.tobytes()[:64], hash(dirs.tobytes()), volume.irradiance_texels,
               volume.distance_texels, self.distance_power)
        if key != self._cache_key:
            self._cache = (blend_matrix(dirs, volume.irradiance_texels, 1.0, interior=True),
                           blend_matrix(dirs, volume.distance_texels, self.distance_power, interior=True))
            self._cache_key = key
        return self._cache

    # -- one frame ----------------------------------------------------------------
    def new_estimates(self, volume: ProbeVolume, results: ProbeRayResults):
        """This frame's estimates for the *interior* texels, channel-planar: irradiance (3, P*(Ti-2)^2),
        moments (2, P*(Td-2)^2), and the masks ((Ti-2)^2,) / ((Td-2)^2,) of texels that received weight.

        Only interior texels are products (the border texels copy them when
        the result is stored): 44% fewer columns for 8x8 texels, 23% for 16x16.
        """
        plan = results.plan
        if plan.shared_directions is None:
            raise ValueError("HysteresisBlend needs a shared direction set (use a per-sample accumulator)")
        (Wi, ok_i), (Wd, ok_d) = self._matrices(plan.shared_directions, volume)
        P, N = len(plan.probe_ids), plan.rays_per_probe
        rad_host, dist_host = results.host()
        rad = rad_host.reshape(3 * P, N)
        irr = (rad @ Wi).reshape(3, -1)
        # the moments' rays: (|d| clamped, its square) stacked, built in place (no concatenation)
        dd = np.empty((2 * P, N), np.float32)
        np.abs(dist_host.reshape(P, N), out=dd[:P])
        np.minimum(dd[:P], np.float32(volume.max_distance), out=dd[:P])
        np.multiply(dd[:P], dd[:P], out=dd[P:])
        mom = (dd @ Wd).reshape(2, -1)
        return irr, mom, ok_i, ok_d

    def update(self, volume: ProbeVolume, results: ProbeRayResults) -> None:
        """Blend this frame's rays into the probes they came from.

        The per-texel hysteresis (with the storage quantisation fused in) runs
        as Dr.Jit kernels on the device mirror, whose atlases are then updated
        in place; the host arrays are refreshed from it when read.
        """
        st = volume.state
        pid = np.asarray(results.plan.probe_ids, np.int64)
        if len(pid) == 0:
            return
        irr, mom, ok_i, ok_d = self.new_estimates(volume, results)
        dev = volume.device
        pid_dr = mi.UInt32(pid.astype(np.uint32))
        fresh_dr = mi.Bool(st.updates[pid] == 0)
        # the blended texels are evaluated before they are scattered: a pending gather of an atlas
        # would make the scatter copy the whole atlas first (5.5 MB per frame)
        irr_new, irr_idx = self._blend_irradiance(volume, irr, ok_i, pid_dr, fresh_dr, len(pid))
        mom_new, mom_idx = self._blend_distance(volume, mom, ok_d, pid_dr, fresh_dr, len(pid))
        dr.eval(irr_new, mom_new)
        dr.scatter(dev.irradiance, irr_new, irr_idx)
        dr.scatter(dev.distance, mom_new, mom_idx)
        dr.eval(dev.irradiance, dev.distance)

        # -- the host copy is refreshed only when something reads it --
        st.device_is_newer(_pull_from(dev))
        st.updates[pid] += 1

    def _blend_irradiance(self, volume, irr, ok_i, pid_dr, fresh_dr, n_probes: int):
        """Blended irradiance texels of the traced probes (all bordered texels) and their atlas indices:
        perceptual space, change detection, brightness damping, storage quantisation."""
        dev = volume.device
        Ti = volume.irradiance_texels
        h = dr.opaque(mi.Float, self.hysteresis)
        probe_local, gidx, src = _texel_indices(pid_dr, n_probes, Ti)
        new = _gather_planar(mi.Color3f, irr, probe_local * (Ti - 2) ** 2 + src)
        old = dr.gather(mi.Color3f, dev.irradiance, gidx)
        fresh = dr.gather(mi.Bool, fresh_dr, probe_local)
        ok = dr.gather(mi.Bool, mi.Bool(ok_i), src)
        inv_g = dr.opaque(mi.Float, 1.0 / self.irradiance_gamma)
        g = dr.opaque(mi.Float, self.irradiance_gamma)
        new_g = dr.power(dr.maximum(new, 0.0), inv_g)
        old_g = dr.power(dr.maximum(old, 0.0), inv_g)
        delta = new_g - old_g
        h0 = dr.select(fresh, 0.0, h)
        big = dr.max(dr.abs(delta)) > dr.opaque(mi.Float, self.change_threshold)
        hh = dr.select(big, dr.maximum(h0 - CHANGE_HYSTERESIS_DROP, 0.0), h0)
        lum = mi.luminance(delta)
        bright = (lum > dr.opaque(mi.Float, min(self.brightness_threshold, 3e38))) & ~fresh
        delta = dr.select(bright, delta * BRIGHTNESS_DAMPING, delta)
        res_g = dr.maximum(old_g + (1.0 - hh) * delta, 0.0)
        res = dr.select(res_g > 0.0, dr.power(res_g, g), 0.0)
        res = self.encoding.quantize_irradiance(res)
        return dr.select(ok, res, old), gidx

    def _blend_distance(self, volume, mom, ok_d, pid_dr, fresh_dr, n_probes: int):
        """Blended distance moments of the traced probes (plain hysteresis) and their atlas indices."""
        dev = volume.device
        Td = volume.distance_texels
        probe_local, gidx, src = _texel_indices(pid_dr, n_probes, Td)
        newd = _gather_planar(mi.Vector2f, mom, probe_local * (Td - 2) ** 2 + src)
        oldd = dr.gather(mi.Vector2f, dev.distance, gidx)
        fresh = dr.gather(mi.Bool, fresh_dr, probe_local)
        ok = dr.gather(mi.Bool, mi.Bool(ok_d), src)
        hd = dr.select(fresh, 0.0, dr.opaque(mi.Float, self.hysteresis))
        resd = dr.fma(1.0 - hd, newd - oldd, oldd)
        resd = self.encoding.quantize_distance(resd, dr.opaque(mi.Float, volume.grid.cell_diagonal))
        return dr.select(ok, resd, oldd), gidx


def _pull_from(dev):
    """Copier of the device atlases ``dev.irradiance`` / ``dev.distance`` (as they are when read) into host arrays.

    It holds the device mirror, not its arrays: a second reference to an atlas
    would make the next frame's in-place ``dr.scatter`` copy it first (5.5 MB).
    """
    def pull(name: str, out: np.ndarray) -> None:
        out[...] = np.asarray(getattr(dev, name), np.float32).reshape(out.shape)
    return pull


def _gather_planar(cls, planar: np.ndarray, k):
    """``cls`` values at flat texel indices ``k`` from a channel-planar (C, n) host array (no transpose)."""
    flat = mi.Float(planar.ravel())
    n = planar.shape[1]
    # the channel offset depends on the number of traced probes: opaque, or every count recompiles
    return cls(*[dr.gather(mi.Float, flat, k + dr.opaque(mi.UInt32, c * n)) for c in range(planar.shape[0])])


@functools.lru_cache(maxsize=None)
def _source_table(texels: int):
    return mi.UInt32(interior_source_index(texels))


def _texel_indices(pid_dr, n_probes: int, texels: int):
    """Per bordered texel of the traced probes: its probe slot, global texel index and the
    interior texel it copies (:func:`interior_source_index`)."""
    texels2 = texels * texels
    k = dr.arange(mi.UInt32, n_probes * texels2)
    probe_local = k // texels2
    texel = k - probe_local * texels2
    probe = dr.gather(mi.UInt32, pid_dr, probe_local)
    src = dr.gather(mi.UInt32, _source_table(texels), texel)
    return probe_local, probe * texels2 + texel, src


class TrueAverage:
    """Per-texel plain mean of lobe-sampled rays (the fp32 reference of ADGI Sec. 5): no history.

    Expects a :class:`~dyngi.probes.rays.LobeDirections` plan for irradiance
    (cosine lobe) and one for distance (cosine-power lobe); interior texels are
    the means, borders are copied.
    """

    def __init__(self, encoding: str = "fp32"):
        self.encoding = get_encoding(encoding)

    @staticmethod
    def _texel_means(values: np.ndarray, P: int, n_texels: int, k: int) -> np.ndarray:
        return values.reshape(P, n_texels, k, -1).mean(axis=2)

    @staticmethod
    def _fill(interior: np.ndarray, texels: int) -> np.ndarray:
        P, _, C = interior.shape
        full = np.zeros((P, texels, texels, C), np.float32)
        full[:, 1:-1, 1:-1] = interior.reshape(P, texels - 2, texels - 2, C)
        src = border_source_index(texels).ravel()
        return full.reshape(P, texels * texels, C)[:, src].reshape(P, texels, texels, C)

    def update(self, volume: ProbeVolume, irr_results: ProbeRayResults, dist_results: ProbeRayResults,
               k_irr: int, k_dist: int) -> None:
        st = volume.state
        pid = np.asarray(irr_results.plan.probe_ids, np.int64)
        P = len(pid)
        Ti, Td = volume.irradiance_texels, volume.distance_texels
        rad = vector_to_numpy(irr_results.radiance).T          # (P*n, 3)
        irr = self._fill(self._texel_means(rad, P, (Ti - 2) ** 2, k_irr), Ti)
        d = np.asarray(dist_results.distance, np.float32)
        d = np.minimum(np.abs(d), np.float32(volume.max_distance))
        mom = self._fill(self._texel_means(np.stack([d, d * d], -1), P, (Td - 2) ** 2, k_dist), Td)
        st.irradiance[pid], st.extra = self.encoding.store_irradiance(irr, pid, st.extra)
        st.distance[pid], st.extra = self.encoding.store_distance(mom, pid, st.extra, volume.grid.cell_diagonal)
        st.updates[pid] += 1
        volume.sync(("irradiance", "distance"))
