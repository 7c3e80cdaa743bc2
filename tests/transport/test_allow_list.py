"""Acceptance of "all call it": outside the transport layer (and the light- and
direction-sampler layers), no module samples a BSDF or an emitter direction itself, except the listed
modules below, each with its reason. Read statically from the source: the test fails on a new caller
(use :mod:`dyngi.transport.path_walk` or add it here with a reason) and on a listed module that no
longer calls (so the list only shrinks)."""
from __future__ import annotations

import os
import re

SRC = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))), "src", "dyngi")

# layers that may sample BSDFs and emitters: the path walk, the light / direction samplers
OWNERS = ("transport", "lights", "directions")

CALL = re.compile(r"\bbsdf\w*\.sample\(|\.bsdf\([^)]*\)\.sample\(|\.sample\(\s*(ctx|gctx|mi\.BSDFContext)"
                  r"|sample_emitter_direction\(")

ALLOWED = {
    # a delta transmission lobe's weight for shadow rays through glass (no direction is sampled)
    "scene/passthrough.py": "thin-glass transmittance of shadow rays",
    # glossy-lobe-only sampling for the DDGI family's glossy probe lookups (Eq. 6), not a path walk
    "probes/glossy.py": "sample_glossy: one glossy-lobe sample (DDGI+ Eq. 6, ddgi-primary's recursion)",
}


def _callers():
    found = set()
    for root, _, files in os.walk(SRC):
        for f in files:
            if not f.endswith(".py"):
                continue
            path = os.path.join(root, f)
            rel = os.path.relpath(path, SRC).replace(os.sep, "/")
            if rel.split("/")[0] in OWNERS:
                continue
            if CALL.search(open(path, encoding="utf-8").read()):
                found.add(rel)
    return found


def test_only_listed_modules_sample_bsdfs_or_emitters_outside_transport():
    found = _callers()
    new = sorted(found - set(ALLOWED))
    assert not new, f"call the transport layer's walk, or list with a reason: {new}"


def test_allow_list_has_no_stale_entries():
    stale = sorted(set(ALLOWED) - _callers())
    assert not stale, f"no longer call: remove from ALLOWED: {stale}"


def test_the_pattern_finds_calls():
    assert CALL.search("bs, w = bsdf.sample(ctx, si, u1, u2, active)")
    assert CALL.search("ds, w = scene.sample_emitter_direction(si, u, True, m)")
    assert CALL.search("bs, w = si.bsdf(ray).sample(mi.BSDFContext(), si, a, b)")
    assert not CALL.search("k, pl = cand.sample(si, u1, u2, active)")
