"""The regular probe grid of a DDGI volume (Majercik et al., JCGT 2019, Sec. 3).

Probes sit on a regular 3D lattice ``origin + spacing * (i, j, k)`` with
``counts = (nx, ny, nz)``; probe ``p`` has grid coordinates
``i = p % nx, j = (p // nx) % ny, k = p // (nx * ny)`` (x fastest). Each probe
may carry a relocation offset (Majercik et al., JCGT 2021, "Scaling
Probe-Based Real-Time Dynamic Global Illumination for Production", Sec. 5),
bounded to a fraction of a cell, and a state (active / inactive).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..backend import dr, mi
from ..errors import DyngiError

PROBE_ACTIVE = 1
PROBE_INACTIVE = 0


@dataclass(frozen=True)
class ProbeGrid:
    origin: tuple      # world position of probe (0, 0, 0)
    spacing: tuple     # distance between neighbouring probes along x, y, z
    counts: tuple      # (nx, ny, nz), each >= 2

    def __post_init__(self):
        c = np.asarray(self.counts)
        if c.shape != (3,) or np.any(c < 2):
            raise DyngiError(f"probe counts must be three integers >= 2, got {self.counts}")
        s = np.asarray(self.spacing, np.float64)
        if s.shape != (3,) or not np.all(np.isfinite(s)) or np.any(s <= 0):
            raise DyngiError(f"probe spacing must be three positive numbers, got {self.spacing}")

    # -- construction ---------------------------------------------------------
    @staticmethod
    def from_box(lo, hi, counts) -> "ProbeGrid":
        """Grid whose corner probes sit on the corners of the box [lo, hi]."""
        lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
        counts = tuple(int(c) for c in counts)
        n = np.maximum(np.asarray(counts) - 1, 1)
        spacing = (hi - lo) / n
        return ProbeGrid(tuple(map(float, lo)), tuple(map(float, spacing)), counts)

    @staticmethod
    def from_scene(scene, counts=None) -> "ProbeGrid":
        """The scene's default probe volume (``scene.meta.probe_box``), optionally with other ``counts``."""
        lo, hi = scene.meta.probe_box
        return ProbeGrid.from_box(lo, hi, counts if counts is not None else scene.meta.probe_counts)

    # -- sizes ---------------------------------------------------------------
    @property
    def n_probes(self) -> int:
        nx, ny, nz = self.counts
        return int(nx * ny * nz)

    @property
    def spacing_np(self) -> np.ndarray:
        return np.asarray(self.spacing, np.float64)

    @property
    def min_spacing(self) -> float:
        return float(np.min(self.spacing))

    @property
    def max_spacing(self) -> float:
        return float(np.max(self.spacing))

    @property
    def cell_diagonal(self) -> float:
        """Length of a cell's diagonal (the 'probe cage diagonal' of ADGI Sec. 4.6)."""
        return float(np.linalg.norm(self.spacing))

    # -- coordinates ---------------------------------------------------------
    def probe_coords(self, index=None) -> np.ndarray:
        """(P, 3) integer grid coordinates of probe indices (all probes by default)."""
        nx, ny, _ = self.counts
        p = np.arange(self.n_probes) if index is None else np.asarray(index)
        return np.stack([p % nx, (p // nx) % ny, p // (nx * ny)], -1)

    def probe_index(self, coords) -> np.ndarray:
        c = np.asarray(coords)
        nx, ny, _ = self.counts
        return c[..., 0] + nx * (c[..., 1] + ny * c[..., 2])

    def base_positions(self) -> np.ndarray:
        """(P, 3) float64 lattice positions (without relocation offsets)."""
        return np.asarray(self.origin) + self.probe_coords() * self.spacing_np

    def positions(self, offsets=None) -> np.ndarray:
        """(P, 3) probe positions: lattice plus relocation ``offsets`` (P, 3) if given."""
        p = self.base_positions()
        return p if offsets is None else p + offsets

    # -- Dr.Jit helpers used inside kernels -----------------------------------
    def opaque_params(self):
        """(origin, spacing, inverse spacing) as opaque Dr.Jit vectors (no recompiles when they change)."""
        o = dr.opaque(mi.Vector3f, [float(v) for v in self.origin])
        s = dr.opaque(mi.Vector3f, [float(v) for v in self.spacing])
        inv = dr.opaque(mi.Vector3f, [float(1.0 / v) for v in self.spacing])
        return o, s, inv
