"""SMC-IR (Hedman et al. 2017): what the host and the device form of Algorithm 1 share -- the random
streams' keys, the candidates' k (Sec. 3.2.4), the warm-up iterations' frame keys, the lighting
signature that tells when a VPL's radiosity must be re-estimated (line 18), and the steps of an iteration
and of INITIALIZEVPLS that do not depend on where the VPL set lives."""
from __future__ import annotations

from ..base import StageTimer

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


def begin_iteration(tech, frame, key: int, t, candidates, invalid) -> tuple:
    """Lines 3-7 of Algorithm 1 as both forms run them: ``candidates(frame, key, t)`` (lines 5-7: the
    candidates and the raw points X), then -- the candidates' radiosity was traced with this frame's
    lighting -- a changed lighting signature clears ``tech._light_sig`` (line 18 then re-estimates every
    survivor), then ``invalid(frame, key, X, t)`` (lines 3-4). Returns (candidates, invalid mask)."""
    cand, pts = candidates(frame, key, t)
    if tech._light_sig != lighting_signature(tech.scene, frame.time):
        tech._light_sig = None
    return cand, invalid(frame, key, pts, t)


def warm_up(frame, t, warmup: int, iterate) -> None:
    """INITIALIZEVPLS (Sec. 3.2): ``warmup + 1`` iterations on ``frame``'s camera, the first filling the
    empty set with candidates, keyed ``WARMUP_FRAME_BASE + i``; timed as the stage ``warmup`` of ``t``
    (their own stages go to a scratch timer)."""
    with t.stage("warmup"):
        wt = StageTimer()
        for i in range(int(warmup) + 1):
            iterate(frame, WARMUP_FRAME_BASE + i, wt)
