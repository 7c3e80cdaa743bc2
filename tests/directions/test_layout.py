"""Where the light and direction samplers live (DESIGN.md, ``lights/`` and ``directions/``).

``lights/`` and ``directions/`` are one layer; the adaptive octree is owned by ``directions/`` and shared with
the VLC, so ``lights/`` may import ``directions/`` and never the reverse. ``sampling/`` keeps warps and
statistics only, and the octree is constructed in one place (``directions.octree.make_octree``)."""
from __future__ import annotations

import os

from tests.test_layers import SRC, _modules, _imports

SAMPLING = {"dyngi.sampling", "dyngi.sampling.diffuse", "dyngi.sampling.fibonacci", "dyngi.sampling.metropolis",
            "dyngi.sampling.octahedral", "dyngi.sampling.reservoir", "dyngi.sampling.rng"}
"""The warps and statistics of ``sampling/``: RNG streams, octahedral and Fibonacci maps, reservoirs,
Metropolis chains, the diffuse-albedo helper (alias tables live with their users)."""


def test_directions_never_import_lights():
    bad = sorted((m, i) for m, p in _modules() if m.startswith("dyngi.directions")
                 for i in _imports(m, p) if i.startswith("dyngi.lights"))
    assert not bad, "directions/ imports lights/: " + ", ".join(f"{m} -> {i}" for m, i in bad)


def test_sampling_keeps_warps_and_statistics_only():
    mods = {m for m, _ in _modules() if m.startswith("dyngi.sampling")}
    assert mods == SAMPLING, f"sampling/ holds {sorted(mods - SAMPLING)} (move them to their concept's package)"


def test_octree_constructed_in_one_place():
    """``AdaptiveOctree(...)`` is called by ``make_octree`` only (the VLC's, the CDQ's and nee-pt's octree)."""
    calls = []
    for mod, path in _modules():
        text = open(path, encoding="utf-8").read()
        n = text.count("AdaptiveOctree(")
        if n:
            calls.append((os.path.relpath(path, SRC), n))
    assert calls == [(os.path.join("directions", "octree.py"), 1)], calls
