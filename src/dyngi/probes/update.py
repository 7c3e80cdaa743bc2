"""Former home of the probe update: :class:`ProbeUpdater` is :class:`~dyngi.probes.pipeline.ProbePipeline`.

Kept so that callers of ``dyngi.probes.update`` (``ProbeUpdater``, ``probes_in_frustum``,
``UPDATE_STAGES``) keep working; new code imports :mod:`dyngi.probes.pipeline`.
"""
from __future__ import annotations

from .pipeline import UPDATE_STAGES, WARMUP_FRAME_BASE, ProbePipeline, probes_in_frustum

ProbeUpdater = ProbePipeline

__all__ = ["ProbeUpdater", "ProbePipeline", "probes_in_frustum", "UPDATE_STAGES", "WARMUP_FRAME_BASE"]
