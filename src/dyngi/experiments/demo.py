"""``dyngi demo``: a short tour of the five papers, one section per paper on its own analog scene.

Each section runs one comparison (:func:`~dyngi.experiments.compare.prepare` /
:func:`~dyngi.experiments.compare.execute`, the report of
:func:`~dyngi.experiments.report.write_outputs` in a sub-folder) of the paper's technique against the
baseline the paper compares with, and states the paper's claim beside the figure measured in this run:

========================  ==========================================  =====================================
section                   techniques                                  analog scene
========================  ==========================================  =====================================
``adgi``                  ``adgi`` vs ``qddgi``                       ``tunnel-gate`` (the gate opens)
``isddgi``                ``isddgi`` vs ``ddgi``                      ``corridor-rooms`` (lights switch)
``ddgi-resampling``       ``ddgi-resampling``, ``ddgi-secondary``,    ``cornell-static`` (static interior)
                          ``restir-pt`` (PT+ReSTIR)
``smcir``                 ``smcir`` vs ``ir``                         ``street-canyon-moving-sun``
``vlc``                   ``nee-pt:lights=vlc`` vs ``lights=sll``,    ``storage-cells`` (512 lights)
                          ``lights=lighttree`` (and the oracle)
``cdq``                   ``nee-pt:directions=cdq`` vs ``=bsdf``      ``sky-pit-sun-disc`` (sunlit pit)
========================  ==========================================  =====================================

The frames of a section span its scene's event (:attr:`Section.span`: the gate opening, the lights
switching, the sun moving) rather than the first fractions of a second at the scene's 30 fps; the
static protocols (DDGI Resampling's accumulation, CDQ's learning of the sun) hold the scene at t = 0.
One ``report.html`` at the top level gives, per section, the claim, our figure, the verdict words of the
paper's claims it touches -- computed from three seeds by the reproductions' own declarations
(:mod:`dyngi.experiments.claims`, :func:`decide_section`), ``undecided`` where the tour's scale cannot
decide and why --, the image grid of the last frame (technique, reference, FLIP map), the error plot and a
link to the section's full report; ``summary.json`` holds the figures, the claims with their rows and
seeds, the commit, and every technique's failure status (the command line's NaN/Inf check reads it).

Sizes (:data:`SIZES`): ``tour`` (the default: 96x54, 8 frames, 64-spp references; the VLC and CDQ sections at
twice the resolution (the paper's octree thresholds), CDQ's with five times the frames, the VLC's reference at
64x the spp; the figures are small-sample readings of one run, the reproductions
``dyngi reproduce NAME`` are the measurements) and ``quick`` (32x18, 2 frames, 4 spp: the tour's
structure, for tests; its figures are noise). References are cached (``~/.cache/dyngi``), so a second
run only renders the techniques; how long the tour takes is in docs/harness.md ("The demo tour").
"""
from __future__ import annotations

import dataclasses
import html
import json
import os
import sys
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .. import backend
from ..errors import DyngiError
from ..scene import load_scene
from .compare import execute, prepare
from .io import atomic_output_dir, check_writable, write_json
from .report import data_uri, write_outputs
from .claims import claim_rows, claims_json, result_from_values
from .reproductions import adgi, cdq, ddgi_resampling, isddgi, smcir, vlc
from .reproductions.isddgi import UPDATE_STAGES

METRICS = ["mse", "relmse", "mape", "flip", "ssim"]


@dataclass(frozen=True)
class Size:
    res: tuple[int, int]
    frames: int
    ref_spp: int


SIZES = {"tour": Size((96, 54), 8, 64), "quick": Size((32, 18), 2, 4)}
"""``tour``: the demo's default; ``quick``: the test size (structure only, the figures are noise)."""


@dataclass(frozen=True)
class Section:
    """One paper's section of the tour.

    ``claims(section, res, frames)``: the paper's claims this section decides, the reproduction's own
    declarations (:mod:`dyngi.experiments.claims`) at the tour's scale; ``value(claim, rs, label)``: a row's
    value of a claim's metric in :func:`~dyngi.experiments.compare.execute`'s result (None: not reached).
    The verdict words are computed over :data:`SEEDS` (nothing in the tour writes one by hand); at the
    tour's scale most claims are ``undecided`` and say why. ``res_scale``: the section runs at this multiple
    of the tour's resolution (the VLC's and CDQ's claims need the paper's records per octree leaf), ``frames_scale``
    of its frames, ``ref_spp_scale`` of its reference samples. ``span``: seconds of scene time
    the frames cover, first frame at ``start`` and last at ``start + span`` (0: the scene held at
    ``start``, a static protocol). ``measure(rs, section)`` returns ``{'text': our figure, 'values'}`` from
    the first seed's result.
    """
    key: str
    title: str
    paper: str
    scene: str
    specs: tuple[str, ...]
    claim: str
    measure: Callable
    span: float = 0.0
    start: float = 0.0
    indirect: bool = False
    ref_depth: int | None = None
    note: str = ""
    view: tuple[str, ...] = field(default=())
    claims: Callable | None = None
    value: Callable | None = None
    res_scale: int = 1
    frames_scale: int = 1
    ref_spp_scale: int = 1

    def res(self, size: "Size") -> tuple[int, int]:
        """This section's image size: the tour's times :attr:`res_scale`."""
        return (size.res[0] * self.res_scale, size.res[1] * self.res_scale)

    def frames(self, size: "Size") -> int:
        """This section's frame count: the tour's times :attr:`frames_scale` (CDQ learns over tens of frames)."""
        return size.frames * self.frames_scale

    def ref_spp(self, size: "Size") -> int:
        """This section's reference spp: the tour's times :attr:`ref_spp_scale` (``storage-cells``: Mitsuba samples
        its 512 lights by power and about 1 in 100 of its NEE samples is unoccluded, so its reference needs ~64x
        the spp for its own noise to stay a few per cent of the oracle's 1-spp MSE)."""
        return size.ref_spp * self.ref_spp_scale

    @property
    def view_command(self) -> str:
        return f"dyngi view {self.scene} --techniques {','.join(self.view or self.specs[:2])}"


# -- what each section measures ------------------------------------------------------------------

def _frames_from(rs, label: str, metric: str, t_from: float = -1.0, first: int = 0) -> np.ndarray:
    """Per-frame ``metric`` of ``label`` for frames at scene time >= ``t_from`` and index >= ``first``."""
    v = [r[metric] for r in rs["rows"] if r["technique"] == label and r["time"] >= t_from - 1e-9
         and r["frame"] >= first]
    return np.asarray(v, np.float64)


def _mean(x) -> float:
    x = np.asarray(x, np.float64)
    return float(np.mean(x)) if x.size else float("nan")


def _ratio(a: float, b: float) -> float:
    return a / b if b > 0 and np.isfinite(a) and np.isfinite(b) else float("nan")


def _steady_ms(seq, skip: int = 1) -> float:
    ms = list(seq.wall_ms)
    return float(np.median(ms[skip:])) if len(ms) > skip else float(ms[-1])


def measure_adgi(rs, sec) -> dict:
    """relMSE and SSIM of ``adgi`` and ``qddgi`` over the frames from the gate's first motion on; ms/frame."""
    s = rs["summary"]
    e = {lb: _mean(_frames_from(rs, lb, "relmse", GATE_OPENS)) for lb in ("adgi", "qddgi")}
    q = {lb: _mean(_frames_from(rs, lb, "ssim", GATE_OPENS)) for lb in ("adgi", "qddgi")}
    ms = {lb: s[lb]["ms_per_frame"] for lb in ("adgi", "qddgi")}
    text = (f"while and after the gate opens: relMSE adgi {e['adgi']:.3g} vs qddgi {e['qddgi']:.3g} "
            f"({_ratio(e['qddgi'], e['adgi']):.2g}x), SSIM {q['adgi']:.3f} vs {q['qddgi']:.3f}; "
            f"{ms['adgi']:.0f} vs {ms['qddgi']:.0f} ms/frame")
    return {"text": text, "values": {"relmse": e, "ssim": q, "ms": ms}}


def measure_isddgi(rs, sec) -> dict:
    """Probe-trace and probe-update ms ratios (ddgi / isddgi), probe rays, MSE ratio (steady frames)."""
    s = rs["summary"]
    trace = {lb: s[lb]["stage_ms"].get("trace probes", 0.0) for lb in ("isddgi", "ddgi")}
    update = {lb: sum(s[lb]["stage_ms"].get(k, 0.0) for k in UPDATE_STAGES) for lb in ("isddgi", "ddgi")}
    rays = {}
    for lb in ("isddgi", "ddgi"):
        st = rs["results"][lb].steady()[0]
        rays[lb] = _mean([x.get("rays", {}).get("trace probes", 0) for x in st])
    mse = {lb: s[lb]["mean"]["mse"] for lb in ("isddgi", "ddgi")}
    sp_t, sp_u = _ratio(trace["ddgi"], trace["isddgi"]), _ratio(update["ddgi"], update["isddgi"])
    r = _ratio(mse["isddgi"], mse["ddgi"])
    text = (f"probe ray tracing {sp_t:.2f}x faster ({trace['isddgi']:.1f} vs {trace['ddgi']:.1f} ms/frame, "
            f"{_ratio(rays['ddgi'], rays['isddgi']):.2g}x fewer rays), probe update {sp_u:.2f}x faster; "
            f"MSE isddgi {mse['isddgi']:.3g} vs ddgi {mse['ddgi']:.3g} ({r:.2f}x)")
    return {"text": text,
            "values": {"trace_ms": trace, "update_ms": update, "probe_rays": rays, "mse": mse,
                       "trace_speedup": sp_t, "update_speedup": sp_u, "mse_ratio": r}}


def measure_ddgi_resampling(rs, sec) -> dict:
    """Table 1's protocol on the run's frames: the MAPE ``ddgi-resampling`` has on its first frame, and
    the frames (and ms: frames x median steady frame time) each technique needs to reach it."""
    base = "ddgi-resampling"
    target = float(_frames_from(rs, base, "mape")[0])
    out, parts = {}, []
    for lb in sec.specs:
        m = _frames_from(rs, lb, "mape")
        hit = np.nonzero(np.isfinite(m) & (m <= target))[0]
        n = int(hit[0]) + 1 if hit.size else None
        ms = _steady_ms(rs["results"][lb], skip=2)
        out[lb] = {"frames": n, "frame_ms": ms, "time_ms": n * ms if n is not None else None,
                   "final_mape": float(m[-1])}
        parts.append(f"{lb} {n} frame{'s' if n != 1 else ''} ({n * ms:.0f} ms)" if n is not None
                     else f"{lb} > {len(m)} frames (MAPE {m[-1]:.3f} after {len(m)})")
    text = f"frames (time) to ddgi-resampling's first-frame MAPE {target:.3f}: " + ", ".join(parts)
    return {"text": text, "values": {"target_mape": target, "techniques": out}}


def measure_smcir(rs, sec) -> dict:
    """|E| and |E'| (SMC-IR Sec. 5.2, indirect light, every pixel) of every spec of the section: ``smcir``, the
    paper's IR (Keller's quasi-random photons, ``ir:photons=qmc``) and the printed reading of Eq. 8
    (``smcir:eq8=text``, the claim's paper-literal row)."""
    s = rs["summary"]
    sm, ir = sec.specs[0], sec.specs[1]
    e = {lb: s[lb]["E"] for lb in sec.specs}
    ep = {lb: s[lb]["E_prime"] for lb in sec.specs}
    text = (f"indirect light, every pixel: |E'| (flicker) {sm} {ep[sm]:.3g} vs {ir} {ep[ir]:.3g} "
            f"({_ratio(ep[ir], ep[sm]):.2g}x lower), |E| {e[sm]:.3g} vs {e[ir]:.3g}"
            + "".join(f"; {lb}: |E'| {ep[lb]:.3g}, |E| {e[lb]:.3g}" for lb in sec.specs[2:]))
    return {"text": text, "values": {"E": e, "E_prime": ep}}


def measure_vlc(rs, sec) -> dict:
    """MSE at 1 spp of the VLC, the SLL (PVS lists) and the light tree, frames after frame 0 (the VLC starts
    empty); the oracle lists' too when the section runs them."""
    v, sll, lh = vlc.HEADLINE
    first = 1 if len(_frames_from(rs, v, "mse")) > 1 else 0
    labels = [lb for lb in (v, sll, lh, vlc.ORACLE) if lb in sec.specs]
    m = {lb: _mean(_frames_from(rs, lb, "mse", first=first)) for lb in labels}
    text = f"MSE at 1 spp (frames {first}..): VLC {m[v]:.3g}"
    for lb, name in ((sll, "SLL"), (lh, "light tree")):
        if lb in m:
            text += f", {name} {m[lb]:.3g} ({_ratio(m[lb], m[v]):.2g}x the VLC's)"
    if vlc.ORACLE in m:
        text += f", oracle lists {m[vlc.ORACLE]:.3g}"
    return {"text": text, "values": {"mse": m}}


def measure_cdq(rs, sec) -> dict:
    """MSE at 1 spp of CDQ and BSDF sampling over the second half of the frames (the first half: the CDQ
    learns from an empty octree); mean (expected error) and median (typical frame) over frames."""
    c, b = "nee-pt:directions=cdq", "nee-pt:directions=bsdf"
    n = len(_frames_from(rs, c, "mse"))
    first = n // 2
    mc, mb = _frames_from(rs, c, "mse", first=first), _frames_from(rs, b, "mse", first=first)
    mean = {c: _mean(mc), b: _mean(mb)}
    med = {c: float(np.median(mc)), b: float(np.median(mb))}
    text = (f"MSE at 1 spp, frames {first}..{n - 1} (after learning): CDQ {mean[c]:.3g} vs BSDF {mean[b]:.3g} "
            f"({_ratio(mean[b], mean[c]):.2g}x lower for CDQ; per-frame medians {med[c]:.3g} vs {med[b]:.3g})")
    return {"text": text, "values": {"mse_mean": mean, "mse_median": med}}


GATE_OPENS = 0.5
"""tunnel-gate's gate starts to slide open at t = 0.5 s (scene/builtin_default.py)."""
SEEDS = (0, 1, 2)
"""Every section runs its techniques with these seeds (the references are shared); the first seed's run
makes the section's report and figures, all three the claims' intervals."""


def _demo_metric(claims, text):
    return [dataclasses.replace(c, metric=f"{text} (the tour's reading)") for c in claims]


def _leaf_samples(rs, label):
    seq = rs["results"].get(label)
    octs = [st.get("octree") for st in (getattr(seq, "stats", None) or [])[1:] if st.get("octree")]
    octs = [o for o in octs if o.get("placed") is not None]
    return float(np.mean([o["placed"] / max(o["leaves"], 1) for o in octs])) if octs else None


def claims_adgi(sec, res, frames, rs=None, by_seed=None):
    after = max(0.0, sec.start + sec.span - adgi.GATE_DONE)
    return [c for c in adgi.declare_claims({"res": res, "dt": sec.span / max(frames - 1, 1)}, after)
            if c.key == "adgi.fig8.level"]


def value_adgi(claim, rs, label):
    return _mean(_frames_from(rs, label, "relmse", GATE_OPENS))


def claims_isddgi(sec, res, frames, rs=None, by_seed=None):
    return isddgi.declare_claims(sec.scene, {"res": res, "seeds": SEEDS}, frames)


def value_isddgi(claim, rs, label):
    return isddgi.claim_metric(claim, rs, label)


def claims_ddgi_resampling(sec, res, frames, rs=None, by_seed=None):
    return _demo_metric(ddgi_resampling.declare_claims(sec.scene, {"res": res, "seeds": len(SEEDS),
                                                                   "max_frames": frames}),
                        "ms to reach ddgi-resampling's first-frame MAPE (frames x median steady frame time)")


def value_ddgi_resampling(claim, rs, label):
    return measure_ddgi_resampling(rs, _SECTION["ddgi-resampling"])["values"]["techniques"][label]["time_ms"]


def claims_smcir(sec, res, frames, rs=None, by_seed=None):
    return _demo_metric(smcir.declare_claims({"specs": sec.specs, "res": res, "frames": frames}, sec.scene,
                                             methods=("ir",)), "|E'| over every pixel (Sec. 5.2)")


def value_smcir(claim, rs, label):
    return rs["summary"][label]["E_prime"]


def claims_vlc(sec, res, frames, rs=None, by_seed=None):
    """Fig. 8 (a)/(c) at the section's scale; the light-selection bound (PVS SLL over the oracle lists,
    :func:`~dyngi.experiments.reproductions.vlc.oracle_bound`) from every seed's run of both rows, when the
    section runs the oracle (without it the bound is unknown and Fig. 8 (a) stays undecided)."""
    fig = None
    if rs is not None:
        fig = {vlc.HEADLINE[0]: {"samples_per_leaf": _leaf_samples(rs, vlc.HEADLINE[0])}}
        runs = by_seed or {SEEDS[0]: rs}
        for spec in (vlc.SPECS[1], vlc.ORACLE):
            if spec in sec.specs:
                fig[spec] = {"mse_per_seed": [value_vlc(None, r, spec) for _, r in sorted(runs.items())]}
    return [c for c in vlc.declare_claims({"res": res, "frames": frames}, sec.scene, fig) if c.baseline in sec.specs]


def value_vlc(claim, rs, label):
    first = 1 if len(_frames_from(rs, label, "mse")) > 1 else 0
    return _mean(_frames_from(rs, label, "mse", first=first))


def claims_cdq(sec, res, frames, rs=None, by_seed=None):
    lb = "nee-pt:directions=cdq"
    a = {"scene": sec.scene, "techniques": {lb: {"samples_per_leaf": None if rs is None else _leaf_samples(rs, lb)}}}
    return _demo_metric(cdq.declare_claims({"res_a": res, "frames_a": frames, "warmup_a": frames // 2}, a),
                        "MSE at 1 spp over every pixel, second half of the frames")


def value_cdq(claim, rs, label):
    n = len(_frames_from(rs, label, "mse"))
    return _mean(_frames_from(rs, label, "mse", first=n // 2))

VLC_SPECS = ("nee-pt:lights=vlc", "nee-pt:lights=sll", "nee-pt:lights=lighttree", "nee-pt:lights=sll-oracle",
             "nee-pt:lights=vlc:cdq_min_records=0:leaf_scaling=false", "nee-pt:lights=vlc:cdq_min_records=0",
             "nee-pt:lights=vlc:leaf_scaling=false")
"""The VLC section's rows: the paper's three (VLC, SLL, LH), the oracle lists (the light-selection bound), the
claim's paper-literal row and one ablation per setting of ours (:func:`~dyngi.experiments.claims.claim_rows`)."""
CDQ_SPECS = ("nee-pt:directions=cdq", "nee-pt:directions=bsdf",
             "nee-pt:directions=cdq:cdq_min_records=0:leaf_scaling=false", "nee-pt:directions=cdq:cdq_min_records=0",
             "nee-pt:directions=cdq:leaf_scaling=false")
"""The CDQ section's rows: CDQ and BSDF sampling, the claim's paper-literal row and one ablation per setting of
ours."""


SECTIONS: tuple[Section, ...] = (
    Section(
        "adgi", "ADGI vs Q-DDGI: the tunnel gate opens",
        "Datta, Goli, Zhang, \"Adaptive Dynamic Global Illumination\", HPG 2022 (poster)",
        "tunnel-gate", ("adgi", "qddgi"),
        "Metropolis chains guided by change and visibility spend the probe rays where the light changes, so "
        "the tunnel interior follows the opening gate with less lag than Q-DDGI's uniform updates, and "
        "cheaper: 15.6 vs 26.8 ms/frame (Table 4, Bistro Exterior, RTX 2080 Ti); tunnel-interior SSIM/MSE "
        "at +4 s 0.948/0.004 vs 0.871/0.005 (Fig. 8, as extracted; whose value is whose is our reading of "
        "the caption).",
        measure_adgi, span=3.5, view=("qddgi", "adgi"), claims=claims_adgi, value=value_adgi),
    Section(
        "isddgi", "IS-DDGI vs DDGI: lights switch on and off",
        "Liu, Huang, Rocha, Malmros, Zhang, \"Importance-Based Ray Strategies for Dynamic Diffuse Global "
        "Illumination\", I3D 2023",
        "corridor-rooms", ("isddgi", "ddgi"),
        "Few rotating uniform rays plus importance rays where the probes' hits changed give \"similar visual "
        "quality to DDGI with a speedup of 1.27x to 2.47x in total DDGI time and 3.29x to 6.64x in probes "
        "ray tracing time\" (abstract); local light switching is its best case.",
        measure_isddgi, span=3.5, view=("ddgi", "isddgi"),
        claims=claims_isddgi, value=value_isddgi),
    Section(
        "ddgi-resampling", "DDGI Resampling vs Secondary DDGI vs PT+ReSTIR: a static interior",
        "Majercik, Mueller, Keller, Nowrouzezahrai, McGuire, \"Dynamic Diffuse Global Illumination "
        "Resampling\", Computer Graphics Forum 41(1), 2022",
        "cornell-static", ("ddgi-resampling", "ddgi-secondary", "restir-pt"),
        "Accumulating static frames at 1 spp, DDGI Resampling reaches in 1 frame the MAPE that Secondary "
        "DDGI needs 29 frames and PT+ReSTIR 109 frames for (Table 1, Red Ball: 13.4 vs 254 vs 1382 ms, "
        "RTX 3090, 1080p).",
        measure_ddgi_resampling, span=0.0, view=("ddgi-resampling", "restir-pt"),
        claims=claims_ddgi_resampling, value=value_ddgi_resampling),
    Section(
        "smcir", "SMC-IR vs instant radiosity: a moving sun",
        "Hedman, Karras, Lehtinen, \"Sequential Monte Carlo Instant Radiosity\", IEEE TVCG 23(5), 2017",
        "street-canyon-moving-sun", ("smcir", "ir:photons=qmc", "smcir:eq8=text"),
        "Moving only a few VPLs per frame (sequential Monte Carlo) keeps the indirect light temporally "
        "coherent: on Epic Citadel with a moving sun, |E| 0.0240 vs 0.0892 and |E'| (flicker) 0.0071 vs "
        "0.0323 for instant radiosity (Table 1, equal VPL budget).",
        measure_smcir, span=5.0, indirect=True, ref_depth=5, claims=claims_smcir, value=value_smcir,
        note="Indirect light only, against the path-traced indirect reference at max depth 5 (Sec. 5.2); "
             "|E| and |E'| over every pixel after Reinhard tone mapping."),
    Section(
        "vlc", "VLC vs the SLL and the light hierarchy: 512 lights in storage cells",
        "Dittebrandt, Hanika, Dachsbacher, \"Temporal Sample Reuse for Next Event Estimation and Path "
        "Guiding for Real-Time Path Tracing\", EGSR 2020",
        "storage-cells", VLC_SPECS,
        "Visible-light caches learnt per octree leaf from last frame's samples reach \"almost an order of "
        "magnitude lower error compared to the SLL and LH\" on the Quake 2 RTX warehouse; \"the LH is "
        "worst in this instance\" (Fig. 8 a, 1 spp).",
        measure_vlc, span=0.0, res_scale=2, ref_spp_scale=64, claims=claims_vlc, value=value_vlc,
        note="Scene held at t = 0 (Fig. 8 is a still; one reference serves every frame). storage-cells: 16 x 16 cells, one light each, 512 lights in every PVS list and about 4 visible from "
             "a point, so light selection limits the error (the oracle row's per-cell visible lists give the "
             "bound a light sampler can reach). At twice the tour's resolution a frame records >= 8 x 4096 "
             "samples, so the octree keeps the paper's thresholds; the paper-literal and ablation rows of the "
             "settings that are ours run beside. The full protocol (16 frames at 320x180, frames 10-15 "
             "measured, 16384-spp reference): dyngi reproduce vlc, docs/techniques/nee-pt.md."),
    Section(
        "cdq", "CDQ path guiding vs BSDF sampling: the sunlit pit",
        "Dittebrandt, Hanika, Dachsbacher, \"Temporal Sample Reuse for Next Event Estimation and Path "
        "Guiding for Real-Time Path Tracing\", EGSR 2020",
        "sky-pit-sun-disc", CDQ_SPECS,
        "With the sun disc in the environment and out of NEE, guiding the indirect rays by the learnt "
        "cosine-weighted direction quantisation \"improves sampling by two to three orders of magnitude\" "
        "for the regions the sun lights indirectly (Fig. 8 b, 1 spp).",
        measure_cdq, span=0.0, res_scale=2, frames_scale=5, claims=claims_cdq, value=value_cdq,
        note="Scene held at t = 0, the paper's 0.5-degree sun; every pixel, not only the indirectly lit ones; "
             "at twice the tour's resolution (the paper's octree thresholds) and five times its frames (the "
             "CDQ learns from an empty octree; the second half is measured). A 1-spp frame's error is "
             "heavy-tailed here (a BSDF ray rarely finds the sun), so few frames give a noisy reading: the "
             "full protocol (160 frames at 320x180, 3 seeds, indirectly lit pixels) is dyngi reproduce cdq."),
)


_SECTION = {s.key: s for s in SECTIONS}


def section_names() -> list[str]:
    return [s.key for s in SECTIONS]


def select_sections(keys) -> list[Section]:
    """The sections named in ``keys`` (all when None or empty), in tour order; an unknown name is an error."""
    if not keys:
        return list(SECTIONS)
    keys = [k.strip() for k in keys if k.strip()]
    bad = [k for k in keys if k not in section_names()]
    if bad:
        raise DyngiError(f"unknown demo section '{bad[0]}'; sections: {', '.join(section_names())}")
    return [s for s in SECTIONS if s.key in keys]


# -- running -----------------------------------------------------------------------------------

VIDEO_FPS = 4.0
"""Playback rate of a section's side-by-side video (its frames are span / (frames - 1) s apart)."""


def retime(scene, start: float, span: float, frames: int):
    """Make frame ``i`` of ``scene`` fall at ``start + i * span / (frames - 1)`` (every frame at ``start``
    when ``span`` is 0): the runner and the reference cache read :meth:`Scene.frame_time`, so the frames
    of a comparison cover the scene's event. Returns ``scene``."""
    dt = span / (frames - 1) if frames > 1 else 0.0
    scene.frame_time = lambda i, _s=float(start), _d=float(dt): _s + i * _d
    scene.fps = VIDEO_FPS
    return scene


def run_section(sec: Section, out_dir: str, size: Size, quiet: bool = True) -> dict:
    """Run one section's comparison, write its report into ``out_dir`` (a folder that the caller makes
    atomic); return ``{'measured', 'summary', 'wall_s', ...}``."""
    w0 = time.perf_counter()
    frames, ref_spp = sec.frames(size), sec.ref_spp(size)
    scene = retime(load_scene(sec.scene), sec.start, sec.span, frames)
    run = prepare(sec.scene, list(sec.specs), out_dir, frames, "equal-frames", ref_spp, {}, METRICS,
                  sec.ref_depth, sec.indirect, scene=scene, tracked=False)
    rs = execute(run, sec.res(size), seed=SEEDS[0], quiet=quiet)
    measured = sec.measure(rs, sec)
    by_seed = {SEEDS[0]: rs}
    for seed in SEEDS[1:]:        # the claims' intervals: fresh techniques per seed, the references cached
        sc = retime(load_scene(sec.scene), sec.start, sec.span, frames)
        run_s = prepare(sec.scene, list(sec.specs), out_dir, frames, "equal-frames", ref_spp, {}, METRICS,
                        sec.ref_depth, sec.indirect, scene=sc, tracked=False)
        by_seed[seed] = execute(run_s, sec.res(size), seed=seed, quiet=quiet)
    claims = decide_section(sec, by_seed, sec.res(size), frames)
    extra = "\n".join([f"## {sec.title}", "", f"Paper: {sec.paper}.", "", f"Claim: {sec.claim}", "",
                       f"Measured here: {measured['text']}.", "", *([sec.note, ""] if sec.note else []),
                       *[line for c in claims for line in c.markdown()]])
    os.makedirs(out_dir, exist_ok=True)
    write_outputs(out_dir, run["scene"], run["labels"], run["specs"], rs["results"], rs["refs"], rs["rows"],
                  rs["summary"], rs["ctx"], run["names"], title=f"demo: {sec.title} ({sec.scene})", extra_md=extra)
    return {"key": sec.key, "scene": sec.scene, "specs": list(sec.specs), "measured": measured, "claims": claims,
            "summary": {lb: {k: v for k, v in rs["summary"][lb].items() if k != "tracked_pixels"}
                        for lb in run["labels"]},
            "frame_times": [float(t) for t in rs["results"][run["labels"][0]].times],
            "ref_depth": run["ref_depth"], "res": list(sec.res(size)), "frames": frames, "ref_spp": ref_spp,
            "wall_s": time.perf_counter() - w0}


def decide_section(sec: Section, by_seed: dict, res, frames: int) -> list:
    """The section's claims (:attr:`Section.claims`) decided from its runs per seed (:attr:`Section.value`):
    the default and baseline rows, and every paper-literal or ablation row (:func:`~dyngi.experiments.claims.
    claim_rows`) whose spec the section runs among its :attr:`Section.specs`. A claim whose technique has a
    setting of ours with a paper value and whose paper-literal row the section does not run says ``undecided``
    (``rows not run``), as does every claim whose scale need the tour does not meet."""
    first = by_seed[min(by_seed)]
    out = []
    for c in sec.claims(sec, res, frames, first, by_seed):
        specs = {"default": c.technique, "baseline": c.baseline}
        specs.update({r.label: r.spec for r in claim_rows(c)
                      if r.role in ("paper-literal", "ablation") and r.spec in sec.specs})
        vals = {label: {s: sec.value(c, rs, spec) for s, rs in by_seed.items()} for label, spec in specs.items()}
        out.append(result_from_values(c, vals))
    return out


def run_tour(out_dir: str, size: str | Size = "tour", sections=None, quiet: bool = True, res=None, frames=None,
             ref_spp=None) -> str:
    """Run the tour into ``out_dir`` (written atomically); return its absolute path.

    ``size``: a key of :data:`SIZES` or a :class:`Size`; ``res``/``frames``/``ref_spp`` override it.
    ``sections``: keys of :data:`SECTIONS` (default all)."""
    base = SIZES[size] if isinstance(size, str) else size
    sz = Size(tuple(res) if res is not None else base.res, int(frames or base.frames), int(ref_spp or base.ref_spp))
    if sz.frames < 2:
        raise DyngiError(f"the demo needs >= 2 frames per section, got {sz.frames}")
    secs = select_sections(sections)
    check_writable(out_dir)
    out_dir = os.path.abspath(out_dir)
    w0 = time.perf_counter()
    results = []
    with atomic_output_dir(out_dir) as tmp:
        for k, sec in enumerate(secs):
            if not quiet:
                print(f"demo [{k + 1}/{len(secs)}] {sec.title}: {', '.join(sec.specs)} on {sec.scene}",
                      file=sys.stderr)
            results.append(run_section(sec, os.path.join(tmp, sec.key), sz, quiet))
        wall = time.perf_counter() - w0
        write_tour_report(tmp, secs, results, sz, wall)
    return out_dir


# -- the top-level report ------------------------------------------------------------------------

_CSS = ("body{font-family:sans-serif;max-width:1100px;margin:auto;padding:0 1em;line-height:1.4}"
        "table{border-collapse:collapse;margin:0.5em 0}td,th{border:1px solid #ccc;padding:3px 8px;"
        "text-align:right}td:first-child,th:first-child{text-align:left}"
        "figure{margin:1em 0}figure img{display:block;max-width:100%;height:auto}"
        "figcaption{font-size:90%;color:#444}blockquote{margin:0.5em 0;padding:0.3em 1em;"
        "border-left:4px solid #8ab;background:#f4f8fa}.ours{font-weight:bold}"
        ".yes{color:#060}.no{color:#a00}code{background:#eee;padding:0 3px}section{margin-top:2.5em}")


def _words(claims) -> str:
    """The section's verdict words: one per claim (computed, :func:`decide_section`)."""
    return "; ".join(f"{c.claim.key}: {c.verdict.word}" for c in claims) or "no claim decided here"


def _claims_html(claims) -> str:
    rows = ["<table><tr><th>claim</th><th>verdict</th><th>ratio to baseline [90 % interval]</th>"
            "<th>why</th></tr>"]
    for c in claims:
        j = c.verdict.rows.get("default")
        iv = "" if j is None else f"{j.ratio:.3g} [{j.interval[0]:.3g}, {j.interval[1]:.3g}] ({j.n} seeds)"
        rows.append(f"<tr><td>{html.escape(c.claim.key)} ({html.escape(c.claim.where)}; "
                    f"{html.escape(c.claim.criterion.text())})</td><td><b>{html.escape(c.verdict.word)}</b></td>"
                    f"<td>{html.escape(iv)}</td><td style='text-align:left'>"
                    f"{html.escape('; '.join(c.verdict.conditions))}</td></tr>")
    rows.append("</table>")
    return "\n".join(rows)


def _section_table(res: dict) -> str:
    rows = ["<table><tr><th>technique</th><th>relMSE</th><th>MSE</th><th>MAPE</th><th>SSIM</th>"
            "<th>ms/frame</th><th>Mrays/frame</th><th>NaN/Inf px</th></tr>"]
    for lb, s in res["summary"].items():
        m = s["mean"]
        rows.append(f"<tr><td>{html.escape(lb)}</td><td>{m['relmse']:.4g}</td><td>{m['mse']:.4g}</td>"
                    f"<td>{m['mape']:.4g}</td><td>{m['ssim']:.3f}</td><td>{s['ms_per_frame']:.1f}</td>"
                    f"<td>{s['rays_per_frame'] / 1e6:.3g}</td><td>{s['nonfinite_pixels']}</td></tr>")
    rows.append("</table>")
    return "\n".join(rows)


def _figure(path: str, caption: str) -> str:
    return (f"<figure><img src='{data_uri(path, 'image/png')}' alt='{html.escape(caption)}'>"
            f"<figcaption>{html.escape(caption)}</figcaption></figure>")


def write_tour_report(out_dir: str, secs, results, size: Size, wall_s: float) -> None:
    """``report.html`` (claim, our figure, table, last frame's grid, error plot, link per section),
    ``summary.md``, ``summary.json`` (figures and every technique's failure status) in ``out_dir``."""
    info = backend.device_info()
    settings = (f"{size.res[0]}x{size.res[1]}, {size.frames} frames per section, references {size.ref_spp} spp "
                f"(Mitsuba's path integrator, cached), {info['variant']} (Mitsuba {info['mitsuba']}); "
                f"ran in {wall_s:.0f} s")
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    parts = ["<!doctype html><html><head><meta charset='utf-8'><title>dyngi demo: the papers' techniques"
             f"</title><style>{_CSS}</style></head><body>",
             "<h1>dyngi demo: five papers' techniques, each on its analog scene against its baseline</h1>",
             f"<p>{html.escape(settings)} (load average {load:.1f}). Every error is against the path-traced "
             "ground truth. These are small, short runs: the figures are readings of this run, not the papers' "
             "measurements (<code>dyngi reproduce NAME</code> runs each paper's protocol).</p>",
             "<table><tr><th>section</th><th>scene</th><th>measured here</th><th>verdicts (computed from "
             f"{len(SEEDS)} seeds at the tour's scale)</th></tr>"]
    for sec, r in zip(secs, results):
        parts.append(f"<tr><td><a href='#{sec.key}'>{html.escape(sec.title)}</a></td><td style='text-align:left'>{sec.scene}</td>"
                     f"<td style='text-align:left'>{html.escape(r['measured']['text'])}</td>"
                     f"<td style='text-align:left'>{html.escape(_words(r['claims']))}</td></tr>")
    parts.append("</table>")
    md = ["# dyngi demo", "", settings + ".", ""]
    for sec, r in zip(secs, results):
        d = os.path.join(out_dir, sec.key)
        grids = sorted(n for n in os.listdir(d) if n.startswith("grid_") and n.endswith(".png"))
        times = r["frame_times"]
        when = (f"held at t = {times[0]:g} s" if sec.span == 0 else
                f"t = {times[0]:g} to {times[-1]:g} s, {times[1] - times[0]:.3g} s apart")
        parts += [f"<section id='{sec.key}'><h2>{html.escape(sec.title)}</h2>",
                  f"<p><i>{html.escape(sec.paper)}</i></p>",
                  f"<p>Scene <code>{sec.scene}</code> ({when}, {r['res'][0]}x{r['res'][1]}, {len(times)} frames, "
                  f"reference {r.get('ref_spp', size.ref_spp)} spp); techniques "
                  + ", ".join(f"<code>{html.escape(s)}</code>" for s in sec.specs) + ".</p>",
                  f"<blockquote><b>The paper:</b> {html.escape(sec.claim)}</blockquote>",
                  f"<p class='ours'>Measured here: {html.escape(r['measured']['text'])}.</p>",
                  _claims_html(r["claims"])]
        if sec.note:
            parts.append(f"<p>{html.escape(sec.note)}</p>")
        parts.append(_section_table(r))
        if grids:
            last = grids[-1]
            parts.append(_figure(os.path.join(d, last), f"frame {int(last[5:9])}: each technique, the reference "
                                 "and the FLIP error map"))
        plot = os.path.join(d, "plots", "errors.png")
        if os.path.exists(plot):
            parts.append(_figure(plot, "error per frame and against cumulative wall time"))
        parts.append(f"<p><a href='{sec.key}/report.html'>Full report of this section</a> (metrics, every grid, "
                     f"stage times, side-by-side video). Explore it live: <code>{html.escape(sec.view_command)}"
                     "</code></p></section>")
        md += [f"## {sec.title}", "", f"Paper: {sec.paper}.", "", f"Claim: {sec.claim}", "",
               f"Measured here ({sec.scene}, {r['res'][0]}x{r['res'][1]}): {r['measured']['text']}.", "",
               *[line for c in r["claims"] for line in c.markdown()],
               f"Report: `{sec.key}/report.html`; live: `{sec.view_command}`.", ""]
    first = secs[0].view_command if secs else "dyngi view tunnel-gate --techniques qddgi,adgi"
    parts += [f"<h2>Explore further</h2><p>Look around a scene, switch techniques and watch the probes live in "
              f"the browser: <code>{html.escape(first)}</code></p></body></html>"]
    with open(os.path.join(out_dir, "report.html"), "w") as f:
        f.write("\n".join(parts))
    with open(os.path.join(out_dir, "summary.md"), "w") as f:
        f.write("\n".join(md) + "\n")
    techniques = {f"{r['key']}/{lb}": {"failed": bool(s.get("failed")),
                                       "nonfinite_pixels": int(s.get("nonfinite_pixels", 0)),
                                       "nonfinite_frames": int(s.get("nonfinite_frames", 0))}
                  for r in results for lb, s in r["summary"].items()}
    write_json(os.path.join(out_dir, "summary.json"), {
        "demo": True, "res": list(size.res), "frames": size.frames, "ref_spp": size.ref_spp, "wall_s": wall_s,
        "load_average": load, "device": info, "commit": claims_json([])["commit"], "seeds": list(SEEDS),
        "sections": [{"key": s.key, "title": s.title, "paper": s.paper, "claim": s.claim, "scene": s.scene,
                      "specs": list(s.specs), "measured": r["measured"], "res": r["res"],
                      "claims": claims_json(r["claims"])["claims"],
                      "wall_s": r["wall_s"],
                      "frame_times": r["frame_times"], "view": s.view_command}
                     for s, r in zip(secs, results)],
        "techniques": techniques})
