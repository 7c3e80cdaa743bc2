"""ADGI's per-sample radiance texels and the per-texel convolution pass to irradiance (ours; the paper is
silent on how a radiance sample becomes an irradiance texel, issue 12 item 5).

The radiance texels are the probe volume's third atlas, its radiance layer (ADGI asks for one of
``radiance_texels`` per side: :meth:`ProbeVolume.add_radiance_layer
<dyngi.probes.volume.ProbeVolume.add_radiance_layer>`; the volume allocates, resets and accounts for it);
:class:`RadianceUpdate` holds ADGI's rules on it and no texels.

A chain sample ``(p, w)`` with radiance ``L`` updates the one *radiance* texel
``w`` falls in (octahedral, ``R x R`` with the DDGI border, interior
``(R-2)^2``) of its probe with Algorithm 3's batch rule
(:mod:`.moving_average`): per texel the stored value is the mean of the
samples that landed in it, whatever their density -- the paper's Eq. 8
argument, which a cosine splat over many texels does not have (there the
splat's result depends on where in the hemisphere the chains happened to be:
biased low on the Cornell box probes whose -w rays miss through the open
front, where the guide is 0; docs/techniques/adgi.md).

Irradiance is then a convolution pass over the radiance texels of every probe
updated this frame (:meth:`RadianceUpdate.irradiance_estimate`: on a GPU on the device, one lane per
irradiance texel and a symbolic loop over the radiance texels, no host read; on the LLVM backend the
NumPy/BLAS pass :meth:`RadianceUpdate.irradiance_estimate_host`, the CPU fast path):
``E(n_t) / pi = sum_r W[r, t] L_r``,
``W[r, t] = max(0, n_t . w_r) Omega_r / sum_r' max(0, n_t . w_r') Omega_r'``
with ``Omega_r`` the texel solid angles (:func:`~dyngi.sampling.octahedral.texel_solid_angles`);
over the texels that hold a sample (texels never reached are left out and the
weights renormalised; an irradiance texel none of whose hemisphere holds one
keeps its value); its result is stored into the volume's irradiance atlas through the encoding
(:class:`~dyngi.probes.accumulator.MeanAccumulator`: the convolution already
is the temporal estimate). Texels no sample reached keep their radiance from
earlier frames (at first, from the warm-up's rays).
"""
from __future__ import annotations

import numpy as np

from ...backend import dr, mi
from ...errors import DyngiError
from ...probes.arrays import upload
from ...probes.estimator import TexelEstimate, is_cpu_backend
from ...probes.trace import vector_to_numpy
from ...sampling.octahedral import texel_directions, texel_solid_angles
from .moving_average import batch_update
from .sparse import SparseKeys


def _ids(probe_ids):
    """Probe ids as a device UInt32: uploaded from the host, or as they are (a masked plan's slots)."""
    if isinstance(probe_ids, np.ndarray) or isinstance(probe_ids, (list, tuple)):
        return upload(np.asarray(probe_ids, np.uint32), mi.UInt32)
    return mi.UInt32(probe_ids)


class RadianceUpdate:
    """ADGI's rules on the probe volume's radiance layer (:meth:`ProbeVolume.add_radiance_layer
    <dyngi.probes.volume.ProbeVolume.add_radiance_layer>`: per probe and interior radiance texel an Algorithm-3
    mean radiance, ``volume.device.radiance``, Color3f interleaved, and its count, ``volume.device
    .radiance_count``): the merge of a pass's samples, the outer count cap and the convolution to irradiance
    (module docstring). It stores no texels: the volume does (one texel store).

    volume : ProbeVolume with a radiance layer (``R = volume.radiance_texels`` incl. border); the convolution
    weights ``W`` map its ``(R-2)^2`` radiance texels to the volume's ``(Ti-2)^2`` interior irradiance texels.
    """

    def __init__(self, volume):
        if volume.radiance_texels is None:
            raise DyngiError("ADGI's radiance update needs a probe volume with a radiance layer "
                             "(ProbeVolume.add_radiance_layer)")
        self.volume = volume
        self.P = volume.n_probes
        self.R = volume.radiance_texels
        self.n_tex = volume.radiance_interior
        self.Ti = volume.irradiance_texels
        wr = texel_directions(self.R)[1:-1, 1:-1].reshape(-1, 3)
        om = texel_solid_angles(self.R).reshape(-1)
        nt = texel_directions(self.Ti)[1:-1, 1:-1].reshape(-1, 3)
        W = np.maximum(wr @ nt.T, 0.0) * om[:, None]
        self.W = (W / W.sum(axis=0, keepdims=True)).astype(np.float32)     # (n_tex, (Ti-2)^2)
        self._W_dr = upload(np.ascontiguousarray(self.W).ravel(), mi.Float)  # W[r, t] at r * (Ti-2)^2 + t
        self.keys = SparseKeys(self.P * self.n_tex)      # the merges' (probe, texel) keys (.sparse)
        self.device = False          # the device path: merges read nothing back (set by the accumulator)

    # the volume's radiance atlas (device arrays; a Dr.Jit scatter writes into them in place)
    @property
    def value(self):
        return self.volume.device.radiance

    @value.setter
    def value(self, v) -> None:
        self.volume.device.radiance = v

    @property
    def count(self):
        return self.volume.device.radiance_count

    @count.setter
    def count(self, c) -> None:
        self.volume.device.radiance_count = c

    def texel_of(self, w):
        """Interior radiance texel (row-major) that direction ``w`` falls in (the volume's layout)."""
        return self.volume.radiance_texel_of(w)

    def merge(self, results, n_max: int, n_max_lane=None, lazy_cap=None, frame: int = 0) -> None:
        """Bin the front-face hits of ``results`` (a ProbeRayResults) into their texels; Algorithm 3 batch rule,
        on the texels that received samples only (:class:`.sparse.SparseKeys`: the (probe, texel) keys
        compacted and reduced). ``n_max_lane`` (UInt32 per ray, optional): a per-sample N_max; a texel takes
        the smallest of its samples' (and of ``n_max``). ``lazy_cap`` (:class:`.sparse.LazyCountCap` over the
        radiance texel keys): Sec. 4.8's outer count cap on the counts read, the keys stamped with ``frame``."""
        plan = results.plan
        if plan.n_rays == 0 or (not plan.is_masked and len(plan.probe_ids) == 0):
            return
        L = results.radiance
        front = results.distance >= 0.0        # back faces: no radiance sample (as the estimator)
        if plan.valid is not None:             # a masked plan: its invalid lanes are no samples
            front &= plan.valid
        wt = (mi.Float(1.0) if plan.weight is None else plan.weight) + dr.zeros(mi.Float, plan.n_rays)
        key = plan.probe * self.n_tex + self.texel_of(plan.direction)
        ukey, u_ok, sums, sw, cnt, slot = self.keys.reduce(key, [L.x, L.y, L.z], wt, front,
                                                           device=self.device or plan.is_masked)
        U = dr.width(ukey)
        if U == 0:
            return
        if plan.weight is not None:      # a sample of multiplicity m counts as m samples (Algorithm 3)
            cnt = mi.UInt32(dr.round(mi.Float(sw)))
        old = dr.gather(mi.Color3f, self.value, ukey, u_ok)
        n_old = dr.gather(mi.UInt32, self.count, ukey, u_ok)
        if lazy_cap is not None:
            n_old = lazy_cap.count(n_old, ukey, ukey // self.n_tex, u_ok)
        s = mi.Color3f(*[mi.Float(x) for x in sums])
        cap = int(n_max)
        if n_max_lane is not None:
            cap = dr.full(mi.UInt32, int(n_max), U)
            # Local mode: Auto would expand (baking U, which follows the samples, into the kernel)
            dr.scatter_reduce(dr.ReduceOp.Min, cap, mi.UInt32(n_max_lane), slot,
                              front & (wt > 0.0), mode=dr.ReduceMode.Local)
        V, N = batch_update(old, n_old, s, cnt, cap)
        hit = u_ok & (cnt > 0)
        dr.eval(V, N, hit)
        del old, n_old      # no pending read of the layer at the scatters (else they copy it whole first)
        if lazy_cap is not None:
            lazy_cap.touched(ukey, hit, frame)
        dr.scatter(self.value, V, ukey, hit)
        dr.scatter(self.count, N, ukey, hit)
        dr.eval(self.value, self.count)

    def irradiance_estimate(self, probe_ids: np.ndarray) -> TexelEstimate:
        """The convolution pass for ``probe_ids``: :meth:`irradiance_estimate_device` on a GPU backend,
        :meth:`irradiance_estimate_host` (the CPU fast path: the texels are already in host memory, and
        BLAS is about 3x the symbolic loop there; docs/techniques/adgi.md) on the LLVM backend."""
        if is_cpu_backend():
            return self.irradiance_estimate_host(probe_ids)
        return self.irradiance_estimate_device(probe_ids)

    def irradiance_estimate_device(self, probe_ids) -> TexelEstimate:
        """The convolution pass for ``probe_ids`` (host ids, or a device UInt32: ADGI's device path) on the
        device (no host read): a TexelEstimate of their
        interior irradiance texels (E/pi), one lane per (probe, irradiance texel) summing over the radiance
        texels that hold a sample in one symbolic loop (``W`` renormalised over them; an irradiance texel
        with none: ``ok`` False, it keeps its value). Counts: the radiance count of the same texel when
        ``R`` equals the irradiance resolution, else 1. :meth:`irradiance_estimate_host` is the NumPy
        reference."""
        pids = _ids(probe_ids)
        nt = self.W.shape[1]
        n = dr.width(pids) * nt
        lane = dr.arange(mi.UInt32, n)
        ntt = dr.opaque(mi.UInt32, nt)
        slot = lane // ntt
        t = lane - slot * ntt
        base = dr.gather(mi.UInt32, pids, slot) * self.n_tex
        n_tex = self.n_tex

        def cond(r, num, den):
            return r < n_tex

        def body(r, num, den):
            have = dr.gather(mi.UInt32, self.count, base + r) > 0
            w = dr.select(have, dr.gather(mi.Float, self._W_dr, r * nt + t), 0.0)
            v = dr.gather(mi.Color3f, self.value, base + r, have)
            return r + 1, dr.fma(v, w, num), den + w

        _, num, den = dr.while_loop((mi.UInt32(0), dr.zeros(mi.Color3f, n), dr.zeros(mi.Float, n)), cond, body)
        ok = den > 1e-6
        E = dr.select(ok, num / dr.select(ok, den, 1.0), 0.0)
        flat = dr.empty(mi.Float, 3 * n)
        for ci in range(3):
            dr.scatter(flat, E[ci], lane + dr.opaque(mi.UInt32, ci * n))
        if self.R == self.Ti:
            cnt = dr.maximum(dr.gather(mi.UInt32, self.count, base + t), 1)
        else:
            cnt = mi.UInt32(1) + dr.zeros(mi.UInt32, n)
        est = TexelEstimate(flat, cnt, ok, n, 3)
        dr.eval(est.value, est.count, est.ok)
        return est

    def irradiance_estimate_host(self, probe_ids: np.ndarray) -> TexelEstimate:
        """NumPy reference of :meth:`irradiance_estimate` (reads the texels back): a TexelEstimate of their interior irradiance texels (E/pi).
        Counts: the radiance count of the same texel when ``R`` equals the irradiance resolution, else 1."""
        pids = np.asarray(probe_ids, np.uint32)
        Pu = len(pids)
        # only the updated probes' texels come to the host (gathered on the device)
        lane = dr.arange(mi.UInt32, Pu * self.n_tex)
        slot = lane // self.n_tex
        src = dr.gather(mi.UInt32, upload(pids, mi.UInt32), slot) * self.n_tex + (lane - slot * self.n_tex)
        v = dr.gather(mi.Color3f, self.value, src)
        c = dr.gather(mi.UInt32, self.count, src)
        dr.eval(v, c)
        val = vector_to_numpy(v).T.reshape(Pu, self.n_tex, 3)                                # (Pu, n_tex, 3)
        cnt_r = np.asarray(c, np.uint32).reshape(Pu, self.n_tex)
        have = (cnt_r > 0).astype(np.float32)                                               # (Pu, n_tex)
        # texels that never received a sample are left out (the weights renormalised over the others)
        num = np.einsum("prc,rt->cpt", val * have[..., None], self.W, optimize=True)        # (3, Pu, Ti_int)
        den = have @ self.W                                                                  # (Pu, Ti_int)
        ok = den > 1e-6
        E = np.where(ok[None], num / np.where(ok, den, 1.0)[None], 0.0)
        n_t = self.W.shape[1]
        n = len(pids) * n_t
        cnt = cnt_r.ravel() if self.R == self.Ti else np.ones(n, np.uint32)
        cnt = np.maximum(cnt, 1)
        return TexelEstimate(upload(np.ascontiguousarray(E, np.float32).ravel(), mi.Float),
                             upload(cnt.astype(np.uint32), mi.UInt32),
                             upload(ok.ravel().astype(np.uint32), mi.UInt32) != 0, n, 3)
