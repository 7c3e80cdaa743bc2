"""Per-stage wall time and ray counts, shared by techniques and the pieces they are built from."""
from __future__ import annotations

import contextlib
import time
from contextlib import contextmanager

from .backend import dr


class StageTimer:
    """Per-stage wall time (ms) and ray counts; each stage ends with ``dr.eval`` of its outputs."""

    def __init__(self):
        self.ms: dict[str, float] = {}
        self.rays: dict[str, int] = {}

    @contextmanager
    def stage(self, name: str):
        t0 = time.perf_counter()
        yield
        dr.sync_thread()
        self.ms[name] = self.ms.get(name, 0.0) + 1e3 * (time.perf_counter() - t0)

    def add_rays(self, name: str, n: int) -> None:
        self.rays[name] = self.rays.get(name, 0) + int(n)

    def as_dict(self) -> dict:
        return {"ms": dict(self.ms), "rays": dict(self.rays),
                "total_ms": float(sum(self.ms.values())), "total_rays": int(sum(self.rays.values()))}


def maybe_stage(timer: StageTimer | None, name: str):
    """``timer.stage(name)``, or a no-op context when ``timer`` is None."""
    return timer.stage(name) if timer is not None else contextlib.nullcontext()
