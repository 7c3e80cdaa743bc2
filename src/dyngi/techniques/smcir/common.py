"""SMC-IR (Hedman et al. 2017): what the host and the device form of Algorithm 1 share -- the random
streams' keys, the candidates' k (Sec. 3.2.4), the warm-up iterations' frame keys and the lighting
signature that tells when a VPL's radiosity must be re-estimated (line 18)."""
from __future__ import annotations

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
