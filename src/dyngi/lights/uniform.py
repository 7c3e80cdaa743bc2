"""``lights=uniform``: every emitter triangle with pmf 1/L (pbrt-v4's ``UniformLightSampler``, Sec. 12.6.1).

The smallest light sampler: the interface of :class:`~dyngi.lights.base.LightSampler`, no state, nothing
learned; a template for a new one (``docs/lights.md``)."""
from __future__ import annotations

from ..backend import dr, mi
from .base import INVALID, EmitterTable, FrameCtx, register


class UniformSelector:
    """Uniform light selection: every triangle light with pmf 1/L (``lights=uniform``)."""

    name = "uniform"

    def __init__(self, tris: EmitterTable, mi_scene=None, bounds=None, **opts):
        self.tris = tris
        self.count = tris.count

    def begin_frame(self, ctx: FrameCtx) -> None:
        self.tris = ctx.tris

    def sample(self, p, n, u, active, p_prev=None):
        active = mi.Bool(active) & (self.count > 0)
        L = max(self.count, 1)
        k = dr.minimum(mi.UInt32(mi.Float(u) * L), L - 1)
        return dr.select(active, k, mi.UInt32(INVALID)), dr.select(active, mi.Float(1.0 / L), 0.0)

    def pmf(self, p, n, light_id, active, p_prev=None):
        ok = mi.Bool(active) & (mi.UInt32(light_id) < self.count)
        return dr.select(ok, mi.Float(1.0 / max(self.count, 1)), 0.0)

    def record(self, p, n, light_id, visible, active) -> None:
        pass

    def end_frame(self) -> None:
        pass

    def stats(self) -> dict:
        return {"lights": self.count}


register("uniform", UniformSelector, "every emitter triangle with pmf 1/L")
