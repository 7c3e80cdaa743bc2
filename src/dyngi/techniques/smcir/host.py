"""SMC-IR's Algorithm 1 on the host (``smcir:impl=host``, the CPU fast path for small sets): the selection
steps on NumPy arrays with a ``cKDTree`` for the k-NN densities; each iteration reads the candidates back.
A mixin of :class:`~dyngi.techniques.smcir.technique.SMCIR` (the technique's state: ``_host_store``,
``_light_sig``; the line numbers are Algorithm 1's, the sections Hedman et al. 2017's)."""
from __future__ import annotations

import numpy as np

from ...backend import dr, mi
from ...color import luminance
from ...sampling.rng import mix_seed
from ...vpl.density import knn_density, knn_density_device, knn_k
from ...vpl.points import camera_sees, candidates_to_host, raw_candidates_device, segment_clear
from ...vpl.radiosity import RENDER_STREAM, estimate_radiosity, stream_seeds
from ...vpl.smc import clamp_size, grow_invalid, m_min, resample_without_replacement
from ..base import Frame, StageTimer
from .common import _S_CAND, _S_RESAMPLE, _S_SEEDS, _S_VALID, CANDIDATE_K, begin_iteration, lighting_signature, warm_up


class HostAlgorithm1:
    """Lines 3-19 of Algorithm 1 on host arrays (:class:`~dyngi.vpl.store.VPLStore`)."""

    def _rng(self, seed: int, key: int, stream: int) -> np.random.Generator:
        return np.random.default_rng(mix_seed(seed, key, stream))

    def _radiosity(self, pos, nrm, seeds):
        """Radiosity estimates (``radiosity_spp`` paths, ``max_depth - 1`` vertices) with these seeds."""
        return estimate_radiosity(self.scene.mi_scene, pos, nrm, seeds, self.params["radiosity_spp"],
                                  int(self.params["max_depth"]) - 1, self.lights)

    def _candidates(self, frame: Frame, key: int, t: StageTimer):
        """Lines 3, 5-8: X, raw hits, resampled candidates with radiosity, seed and k=1 density."""
        p, I = self.params, self.budget
        n = p["candidate_rate"] * I
        with t.stage("candidates"):
            c = raw_candidates_device(self.scene, frame.camera, frame.res, n, frame.seed, key, _S_CAND)
            dr.eval(c)
        with t.stage("resampling"):
            # line 6's density of the raw hits among themselves, k = 1 (impl='host'): the device grid on the
            # GPU; on the CPU the host k-d tree (faster there; docs/techniques/smcir.md)
            if mi.variant().startswith("cuda"):
                dens = knn_density_device(c["pos"], k=CANDIDATE_K, valid=c["ok"])
                dr.eval(dens)
                cand, pts, rays = candidates_to_host(c, n, {"density": dens})
                p_raw = cand.pop("density")
            else:
                cand, pts, rays = candidates_to_host(c, n)
                p_raw = knn_density(cand["pos"], k=CANDIDATE_K)
            m = len(cand["pos"])
            if m > I:
                with np.errstate(divide="ignore"):
                    wts = np.where(p_raw > 0, 1.0 / np.maximum(p_raw, 1e-300), np.inf)
                sel = resample_without_replacement(wts, I, self._rng(frame.seed, key, _S_RESAMPLE))
                cand = {k: v[sel] for k, v in cand.items()}
            cand.pop("mailbox_albedo", None)
            cand["seed"] = self._rng(frame.seed, key, _S_SEEDS).integers(0, 1 << 62, len(cand["pos"]),
                                                                         dtype=np.uint64)
        t.add_rays("candidates", rays)
        with t.stage("radiosity"):
            cand["radiosity"], r = self._radiosity(cand["pos"], cand["nrm"], cand["seed"])
        t.add_rays("radiosity", r)
        return cand, pts

    def _invalid(self, frame: Frame, key: int, pts, t: StageTimer) -> np.ndarray:
        """Lines 3-4: the used VPLs that cannot be verified as indirectly visible (Sec. 3.2.2)."""
        p, st = self.params, self._host_store
        used = np.flatnonzero(st.used)
        valid = np.zeros(st.capacity, bool)
        rays = 0
        with t.stage("visibility"):
            if len(used):
                seen, r1 = camera_sees(self.scene, frame.camera, frame.res, st.mailbox[used], st.mailbox_n[used])
                ok = np.zeros(len(used), bool)
                if seen.any():
                    s_idx = used[seen]
                    clear, r2 = segment_clear(self.scene, st.mailbox[s_idx], st.mailbox_n[s_idx], st.pos[s_idx],
                                              st.nrm[s_idx])
                    ok[seen] = clear
                    rays += r2
                valid[used[ok]] = True
                rays += r1
                rng = self._rng(frame.seed, key, _S_VALID)
                nx = len(pts["x"])
                for _ in range(p["validation_iterations"]):
                    inv = np.flatnonzero(st.used & ~valid)
                    if len(inv) == 0 or nx == 0 or p["validations"] == 0:
                        break
                    src = rng.choice(nx, size=min(nx, self.budget), replace=False)
                    src = np.repeat(src, p["validations"])
                    tgt = inv[rng.integers(0, len(inv), len(src))]
                    clear, r = segment_clear(self.scene, pts["x"][src], pts["n"][src], st.pos[tgt], st.nrm[tgt])
                    rays += r
                    if clear.any():
                        tg, first = np.unique(tgt[clear], return_index=True)
                        sx = src[clear][first]
                        valid[tg] = True
                        st.mailbox[tg] = pts["x"][sx]
                        st.mailbox_n[tg] = pts["n"][sx]
        t.add_rays("visibility", rays)
        return st.used & ~valid

    def _reestimate(self, frame: Frame, t: StageTimer, new_slots: np.ndarray):
        """Lines 18-19: radiosity (survivors keep theirs while the lighting is static) and density.

        ``reestimate='independent'``: the rendering radiosity comes from stream 1 of each VPL's seed
        (:func:`~dyngi.vpl.radiosity.stream_seeds`), the selection radiosity (``sel_radiosity``, what
        lines 7-16 compare) from stream 0; when the lighting changes both are re-estimated (one kernel,
        twice the lanes of the paper's line 18). ``'same-seed'``: one estimate serves both."""
        st = self._host_store
        sig = lighting_signature(self.scene, frame.time)
        redo = st.used.copy() if sig != self._light_sig else np.zeros(st.capacity, bool)
        redo[new_slots] = False          # new VPLs carry their candidate estimate (same seed, same scene)
        self._light_sig = sig
        idx = np.flatnonzero(redo)
        indep = self.params["reestimate"] == "independent"
        with t.stage("radiosity"):
            if indep:
                # survivors under changed lighting: both streams; new VPLs: the rendering stream only
                new = np.asarray(new_slots, np.int64)
                both = np.concatenate([idx, idx, new])
                seeds = np.concatenate([st.seed[idx], stream_seeds(st.seed[idx], RENDER_STREAM),
                                        stream_seeds(st.seed[new], RENDER_STREAM)])
                if len(both):
                    L, r = self._radiosity(st.pos[both], st.nrm[both], seeds)
                    t.add_rays("radiosity", r)
                    st.sel_radiosity[idx] = L[:len(idx)]
                    st.radiosity[idx] = L[len(idx):2 * len(idx)]
                    st.radiosity[new] = L[2 * len(idx):]
            else:
                if len(idx):
                    st.sel_radiosity[idx], r = self._radiosity(st.pos[idx], st.nrm[idx], st.seed[idx])
                    t.add_rays("radiosity", r)
                st.radiosity[st.used] = st.sel_radiosity[st.used]
        with t.stage("knn"):
            used = np.flatnonzero(st.used)
            k = self.params["density_k"] or knn_k(self.budget, self.params["eq8"])
            st.density[used] = knn_density(st.pos[used], k=k, n_total=len(used))

    def iterate(self, frame: Frame, key: int, t: StageTimer) -> dict:
        """One iteration of Algorithm 1 (lines 3-19) for ``frame``'s camera; returns its counts."""
        p, st = self.params, self._host_store
        cand, invalid = begin_iteration(self, frame, key, t, self._candidates, self._invalid)
        with t.stage("candidates"):
            used = np.flatnonzero(st.used)
            n_c = len(cand["pos"])
            dens = knn_density(st.pos[used], cand["pos"], k=CANDIDATE_K, n_total=max(len(used), 1)) if len(used) else \
                np.zeros(n_c)
            lum = luminance(cand["radiosity"])
            with np.errstate(divide="ignore", invalid="ignore"):
                c_int = np.where(dens > 0, lum / np.maximum(dens, 1e-300), np.where(lum > 0, np.inf, 0.0))
            cur_int = st.intensity()
            mm = m_min(cur_int[used], c_int, p["max_moves"], p["quantile"])
            n_invalid = int(invalid.sum())
            invalid = grow_invalid(invalid, st.used, cur_int, mm)
            removed = clamp_size(invalid, cur_int, p["max_moves"])
            st.clear(removed)
            free = np.flatnonzero(~st.used)
            order = np.argsort(-c_int, kind="stable")[: len(free)]
            slots = free[: len(order)]
            if len(slots):
                st.put(slots, pos=cand["pos"][order], nrm=cand["nrm"][order], albedo=cand["albedo"][order],
                       sel_radiosity=cand["radiosity"][order], radiosity=cand["radiosity"][order],
                       mailbox=cand["mailbox"][order], mailbox_n=cand["mailbox_n"][order], seed=cand["seed"][order])
        self._reestimate(frame, t, slots)
        return {"invalid": n_invalid, "m_min": mm, "replaced": int(len(slots)), "candidates": n_c}


    def _update_vpls_host(self, frame: Frame, t: StageTimer):
        p = self.params
        st = self._host_store
        if st.count == 0:
            warm_up(frame, t, p["warmup"], self.iterate)     # INITIALIZEVPLS (Sec. 3.2)
        info = self.iterate(frame, frame.index, t)
        flux = st.flux(max(st.count, 1))
        info.update({"vpls_used": st.count, "vpl_budget": self.budget})
        self.last_stats = info
        return st.pos, st.nrm, flux, info

