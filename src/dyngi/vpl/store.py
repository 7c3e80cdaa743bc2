"""The VPL store: one slot per VPL of the budget I (Hedman et al. 2017, Sec. 3).

Host (NumPy) arrays, one row per slot; a slot is ``used`` or empty. A VPL is a
point ``y`` on a diffuse surface with normal ``n`` (the side it was reached
from), diffuse ``albedo``, ``radiosity`` L(y) (outgoing radiance of the diffuse
surface, RGB: light reflected at least once, never its own emission), surface
``density`` p(y) (per unit area, Eq. 7) and a ``mailbox`` point (with its normal)
that both the camera and the VPL saw (Sec. 3.2.2), and a per-VPL ``seed`` for its
radiosity estimate (Sec. 3.2.3). ``sel_radiosity`` is the estimate the selection
steps see (Algorithm 1, lines 7, 9-16: stream 0 of the seed); ``radiosity`` the
one shading uses (line 18: ``smcir`` traces it with an independent stream,
:func:`dyngi.vpl.radiosity.stream_seeds`, so that the selection does not bias it).
Its *intensity* is I(y) = lum(L_sel(y)) / p(y) (Eq. 6), lum the Rec. 709 luminance
(:func:`dyngi.color.luminance`; the paper names no weighting: our choice).

Shading sums ``flux_i * G * V`` with ``flux_i = L_i / (I p_i)`` (Eq. 5 with the
camera path fixed at the primary hit; :mod:`dyngi.vpl.shading`). Techniques that
do not estimate a density (``ir``: photons) store ``density`` so that ``flux`` is
their own weight (``ir``: p = N_photons / I, so flux = L / N_photons).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..color import luminance


@dataclass
class VPLStore:
    capacity: int
    pos: np.ndarray = field(default=None)
    nrm: np.ndarray = field(default=None)
    albedo: np.ndarray = field(default=None)
    radiosity: np.ndarray = field(default=None)
    density: np.ndarray = field(default=None)
    mailbox: np.ndarray = field(default=None)
    mailbox_n: np.ndarray = field(default=None)
    seed: np.ndarray = field(default=None)
    used: np.ndarray = field(default=None)
    sel_radiosity: np.ndarray = field(default=None)

    FIELDS = ("pos", "nrm", "albedo", "radiosity", "density", "mailbox", "mailbox_n", "seed", "used",
              "sel_radiosity")

    def __post_init__(self):
        c = int(self.capacity)
        z3 = lambda: np.zeros((c, 3), np.float32)  # noqa: E731
        for k in ("pos", "nrm", "albedo", "radiosity", "mailbox", "mailbox_n", "sel_radiosity"):
            if getattr(self, k) is None:
                setattr(self, k, z3())
        if self.density is None:
            self.density = np.ones(c, np.float64)
        if self.seed is None:
            self.seed = np.zeros(c, np.uint64)
        if self.used is None:
            self.used = np.zeros(c, bool)

    @property
    def count(self) -> int:
        return int(self.used.sum())

    def intensity(self) -> np.ndarray:
        """I(y) = lum(L_sel(y)) / p(y) (Eq. 6) with the selection estimate; 0 for empty slots."""
        lum = luminance(self.sel_radiosity)
        return np.where(self.used, lum / np.maximum(self.density, 1e-30), 0.0)

    def flux(self, budget: int | None = None) -> np.ndarray:
        """Per-slot shading weight L / (I p) (Eq. 5), RGB float32; 0 for empty slots."""
        n = float(budget or self.capacity)
        f = self.radiosity.astype(np.float64) / (n * np.maximum(self.density, 1e-30))[:, None]
        return np.where(self.used[:, None], f, 0.0).astype(np.float32)

    def put(self, slots: np.ndarray, **cols) -> None:
        """Write rows ``slots`` from ``cols`` (same names as the fields) and mark them used."""
        for k, v in cols.items():
            getattr(self, k)[slots] = v
        self.used[slots] = True

    def clear(self, slots: np.ndarray) -> None:
        self.used[slots] = False
        self.radiosity[slots] = 0.0
        self.sel_radiosity[slots] = 0.0

    def copy(self) -> "VPLStore":
        return VPLStore(self.capacity, **{k: getattr(self, k).copy() for k in self.FIELDS})
