"""``lights=power``: an emitter triangle with probability proportional to its power, luminance x area x pi
(pbrt-v4's ``PowerLightSampler``, Sec. 12.6.2); the same for every shading point. The table is rebuilt
on the host in ``begin_frame`` (an animated light changes its area), same size, so nothing recompiles."""
from __future__ import annotations

import numpy as np

from ..backend import dr, mi
from .emitter_table import INVALID
from .base import register


class PowerSampler:
    """pmf(k) = power_k / sum(power); uniform where every power is 0."""

    name = "power"

    def __init__(self, tris, mi_scene=None, bounds=None):
        self.tris = tris
        self.count = int(tris.count)
        self._upload()

    def _upload(self):
        pw = np.maximum(self.tris.host_arrays()["power"], 0.0) if self.count else np.zeros(0)
        if self.count and pw.sum() <= 0:
            pw = np.ones_like(pw)
        pmf = pw / pw.sum() if self.count else np.zeros(0)
        pad = np.concatenate([pmf, np.zeros(max(0, 2 - pmf.size))])   # >= 2 entries: never a literal
        self.table = mi.DiscreteDistribution(mi.Float(np.where(pad > 0, pad, 0.0).astype(np.float32)
                                                      if pad.sum() > 0 else np.ones(2, np.float32)))
        self.pmf_by_id = mi.Float(pad.astype(np.float32))

    def begin_frame(self, ctx) -> None:
        self.tris = ctx.tris
        self._upload()

    def sample(self, p, n, u, active, p_prev=None):
        active = mi.Bool(active) & (self.count > 0)
        k = self.table.sample(mi.Float(u), active)
        pmf = dr.gather(mi.Float, self.pmf_by_id, k, active)
        ok = active & (pmf > 0.0)
        return dr.select(ok, k, mi.UInt32(INVALID)), dr.select(ok, pmf, 0.0)

    def pmf(self, p, n, light_id, active, p_prev=None):
        light_id = mi.UInt32(light_id)
        ok = mi.Bool(active) & (light_id < self.count)
        return dr.select(ok, dr.gather(mi.Float, self.pmf_by_id, light_id, ok), 0.0)

    def record(self, p, n, light_id, visible, active) -> None:
        """Power sampling learns nothing."""

    def end_frame(self) -> None:
        pass

    def stats(self) -> dict:
        return {"lights": self.count}


register("power", PowerSampler, "emitter triangle with pmf proportional to its power (pbrt-v4 12.6.2)")
