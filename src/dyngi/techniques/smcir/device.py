"""SMC-IR's Algorithm 1 on the device (``smcir:impl=device``, the default): the VPL set in Dr.Jit arrays
(:class:`~dyngi.vpl.smc_device.DeviceVPLStore`), every step at a fixed width, no host read in an
iteration, nothing compiled in a steady frame. A mixin of
:class:`~dyngi.techniques.smcir.technique.SMCIR` (the technique's state: ``_dev``, ``_light_sig``,
``_filled``; the line numbers are Algorithm 1's, the sections Hedman et al. 2017's)."""
from __future__ import annotations

from ...backend import dr, mi
from ...color import luminance
from ...sampling.rng import make_sampler, mix_seed
from ...vpl.density import MIN_RADIUS, KNNGrid, knn_density_device, knn_k
from ...vpl.points import raw_candidates_device
from ...vpl.radiosity import RENDER_STREAM, estimate_radiosity_device
from ...vpl.smc import resample_with_replacement_device
from ...vpl.smc_device import (camera_sees_device, quantile_device, ranks, sample_without_replacement_device,
                               segment_clear_device, stream_seeds_device)
from ..base import Frame, StageTimer
from .common import _S_CAND, _S_RESAMPLE, _S_SEEDS, _S_VALID, CANDIDATE_K, begin_iteration, lighting_signature, warm_up


class DeviceAlgorithm1:
    """Lines 3-19 of Algorithm 1 on the device."""

    def _radiosity_device(self, pos, nrm, seeds, active):
        """:meth:`_radiosity` on Dr.Jit arrays: (Color3f, rays)."""
        return estimate_radiosity_device(self.scene.mi_scene, pos, nrm, seeds, self.params["radiosity_spp"],
                                         int(self.params["max_depth"]) - 1, active, self.lights)

    def _candidates_device(self, frame: Frame, key: int, t: StageTimer):
        """Lines 3, 5-8 on the device: raw hits (16 I lanes, none dropped), line 6's k = 1 density among
        the valid ones (:class:`~dyngi.vpl.density.KNNGrid`), I drawn without replacement with weights
        1 / p, per-candidate 62-bit seeds and their stream-0 radiosity. Returns (candidate dict over I
        lanes with an ``ok`` mask, the raw dict: its ``mailbox``/``okx`` lanes are the points X)."""
        p, I = self.params, self.budget
        n = p["candidate_rate"] * I
        with t.stage("candidates"):
            c = raw_candidates_device(self.scene, frame.camera, frame.res, n, frame.seed, key, _S_CAND)
            dr.eval(c)
        t.add_rays("candidates", n + dr.count(c["okx"]))
        with t.stage("resampling"):
            dens = knn_density_device(c["pos"], k=CANDIDATE_K, valid=c["ok"])
            w = dr.select(c["ok"], dr.select(dens > 0.0, 1.0 / dens, dr.inf), 0.0)
            u = make_sampler(n, frame.seed, key, _S_RESAMPLE).next_1d()
            sel, ok = sample_without_replacement_device(w, u, I)
            cand = {k: dr.gather(type(c[k]), c[k], sel) for k in ("pos", "nrm", "albedo", "mailbox", "mailbox_n")}
            cand["ok"] = ok & dr.gather(mi.Bool, c["ok"], sel)
            rng = mi.PCG32(size=I, initstate=mi.UInt64(dr.opaque(mi.UInt32, mix_seed(frame.seed, key, _S_SEEDS))))
            cand["seed"] = rng.next_uint64() >> 2
            dr.eval(cand)
        with t.stage("radiosity"):
            cand["radiosity"], r = self._radiosity_device(cand["pos"], cand["nrm"], cand["seed"], cand["ok"])
            dr.eval(cand["radiosity"])
        t.add_rays("radiosity", r)
        return cand, c

    def _invalid_device(self, frame: Frame, key: int, c: dict, t: StageTimer):
        """Lines 3-4 on the device (Sec. 3.2.2): a used VPL is valid if the camera sees its mailbox and the
        mailbox sees it; then ``validation_iterations`` rounds in which I points of X (drawn uniformly
        among the valid x, with replacement: our choice) each try V random invalid VPLs (uniform among
        the invalid ones); a clear segment validates the VPL and the lowest such lane's x becomes its
        mailbox. Returns the INVALID mask (Bool over the slots)."""
        p, st, I = self.params, self._dev, self.budget
        ms = self.scene.mi_scene
        with t.stage("visibility"):
            seen = camera_sees_device(ms, frame.camera, frame.res, st.mailbox, st.mailbox_n, st.used)
            valid = segment_clear_device(ms, st.mailbox, st.mailbox_n, st.pos, st.nrm, seen)
            dr.eval(valid)
            rays = dr.count(st.used) + dr.count(seen)
            V, n_it = int(p["validations"]), int(p["validation_iterations"]) if p["validations"] else 0
            X, NX, okx = mi.Point3f(c["mailbox"]), mi.Vector3f(c["mailbox_n"]), c["okx"]
            for it in range(n_it):
                inv = st.used & ~valid
                sm = make_sampler(I * V, frame.seed, key, _S_VALID + 0x100 * (it + 1))
                src = resample_with_replacement_device(mi.Float(okx), make_sampler(I, frame.seed, key,
                                                                                   _S_VALID + it).next_1d())
                src = dr.gather(mi.UInt32, src, dr.arange(mi.UInt32, I * V) // V)
                tgt = resample_with_replacement_device(mi.Float(inv), sm.next_1d())
                act = dr.gather(mi.Bool, inv, tgt) & dr.gather(mi.Bool, okx, src)
                xs, xn = dr.gather(mi.Point3f, X, src), dr.gather(mi.Vector3f, NX, src)
                clear = segment_clear_device(ms, xs, xn, dr.gather(mi.Point3f, st.pos, tgt),
                                             dr.gather(mi.Vector3f, st.nrm, tgt), act)
                rays = rays + dr.count(act)
                win = dr.full(mi.UInt32, 0xFFFFFFFF, I)
                dr.scatter_reduce(dr.ReduceOp.Min, win, dr.arange(mi.UInt32, I * V), tgt, clear)
                got = win != 0xFFFFFFFF
                wsrc = dr.gather(mi.UInt32, src, win, got)
                valid |= got
                st.mailbox = dr.select(got, dr.gather(mi.Point3f, X, wsrc, got), st.mailbox)
                st.mailbox_n = dr.select(got, dr.gather(mi.Vector3f, NX, wsrc, got), st.mailbox_n)
                dr.eval(valid, st.mailbox, st.mailbox_n)
        t.add_rays("visibility", rays)
        return st.used & ~valid

    def _new_width(self) -> int:
        """Slots filled per iteration at most: I for the first fill, then ``max(M_max, 16)`` (our choice:
        after the fill at most M_max slots are freed per iteration, so this only delays refilling slots
        that an earlier iteration found no valid candidate for; it bounds line 18's width)."""
        return self.budget if not self._filled else min(self.budget, max(int(self.params["max_moves"]), 16))

    def _reestimate_device(self, frame: Frame, t: StageTimer, new, rank_new):
        """Lines 18-19 on the device (as :meth:`_reestimate`; ``new``: the slots filled this iteration,
        ``rank_new`` their order). While the lighting signature is unchanged only the new VPLs' rendering
        stream is traced (gathered into :meth:`_new_width` lanes); when it changes, both streams of every
        VPL (2 I lanes)."""
        st, I = self._dev, self.budget
        sig = lighting_signature(self.scene, frame.time)
        changed = sig != self._light_sig
        self._light_sig = sig
        indep = self.params["reestimate"] == "independent"
        redo = st.used & ~new
        with t.stage("radiosity"):
            if indep and changed:
                j = dr.arange(mi.UInt32, 2 * I)
                lo = j < I
                v = dr.select(lo, j, j - I)
                seeds = dr.gather(mi.UInt64, st.seed, v)
                seeds = dr.select(lo, seeds, stream_seeds_device(seeds, RENDER_STREAM))
                act = dr.gather(mi.Bool, redo, v) | (~lo & dr.gather(mi.Bool, new, v))
                L, r = self._radiosity_device(dr.gather(mi.Point3f, st.pos, v), dr.gather(mi.Vector3f, st.nrm, v),
                                              seeds, act)
                i = dr.arange(mi.UInt32, I)
                st.sel_radiosity = dr.select(redo, dr.gather(mi.Color3f, L, i), st.sel_radiosity)
                st.radiosity = dr.select(redo | new, dr.gather(mi.Color3f, L, i + I), st.radiosity)
                t.add_rays("radiosity", r)
            elif indep:
                W = self._new_width()
                slot = dr.zeros(mi.UInt32, W)
                take = dr.zeros(mi.Bool, W)
                dr.scatter(slot, dr.arange(mi.UInt32, I), rank_new, new)
                dr.scatter(take, mi.Bool(True), rank_new, new)
                L, r = self._radiosity_device(dr.gather(mi.Point3f, st.pos, slot), dr.gather(mi.Vector3f, st.nrm, slot),
                                              stream_seeds_device(dr.gather(mi.UInt64, st.seed, slot), RENDER_STREAM),
                                              take)
                back = dr.gather(mi.Color3f, L, rank_new, new)
                st.radiosity = dr.select(new, back, st.radiosity)
                t.add_rays("radiosity", r)
            else:
                if changed:
                    L, r = self._radiosity_device(st.pos, st.nrm, st.seed, redo)
                    st.sel_radiosity = dr.select(redo, L, st.sel_radiosity)
                    t.add_rays("radiosity", r)
                st.radiosity = dr.select(st.used, st.sel_radiosity, 0.0)
            dr.eval(st.radiosity, st.sel_radiosity)
        with t.stage("knn"):
            k = self.params["density_k"] or knn_k(self.budget, self.params["eq8"])
            d = knn_density_device(st.pos, k=k, valid=st.used)
            st.density = dr.select(st.used, d, 1.0)
            dr.eval(st.density)

    def iterate_device(self, frame: Frame, key: int, t: StageTimer) -> dict:
        """One iteration of Algorithm 1 (lines 3-19) on the device; its counts are width-1 device arrays
        (read by the caller after the image)."""
        p, st, I = self.params, self._dev, self.budget
        cand, invalid = begin_iteration(self, frame, key, t, self._candidates_device, self._invalid_device)
        with t.stage("candidates"):
            # -- line 8: candidate densities (k = 1) against the current VPLs; Eq. 6 intensities --
            n_used = dr.count(st.used)
            grid = KNNGrid(st.pos, st.used)
            r = dr.maximum(grid.kth_distance(cand["pos"], CANDIDATE_K), MIN_RADIUS)
            dens = dr.select(dr.isfinite(r), CANDIDATE_K / (dr.maximum(mi.Float(n_used), 1.0) * dr.pi * r * r), 0.0)
            lum = luminance(cand["radiosity"])
            c_int = dr.select(dens > 0.0, lum / dr.maximum(dens, 1e-30), dr.select(lum > 0.0, dr.inf, 0.0))
            cur = dr.select(st.used, luminance(st.sel_radiosity) / dr.maximum(st.density, 1e-30), 0.0)
            # -- line 9, Eq. 9: M_min = min(M_max, M_strong) --
            q = quantile_device(cur, st.used, p["quantile"])
            n_cand = dr.count(cand["ok"])
            strong = dr.select(n_used > 0, dr.count(cand["ok"] & (c_int > q)), n_cand)
            mm = dr.minimum(strong, int(p["max_moves"]))
            n_invalid = dr.count(invalid)
            # -- lines 10-12: the lowest-intensity valid VPLs join INVALID until it holds M_min --
            need = mi.Int32(mm) - mi.Int32(n_invalid)
            ok_v = st.used & ~invalid
            rk = ranks(dr.select(ok_v, cur, dr.inf))
            invalid |= ok_v & (mi.Int32(rk) < need)
            # -- line 13: CLAMPSIZE(INVALID, M_max), the lowest intensities first --
            removed = invalid & (ranks(dr.select(invalid, cur, dr.inf)) < int(p["max_moves"]))
            st.used &= ~removed
            st.radiosity = dr.select(removed, 0.0, st.radiosity)
            st.sel_radiosity = dr.select(removed, 0.0, st.sel_radiosity)
            # -- lines 14-16: free slots take the highest-intensity candidates --
            free = ~st.used
            rf = dr.prefix_sum(mi.UInt32(free))
            corder = dr.argsort(dr.select(cand["ok"], c_int, -dr.inf), descending=True)
            new = free & (rf < n_cand) & (rf < self._new_width())
            src = dr.gather(mi.UInt32, corder, rf, new)
            for k in ("pos", "nrm", "albedo", "mailbox", "mailbox_n"):
                setattr(st, k, dr.select(new, dr.gather(type(cand[k]), cand[k], src, new), getattr(st, k)))
            L = dr.gather(mi.Color3f, cand["radiosity"], src, new)
            st.sel_radiosity = dr.select(new, L, st.sel_radiosity)
            st.radiosity = dr.select(new, L, st.radiosity)
            st.seed = dr.select(new, dr.gather(mi.UInt64, cand["seed"], src, new), st.seed)
            st.used |= new
            replaced = dr.count(new)
            st.eval()
        self._reestimate_device(frame, t, new, rf)
        self._filled = True
        st.eval()
        return {"invalid": n_invalid, "m_min": mm, "replaced": replaced, "candidates": n_cand}

    def _update_vpls_device(self, frame: Frame, t: StageTimer):
        p = self.params
        if not self._initialised:
            warm_up(frame, t, p["warmup"], self.iterate_device)     # INITIALIZEVPLS (Sec. 3.2)
            self._initialised = True
        info = self.iterate_device(frame, frame.index, t)
        st = self._dev
        n_used = dr.count(st.used)
        flux = dr.select(st.used, st.radiosity / (dr.maximum(mi.Float(n_used), 1.0)
                                                  * dr.maximum(st.density, 1e-30)), 0.0)
        dr.eval(flux, n_used)
        info.update({"vpls_used": n_used, "vpl_budget": self.budget})
        self.last_stats = info
        return st.pos, st.nrm, flux, info

