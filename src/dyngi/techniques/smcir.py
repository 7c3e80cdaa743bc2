"""Sequential Monte Carlo instant radiosity (Hedman, Karras, Lehtinen, TVCG 2017): technique ``smcir``.

Keeps a temporally coherent set of I VPLs on the surfaces indirectly visible to
the camera, distributed toward uniform intensity I(y) = L(y) / p(y) (Eq. 4, 6),
and replaces at most ``M_max`` of them per frame. Algorithm 1, per frame:

1. X: camera rays through random pixel positions (``candidate_rate * I`` of them);
2. INVALID: VPLs whose mailbox point (Sec. 3.2.2) the camera no longer sees (in the
   frustum, unoccluded, facing) or that no longer see it; then ``validation_iterations``
   (2) rounds in which up to I points of X each cast rays to V (16) random invalid
   VPLs: a clear, mutually facing segment validates the VPL and becomes its mailbox;
3. candidates: one cosine ray from each point of X (16 I raw hits), their kNN density
   among themselves (Eq. 7 with k = 1, Sec. 3.2.4: lines 6 and 8 use k = 1), I drawn by weighted
   resampling without replacement toward uniform area density (weights 1 / p, Sec. 3.2.1);
4. candidate radiosities (``radiosity_spp`` = 16 paths with NEE, per-candidate seed,
   Sec. 3.2.3) and densities (k = 1 against the current VPLs, Sec. 3.2.4);
5. M_min = min(M_max, M_strong) (Eq. 9, 95% rule); the lowest-intensity valid VPLs join
   INVALID until it holds M_min; CLAMPSIZE(INVALID, M_max) are removed (the lowest
   intensities first: our choice) and the free slots take the highest-intensity candidates;
6. radiosity (per-VPL seeds) and density (k of Eq. 8 among the VPLs) of all VPLs
   re-estimated (lines 18-19); render (:mod:`dyngi.techniques.vpl_base`).

Line 18, independent re-estimate (our reading, ``reestimate='independent'``, the default): the
selection (lines 7-16) compares each VPL's estimate from stream 0 of its seed (``sel_radiosity``);
the radiosity used for rendering is a *second* estimate from stream 1 of the same seed
(:func:`dyngi.vpl.radiosity.stream_seeds`). Sec. 3.2.3 asks that "the path tracer generates similar
paths for the same VPL throughout the lifetime of the VPL" (no flicker): both streams are fixed per
VPL, so that holds; and Sec. 3.1 says Eq. 5 is unbiased "given unbiased estimates for the radiosities",
which an estimate that was *selected* for being large is not (replacement keeps the highest candidate
intensities and drops the lowest VPLs, a winner's curse). The paper's text does not say whether line 18
re-uses the selection's random numbers; "the intensities are reestimated for the remaining VPLs"
(Sec. 3.2) reads as a fresh estimate. Cost: the <= M_max new VPLs get one extra 16-path estimate per
frame; when the lighting changes, line 18 traces both streams (2x its rays; the paper's cost:
``reestimate='same-seed'``, one estimate for both, the pre-fix behaviour). Tested by a synthetic
winner's curse (tests/techniques/test_smcir_reestimate.py).

Where it runs (``impl``): ``'device'`` (the default) keeps the VPL set in Dr.Jit arrays
(:class:`dyngi.vpl.smc_device.DeviceVPLStore`) and runs lines 3-19 with fixed widths -- the k-NN
densities on the device grid (:class:`dyngi.vpl.density.KNNGrid`), the resampling of line 6 by
Efraimidis-Spirakis keys and a device sort, visibility as masked shadow rays, Eq. 9's quantile and the
"lowest/highest intensity first" choices by stable sorts, the counts as device values read after the
image: an iteration (also each warm-up one) reads nothing back and a steady frame compiles nothing
(tests/techniques/test_smcir_device.py). ``'host'`` runs the same steps on NumPy arrays with a
``cKDTree`` (the CPU fast path: small sets; each iteration reads the candidates back). The two draw
different random numbers (the host one from NumPy generators), so their VPL sets differ; the radiosity
of a VPL of a given seed is bit-identical in both (:func:`dyngi.vpl.radiosity.estimate_radiosity` is
the host form of the device estimate). Random validation on the device draws its points of X with
replacement (uniform among the valid x; our choice), the host one without; after the first fill the
device fills at most ``max(M_max, 16)`` free slots per iteration (our choice: a fixed width for line 18's
new-VPL estimate; it differs from the host only when an earlier iteration left slots empty).

Initialisation: the first I candidates, then ``warmup`` (100) iterations before the first
frame (Sec. 3.2). Radiosity paths have ``max_depth - 1`` vertices from the VPL: with the
default ``max_depth = 5`` three bounces of indirect light in all (Sec. 5).

Exactness note (ours): a VPL's radiosity depends only on its seed and the lights and
geometry, so while those do not move (the scene's animators' signature is unchanged)
surviving VPLs keep their previous estimate instead of re-tracing it -- bit-identical to
re-estimating (tested), at a fraction of the cost of line 18.

Parameters (besides the common ones of :mod:`~dyngi.techniques.vpl_base`)
-------------------------------------------------------------------------
max_moves : int = 16            M_max, VPLs replaced per frame at most (Sec. 3.2)
candidate_rate : int = 16       raw hits per candidate (16:1 resampling, Sec. 3.2.1)
validations : int = 16          V, invalid VPLs each point tries per round (Sec. 3.2.2)
validation_iterations : int = 2 rounds of random validation (Sec. 3.2.2)
radiosity_spp : int = 16        paths per VPL radiosity estimate (Sec. 3.2.3)
warmup : int = 100              iterations before the first frame (Sec. 3.2)
quantile : float = 0.95         the M_strong threshold of Eq. 9
density_k : int = 0             k of the rendering density (line 19); 0: Eq. 8 (k = 1 for I <= 4095)
reestimate : str = 'independent' line 18's rendering radiosity: stream 1 of the VPL's seed, or
                                'same-seed' (the selection's own estimate)
impl : str = 'device'           'device' (Dr.Jit, no host round trip) or 'host' (NumPy + k-d tree)
lights : str = 'scene'          light sampler of the radiosity paths' NEE (:mod:`~dyngi.techniques.vpl_base`)

Bias (Sec. 3.3): kNN densities make the estimate biased but consistent; clamping removes
near-field interreflections; ray-traced visibility replaces the paper's shadow maps. Measured
(exhaustive shading, 2048 VPLs, mean indirect / the clamped path-tracing reference of
:mod:`dyngi.experiments.clamped_reference` with the same clamp, 1024 spp; mean of 3 seeds; with
``impl='host'``, the same estimator as the device one with other random numbers -- the default's
bound, tests/techniques/test_smcir_bias.py, runs the device one):

=====================================  ==========================  ==========================
variant                                cornell-static 48x36, 100   corridor-walk f0 48x27, 30
                                       warm-up iterations          warm-up iterations
=====================================  ==========================  ==========================
``reestimate=same-seed`` (before)      1.45                        1.56
defaults (independent re-estimate)     1.42                        1.34
defaults, ``density_k=16``             1.08                        0.98
defaults, ``radiosity_spp=256``        1.39                        1.24
no replacements (warmup=0, M_max=0)    1.03                        1.12
mir / ir (same clamp)                  1.00 / 0.99                 0.99 / 0.83
=====================================  ==========================  ==========================

What remains is Eq. 8's k = 1 for the rendering density (line 19): once the replacements (whose
candidate density is k = 1 against the current VPLs, Sec. 3.2.4, "encourages blue-noise properties")
have made the VPL set blue-noise-like, nearest-neighbour areas ``pi r_1^2`` exceed each VPL's true
share of the surface (for a Poisson set E[pi r_1^2 I p] = 1 exactly; for a hexagonal packing it is
2 pi / sqrt(3) = 3.6), so 1/p and the indirect light are over-estimated by ~1.3-1.4x. The default
stays Eq. 8 (the paper's k = max(1, floor(sqrt(I)/32)) = 1 for I = 2048 and 512); ``density_k=16``
removes most of it (also run by ``dyngi reproduce smcir``).
"""
from __future__ import annotations

import numpy as np

from ..sampling.rng import make_sampler, mix_seed
from ..backend import dr, mi
from ..color import luminance
from ..vpl.density import MIN_RADIUS, KNNGrid, knn_density, knn_density_device, knn_k
from ..vpl.points import camera_sees, candidates_to_host, raw_candidates_device, segment_clear
from ..vpl.radiosity import RENDER_STREAM, estimate_radiosity, stream_seeds
from ..vpl.smc import clamp_size, grow_invalid, m_min, resample_with_replacement_device, resample_without_replacement
from ..vpl.smc_device import (DeviceVPLStore, camera_sees_device, estimate_radiosity_device,
                              quantile_device, ranks, sample_without_replacement_device, segment_clear_device,
                              stream_seeds_device)
from ..vpl.store import VPLStore
from .base import Frame, Param, StageTimer, register
from .vpl_base import COMMON_PARAMS, VPLTechnique

_S_CAND, _S_RESAMPLE, _S_SEEDS, _S_VALID = 0x5C1, 0x5C2, 0x5C3, 0x5C4
REESTIMATE_MODES = ("independent", "same-seed")
IMPLS = ("device", "host")
CANDIDATE_K = 1
"""k of the candidates' densities, lines 6 and 8 (Sec. 3.2.4: "For candidates ... We set k=1"): the raw
hits' density among themselves for the resampling of line 6, and against the current VPLs for line 8."""
WARMUP_FRAME_BASE = 1 << 30
"""Frame keys of the warm-up iterations' random streams (beyond any real frame index)."""


def lighting_signature(scene, t: float) -> tuple:
    """Signature of what a VPL's radiosity depends on: the animated lights and shapes (not the camera)."""
    return tuple(a.signature(t) for a in getattr(scene, "animators", []))


@register
class SMCIR(VPLTechnique):
    name = "smcir"
    description = "SMC instant radiosity (Hedman et al. 2017): temporally coherent VPLs, <= 16 moved per frame"
    PARAMS = {
        **COMMON_PARAMS,
        "max_moves": Param(16, "M_max: VPLs replaced per frame at most", min=0, max=1 << 16),
        "candidate_rate": Param(16, "raw hits per candidate (16:1 resampling)", min=1, max=256),
        "validations": Param(16, "V: random invalid VPLs tried per point and round", min=0, max=256),
        "validation_iterations": Param(2, "rounds of random mailbox validation", min=0, max=8),
        "radiosity_spp": Param(16, "paths per VPL radiosity estimate", min=1, max=4096),
        "warmup": Param(100, "algorithm iterations before the first frame", min=0, max=10000),
        "density_k": Param(0, "k of the rendering density (Eq. 7); 0: Eq. 8, max(1, floor(sqrt(I)/32))",
                           min=0, max=256),
        "reestimate": Param("independent", "line 18's radiosity for rendering: a second per-VPL seed stream, "
                            "independent of the estimate selection saw, or the same seed (no second estimate)",
                            choices=REESTIMATE_MODES),
        "impl": Param("device", "where Algorithm 1 runs: 'device' (Dr.Jit arrays, no host round trip) or 'host' "
                      "(NumPy selection steps, a k-d tree: the CPU fast path)", choices=IMPLS),
        "quantile": Param(0.95, "M_strong threshold: candidates above this quantile of the VPL intensities",
                          min=0.0, max=1.0),
    }


    def __init__(self, scene, params=None):
        super().__init__(scene, params)
        self._host_store = VPLStore(self.budget)
        self._dev = DeviceVPLStore(self.budget) if self.params["impl"] == "device" else None
        self._light_sig = None
        self._initialised = False
        self._filled = False      # the device store's first fill (INITIALIZEVPLs) is done
        self.last_stats: dict = {}

    @property
    def store(self) -> VPLStore:
        """The VPL set as host arrays (``impl='device'``: a copy read back, for inspection and tests)."""
        return self._dev.to_host() if self._dev is not None else self._host_store

    # -- helpers -------------------------------------------------------------------------------
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
            # GPU; on the CPU the host k-d tree (faster there; docs/benchmarks.md)
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
            k = self.params["density_k"] or knn_k(self.budget)
            st.density[used] = knn_density(st.pos[used], k=k, n_total=len(used))

    def iterate(self, frame: Frame, key: int, t: StageTimer) -> dict:
        """One iteration of Algorithm 1 (lines 3-19) for ``frame``'s camera; returns its counts."""
        p, st = self.params, self._host_store
        cand, pts = self._candidates(frame, key, t)
        # candidate radiosities were traced with the lighting of this frame; survivors' follow in _reestimate
        if self._light_sig != lighting_signature(self.scene, frame.time):
            self._light_sig = None
        invalid = self._invalid(frame, key, pts, t)
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

    # -- Algorithm 1 on the device (impl='device') ------------------------------------------------
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
            k = self.params["density_k"] or knn_k(self.budget)
            d = knn_density_device(st.pos, k=k, valid=st.used)
            st.density = dr.select(st.used, d, 1.0)
            dr.eval(st.density)

    def iterate_device(self, frame: Frame, key: int, t: StageTimer) -> dict:
        """One iteration of Algorithm 1 (lines 3-19) on the device; its counts are width-1 device arrays
        (read by the caller after the image)."""
        p, st, I = self.params, self._dev, self.budget
        cand, c = self._candidates_device(frame, key, t)
        if self._light_sig != lighting_signature(self.scene, frame.time):
            self._light_sig = None
        invalid = self._invalid_device(frame, key, c, t)
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

    def update_vpls(self, frame: Frame, t: StageTimer):
        if self._dev is None:
            return self._update_vpls_host(frame, t)
        p = self.params
        if not self._initialised:
            # INITIALIZEVPLs: candidates fill the budget, then the warm-up iterations (Sec. 3.2)
            with t.stage("warmup"):
                wt = StageTimer()
                for i in range(p["warmup"] + 1):
                    self.iterate_device(frame, WARMUP_FRAME_BASE + i, wt)
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

    def _update_vpls_host(self, frame: Frame, t: StageTimer):
        p = self.params
        info = {}
        st = self._host_store
        if st.count == 0:
            # INITIALIZEVPLs: candidates fill the budget, then the warm-up iterations (Sec. 3.2)
            with t.stage("warmup"):
                wt = StageTimer()
                self.iterate(frame, WARMUP_FRAME_BASE, wt)
                for i in range(p["warmup"]):
                    self.iterate(frame, WARMUP_FRAME_BASE + 1 + i, wt)
        info = self.iterate(frame, frame.index, t)
        flux = st.flux(max(st.count, 1))
        info.update({"vpls_used": st.count, "vpl_budget": self.budget})
        self.last_stats = info
        return st.pos, st.nrm, flux, info
