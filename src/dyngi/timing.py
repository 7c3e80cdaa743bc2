"""Per-stage wall time and ray counts, shared by techniques and the pieces they are built from."""
from __future__ import annotations

import contextlib
import time
from contextlib import contextmanager

import numpy as np

from .backend import dr


class StageTimer:
    """Per-stage wall time (ms) and ray counts; each stage ends with ``dr.eval`` of its outputs."""

    def __init__(self):
        self.ms: dict[str, float] = {}
        self.rays: dict[str, int] = {}
        self._lazy: list = []

    @contextmanager
    def stage(self, name: str, sync: bool = True):
        """Time a block as (part of) stage ``name``; repeated blocks add up.

        ``sync=False`` leaves the Dr.Jit kernels the block launched running
        (they finish during the next blocks, which then wait for them): for a
        stage whose kernels overlap host work of another stage. Its time counts
        where its results are waited for, so stage times still add up to the
        wall time.
        """
        t0 = time.perf_counter()
        yield
        if sync:
            dr.sync_thread()
        self.ms[name] = self.ms.get(name, 0.0) + 1e3 * (time.perf_counter() - t0)

    def add_rays(self, name: str, n) -> None:
        """Add ``n`` rays to stage ``name``: an int, or a Dr.Jit count (e.g. ``dr.count(mask)``) that is
        read only in :meth:`as_dict`, so that counting measured rays adds no wait to the stage."""
        if isinstance(n, (int, np.integer)):
            self.rays[name] = self.rays.get(name, 0) + int(n)
        else:
            self._lazy.append((name, n))

    def as_dict(self) -> dict:
        for name, n in self._lazy:
            self.rays[name] = self.rays.get(name, 0) + int(np.asarray(n).ravel()[0])
        self._lazy.clear()
        return {"ms": dict(self.ms), "rays": dict(self.rays),
                "total_ms": float(sum(self.ms.values())), "total_rays": int(sum(self.rays.values()))}


def maybe_stage(timer: StageTimer | None, name: str, sync: bool = True):
    """``timer.stage(name, sync)``, or a no-op context when ``timer`` is None."""
    return timer.stage(name, sync) if timer is not None else contextlib.nullcontext()
