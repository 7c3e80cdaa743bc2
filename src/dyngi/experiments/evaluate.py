"""Evaluation of rendered sequences against the ground truth: references, per-frame metrics, summaries.

Used by ``dyngi compare`` (:mod:`dyngi.experiments.compare`) and ``dyngi reproduce``
(:mod:`dyngi.experiments.reproduce`), so that both measure the same way.

Images are measured *as returned*. A frame with NaN/Inf values is a failure of that technique: its
pixels with a non-finite channel are counted (``nonfinite`` column of ``metrics.csv``), its metrics
are NaN, and the summary, the report and the CLI say so; nothing is zeroed or clamped. MSE, relMSE and
MAPE take negative values as they are. FLIP, SSIM and the temporal |E|, |E'| are defined on displayable
(tone-mapped, non-negative) images: for those three only, negative values are shown as 0, as a display
would, and the number of negative pixels is reported (``negative`` column).

References (:func:`collect_references`): Mitsuba's ``path`` (:mod:`dyngi.experiments.references.path`) at
``ref_depth`` (default: the scene's own max depth), as two independent cached halves whose difference
estimates the reference's own noise per frame (:func:`~dyngi.experiments.references.path.reference_halves`).
With ``indirect`` the indirect-only reference of :mod:`dyngi.experiments.references.indirect`; clamped path
tracing (:func:`collect_clamped_references`, :mod:`dyngi.experiments.references.clamped`).
"""
from __future__ import annotations

import numpy as np

from ..errors import DyngiError
from ..metrics import METRICS, temporal_errors
from ..metrics.temporal import auto_exposure, pick_tracked_pixels
from .references.clamped import cached_clamped, clamped_indirect, clamped_reference_halves
from .references.indirect import cached_indirect_reference
from .references.path import reference_halves
from .runner import frame_rays
from .references.tracked import TRACKED_SPP_FACTOR, TRACKED_SPP_MAX, cached_tracked_reference

METRIC_NAMES = ("mse", "relmse", "mape", "flip", "ssim")
LABELS = {"mse": "MSE", "relmse": "relMSE", "mape": "MAPE", "flip": "FLIP", "ssim": "SSIM"}
DISPLAY_METRICS = frozenset({"flip", "ssim"})
"""Metrics of displayed images: negative values enter them as 0 (see the module docstring)."""
NOISE_MARGIN = 10.0
"""The reference's own relMSE should be at least this factor below the smallest technique relMSE."""


def check_metric_names(names) -> list[str]:
    names = list(names) if names else list(METRIC_NAMES)
    for m in names:
        if m not in METRICS:
            raise DyngiError(f"unknown metric '{m}'; valid metrics: {', '.join(sorted(METRICS))}")
    return names


# -- references --------------------------------------------------------------------

def indirect_reference_fn():
    """``f(scene, t, res, spp, max_depth) -> (image, noise)``: the cached indirect-only reference of
    :mod:`dyngi.experiments.references.indirect` (dyngi's validated path tracer in its indirect-only mode:
    unclamped, unbiased, noise from two independent halves)."""

    def fn(scene, t, res, spp, max_depth):
        img, noise, _ = cached_indirect_reference(scene, t, res, spp, max_depth)
        return img, noise
    return fn


def _noise_of(out) -> tuple[np.ndarray, dict]:
    if isinstance(out, tuple):
        img, noise = out[0], (out[1] if len(out) > 1 else None)
    else:
        img, noise = out, None
    return np.asarray(img, np.float32), (dict(noise) if isinstance(noise, dict) else {})


class ReferenceList(list):
    """The per-frame reference images, with ``tracked``: the 8 tracked pixels of SMC-IR Sec. 5.2 and their
    per-pixel references of more samples (``{'pixels', 'values': T x 8 x 3, 'spp'}``), or None."""

    tracked: dict | None = None


def collect_references(scene, frames: int, res, spp: int, ref_depth: int, indirect: bool = False,
                       bar=None, tracked_spp: int | None = None) -> tuple[list, list]:
    """(images, noise dicts) of the references of frames 0..frames-1 (cached on disk).

    The images come as a :class:`ReferenceList` whose ``tracked`` holds the 8 tracked pixels (chosen
    from frame 0's reference, :func:`dyngi.metrics.temporal.pick_tracked_pixels`) and their per-pixel
    references of ``tracked_spp`` samples (default 16x ``spp``, :mod:`dyngi.experiments.references.tracked`;
    0: none, the image reference's values stand in)."""
    refs, noise = _collect_images(scene, frames, res, spp, ref_depth, indirect, bar)
    refs = ReferenceList(refs)
    if refs:
        pix = pick_tracked_pixels(refs[0])
        tspp = min(TRACKED_SPP_MAX, TRACKED_SPP_FACTOR * int(spp)) if tracked_spp is None else int(tracked_spp)
        if tspp > 0:
            vals = np.stack([cached_tracked_reference(scene, scene.frame_time(i), res, pix, tspp, ref_depth,
                                                      indirect)
                             for i in range(frames)])
        else:
            vals = np.stack([r[pix[:, 0], pix[:, 1]] for r in refs])
        refs.tracked = {"pixels": pix, "values": vals, "spp": tspp if tspp > 0 else int(spp)}
    return refs, noise


def _collect_images(scene, frames: int, res, spp: int, ref_depth: int, indirect: bool = False,
                    bar=None) -> tuple[list, list]:
    """(images, noise dicts) of the references of frames 0..frames-1 (cached on disk)."""
    fn = indirect_reference_fn() if indirect else None
    refs, noise = [], []
    for i in range(frames):
        t = scene.frame_time(i)
        if fn is None:
            img, nz = reference_halves(scene, t, res, spp, ref_depth)
        else:
            img, nz = _noise_of(fn(scene, t, res, spp, ref_depth))
        refs.append(img)
        noise.append(nz)
        if bar is not None:
            bar.update(1)
    return refs, noise


def collect_clamped_references(scene, frames: int, res, spp: int, max_depth: int, gmax: float, bar=None,
                               tracked_spp: int | None = None):
    """As :func:`collect_references`, with clamped path tracing (:mod:`dyngi.experiments.references.clamped`):
    (references, noise dicts); the tracked pixels' values from its ``clamped_indirect`` at those pixels,
    ``tracked_spp`` samples (default 16x ``spp`` as the path-traced tracked reference; 0: the image's values
    stand in)."""
    refs, noise = ReferenceList(), []
    for i in range(frames):
        img, nz = clamped_reference_halves(scene, scene.frame_time(i), res, spp, max_depth, gmax)
        refs.append(img)
        noise.append(nz)
        if bar is not None:
            bar.update(1)
    if refs:
        pix = pick_tracked_pixels(refs[0])
        tspp = min(TRACKED_SPP_MAX, TRACKED_SPP_FACTOR * int(spp)) if tracked_spp is None else int(tracked_spp)
        if tspp > 0:
            vals = np.stack([cached_clamped("tracked", {"state": scene.state_hash(float(scene.frame_time(i))),
                                                 "res": list(map(int, res)), "pixels": pix.tolist(),
                                                 "spp": tspp, "max_depth": int(max_depth),
                                                 "gmax": float(min(gmax, 3.0e38))},
                                     lambda i=i: clamped_indirect(scene, scene.frame_time(i), res, tspp, max_depth,
                                                                  gmax, seed=0x7AC4, pixels=pix), (len(pix), 3))
                             for i in range(frames)])
        else:
            vals = np.stack([r[pix[:, 0], pix[:, 1]] for r in refs])
        refs.tracked = {"pixels": pix, "values": vals, "spp": tspp if tspp > 0 else int(spp)}
    return refs, noise


def summarize_noise(noise: list[dict]) -> dict:
    """Mean of the per-frame noise estimates (relMSE, MSE); NaN where not estimated."""
    out = {}
    for k in ("relmse", "mse"):
        vals = [n[k] for n in noise if isinstance(n.get(k), (int, float))]
        out[k] = float(np.mean(vals)) if vals else float("nan")
    out["per_frame_relmse"] = [n.get("relmse", float("nan")) for n in noise]
    return out


# -- metrics -----------------------------------------------------------------------

def image_health(img: np.ndarray) -> tuple[int, int]:
    """(pixels with a NaN/Inf channel, pixels with a negative channel) of an H x W x 3 image."""
    a = np.asarray(img)
    bad = ~np.isfinite(a)
    nonfinite = int(np.count_nonzero(bad.any(axis=-1)))
    with np.errstate(invalid="ignore"):
        neg = int(np.count_nonzero((np.where(bad, 0.0, a) < 0).any(axis=-1)))
    return nonfinite, neg


def frame_metrics(img, ref, names) -> dict:
    """Metrics of one frame as returned; all NaN when the image has NaN/Inf values."""
    a = np.asarray(img, np.float64)
    if not np.all(np.isfinite(a)):
        return {k: float("nan") for k in names}
    out = {}
    for k in names:
        x = np.maximum(a, 0.0) if k in DISPLAY_METRICS else a
        out[k] = float(METRICS[k](x, ref))
    return out


def evaluate_sequence(label: str, seq, refs: list, names, images: list | None = None) -> tuple[list, dict]:
    """(csv rows, summary) of one technique's run against ``refs``.

    ``images``: what to measure (default ``seq.images``; ``seq.indirect`` for indirect-only comparisons).
    Summary: ``mean`` per metric (NaN if any frame failed), ``E``/``E_prime`` (SMC-IR Sec. 5.2, every
    pixel against the image reference), ``E_tracked``/``E_prime_tracked`` (the same over the 8 tracked
    pixels against their per-pixel reference, when ``refs.tracked`` is set: :class:`ReferenceList`),
    ``ms_per_frame`` and ``rays_per_frame`` over the steady frames, ``stage_ms``,
    ``nonfinite_pixels``/``nonfinite_frames``/``failed``, ``negative_pixels``.
    """
    images = seq.images if images is None else images
    rows, per_frame, nonfinite, negative = [], [], [], []
    for i, img in enumerate(images):
        nf, neg = image_health(img)
        m = frame_metrics(img, refs[i], names)
        st = seq.stats[i]
        row = {"technique": label, "frame": i, "time": seq.times[i], **m, "nonfinite": nf, "negative": neg,
               "wall_ms": seq.wall_ms[i], "rays": frame_rays(st)}
        for stage, ms in st.get("ms", {}).items():
            row[f"ms_{stage}"] = ms
        rows.append(row)
        per_frame.append(m)
        nonfinite.append(nf)
        negative.append(neg)
    failed = any(nonfinite)
    if failed:
        tm = {"E": float("nan"), "E_prime": float("nan")}
    else:
        tm = temporal_errors(np.stack([np.maximum(x, 0.0) for x in images]), np.stack(refs))
    tracked = getattr(refs, "tracked", None)
    te = {"E": float("nan"), "E_prime": float("nan")}
    if tracked is not None and not failed:   # Sec. 5.2: 8 tracked pixels against their own reference
        pix = tracked["pixels"]
        est = np.stack([np.maximum(x, 0.0)[pix[:, 0], pix[:, 1]] for x in images])[:, :, None, :]
        te = temporal_errors(est, np.asarray(tracked["values"])[:, :, None, :])
    steady, steady_ms = seq.steady()
    stage_ms = {}
    for st in steady:
        for k, v in st.get("ms", {}).items():
            stage_ms[k] = stage_ms.get(k, 0.0) + v / len(steady)
    summary = {
        "mean": {k: float(np.mean([f[k] for f in per_frame])) for k in names},
        "E": float(tm["E"]), "E_prime": float(tm["E_prime"]),
        "E_tracked": float(te["E"]), "E_prime_tracked": float(te["E_prime"]),
        "tracked_pixels": tracked["pixels"].tolist() if tracked is not None else None,
        "tracked_spp": int(tracked["spp"]) if tracked is not None else None,
        "ms_per_frame": float(np.mean(steady_ms)),
        "stage_ms": stage_ms,
        "rays_per_frame": float(np.mean([frame_rays(s) for s in steady])),
        "nonfinite_pixels": int(sum(nonfinite)),
        "nonfinite_frames": int(sum(1 for n in nonfinite if n)),
        "negative_pixels": int(sum(negative)),
        "failed": bool(failed),
    }
    return rows, summary


# -- the SMC-IR table's tracked-pixel measurement (Sec. 5.2; issue 42) -----------------------------------------
# Used by the SMC-IR reproduction only; evaluate_sequence above (every other comparison) is unchanged.

def tracked_exposure(refs, exposure="auto") -> float:
    """Reinhard's scale for the tracked pixels' |E|, |E'|: ``'auto'``, the key a / Lw of the whole *image*
    reference sequence (Reinhard et al. 2002, Eqs. 1-2; as tests/techniques/smcir/test_flicker.py), or a
    fixed number (1: the harness's default k)."""
    return float(auto_exposure(list(refs))) if exposure == "auto" else float(exposure)


def tracked_temporal(images, values, pixels, exposure: float, scale: float = 1.0) -> dict:
    """|E| and |E'| (Eq. 10) of the 8 tracked ``pixels`` of ``images`` (T x H x W x 3, shown as
    non-negative) against their per-pixel reference ``values`` (T x 8 x 3) at Reinhard scale ``exposure``;
    ``scale`` multiplies the estimate first (1 / its brightness: the brightness-normalised |E'|, which a
    dim method cannot lower by being dim)."""
    pix = np.asarray(pixels)
    est = np.stack([np.asarray(x, np.float64)[pix[:, 0], pix[:, 1]] for x in images])
    if not np.all(np.isfinite(est)):          # a failed run (NaN/Inf): no figure, as evaluate_sequence
        return {"E": float("nan"), "E_prime": float("nan")}
    est = np.maximum(est, 0.0)
    return temporal_errors(est[:, :, None, :] * float(scale), np.asarray(values, np.float64)[:, :, None, :],
                           exposure=float(exposure))


def tracked_reference_floor(half_a, half_b, exposure: float) -> dict:
    """The tracked reference's own |E| and |E'| (its noise; a floor under any method's): half a measured
    against half b (T x 8 x 3 each, independent, S / 2 samples), halved -- a - b has twice the standard
    deviation of the S-sample mean's noise, in each frame and in each frame-to-frame difference."""
    t = temporal_errors(np.asarray(half_a, np.float64)[:, :, None, :], np.asarray(half_b, np.float64)[:, :, None, :],
                        exposure=float(exposure))
    return {"E": 0.5 * float(t["E"]), "E_prime": 0.5 * float(t["E_prime"])}


def noise_warning(summary: dict, ref_noise: dict, names) -> str | None:
    """A warning when the reference's relMSE is not at least NOISE_MARGIN x below every technique's."""
    if "relmse" not in names:
        return None
    errs = [s["mean"]["relmse"] for s in summary.values() if np.isfinite(s["mean"]["relmse"])]
    rn = ref_noise.get("relmse", float("nan"))
    if not errs or not np.isfinite(rn):
        return None
    smallest = min(errs)
    if rn * NOISE_MARGIN > smallest:
        return (f"the reference's own relMSE ({rn:.3g}) is not {NOISE_MARGIN:g}x below the smallest technique "
                f"relMSE ({smallest:.3g}): differences at that level are reference noise; raise --ref-spp")
    return None


def failures(summary: dict) -> list[str]:
    """One line per technique that returned NaN/Inf pixels."""
    return [f"{t}: {s['nonfinite_pixels']} NaN/Inf pixel(s) in {s['nonfinite_frames']} frame(s)"
            for t, s in summary.items() if s.get("failed")]
