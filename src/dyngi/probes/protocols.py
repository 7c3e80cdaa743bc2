"""The five parts of a probe update, as declared interfaces (``typing.Protocol``).

DESIGN names one probe-volume update: **ray planner -> tracer/shader -> estimator -> temporal
accumulator -> encoding**. :class:`~dyngi.probes.pipeline.ProbePipeline` runs them in that order
(Majercik et al., JCGT 2019, Sec. 3: rays per probe, shading of the hits, per-texel blend), plus
the shared warm-up and the state update (relocation/classification, Majercik et al., JCGT 2021,
Sec. 5). Every probe technique of the DDGI family builds one pipeline from parts that satisfy
these protocols; a new technique replaces a part, not the loop.

* :class:`RayPlanner` -- which rays each probe traces this frame (:mod:`.rays`; ADGI's chains,
  IS-DDGI's allocation). Returns a :class:`~dyngi.probes.rays.RayPlan`.
* :class:`HitShader` -- radiance leaving the hit of a probe ray towards the probe
  (:class:`~dyngi.probes.trace.DiffuseHitShader`; the DDGI+ and IS-DDGI shaders). Tracing itself is
  the pipeline's (:meth:`ProbePipeline.trace`, the one caller of ``trace_probe_rays``).
* :class:`Estimator` -- this frame's rays -> per-texel means and counts (:mod:`.estimator`).
* :class:`TemporalAccumulator` -- merge of those means with the stored texels (:mod:`.accumulator`).
* :class:`Encoding` -- how a texel is stored (:mod:`.encoding`): ``roundtrip`` = ``load(store(.))``.

A :class:`Blend` is an estimator + an accumulator + an encoding (:mod:`.blend`); the pipeline calls
``blend.update(volume, results)``. Optional hooks a part may have (the pipeline calls them when
present): ``RayPlanner.begin_warmup()`` / ``end_warmup()`` (around the shared warm-up, e.g.
IS-DDGI's one-ray-per-set warm-up); ``HitShader.prepare(plan)`` before a trace and ``prepare(None)``
after (IS-DDGI's per-ray shading keys); ``Blend.update(volume, results, distance_results)`` for
blends fed by a separate distance plan (the reference's cosine-power lobe rays).

Several traces in one update (ADGI: pilot rays, static and dynamic Metropolis chains, each merged with
its own count cap) are a :class:`MultiPassPlanner` and a :class:`PassAccumulator` of the pipeline
(:meth:`~dyngi.probes.pipeline.ProbePipeline.update_passes`): the planner yields passes
(:class:`~dyngi.probes.pipeline.ProbePass`), the pipeline traces each and the accumulator merges it into
the volume's texels; the planner sees each pass's results before it plans the next.
"""
from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class RayPlanner(Protocol):
    """Rays of this frame for the probes ``probe_ids``.

    ``previous`` is the :class:`~dyngi.probes.trace.ProbeRayResults` of the pipeline's previous
    update (None on the first); ``hints`` are technique-specific planning inputs the pipeline passes
    through unchanged (IS-DDGI: ``importance`` per probe and ``n_rays``, the budget's ray total).
    A planner that takes no hints ignores them (accept ``**hints``).
    """

    def plan(self, frame: int, seed: int, probe_ids: np.ndarray, previous=None, **hints) -> Any: ...


@runtime_checkable
class HitShader(Protocol):
    """``shade(scene, ray, si, sampler, query, active) -> (L, hit, front, shadow)``: Dr.Jit radiance
    towards the probe, hit and front-face masks and the NEE shadow-ray mask (counted as rays)."""

    def shade(self, scene, ray, si, sampler, query, active): ...


@runtime_checkable
class Estimator(Protocol):
    """This frame's rays -> :class:`~dyngi.probes.estimator.TexelEstimate` per atlas."""

    name: str

    def irradiance(self, volume, results): ...

    def distance(self, volume, results): ...


@runtime_checkable
class TemporalAccumulator(Protocol):
    """Per texel: ``(old, new mean, old count, new samples m, fresh, cap) -> (value, count)`` (Dr.Jit)."""

    name: str

    def irradiance(self, old, new, n_old, m, fresh, cap: int): ...

    def distance(self, old, new, n_old, m, fresh, cap: int): ...


@runtime_checkable
class Encoding(Protocol):
    """Texel storage: what a texel holds after storing (``load(store(.))``), Dr.Jit."""

    name: str
    count_max: int

    def roundtrip_irradiance(self, rgb, count, old=None): ...

    def roundtrip_distance(self, mom, count, diagonal, old=None): ...


@runtime_checkable
class Blend(Protocol):
    """Estimator + accumulator + encoding: merges a trace's results into the volume in place."""

    accumulator: TemporalAccumulator
    encoding: Encoding

    def update(self, volume, results, *distance_results) -> None: ...


@runtime_checkable
class MultiPassPlanner(Protocol):
    """A planner of several passes per update (a :class:`RayPlanner` too: its ``plan`` plans the warm-up's
    single-pass updates).

    ``passes(frame, timer)`` is a generator over one frame (``frame`` a
    :class:`~dyngi.techniques.base.Frame`): it yields :class:`~dyngi.probes.pipeline.ProbePass` es and
    receives, for each, what running it gave (a :class:`~dyngi.probes.pipeline.PassResult` for a trace, the
    state counts of a re-test, the accumulator's return value of an accumulator step); its return value is
    the update's counts. It may time its passes (a timer stage around a ``yield``)."""

    def plan(self, frame: int, seed: int, probe_ids: np.ndarray, previous=None, **hints) -> Any: ...

    def passes(self, frame, timer=None): ...


@runtime_checkable
class PassAccumulator(Protocol):
    """Merges a pass into the volume: ``accumulate(pipeline, probe_pass, results, distance_results)``
    (through the pipeline's :meth:`~dyngi.probes.pipeline.ProbePipeline.merge` /
    :meth:`~dyngi.probes.pipeline.ProbePipeline.merge_slots`, with its own accumulator and encoding); for a
    pass without a plan (``results`` None) an accumulator step whose return value goes to the planner.
    Optional hook: ``end_warmup(pipeline, results)`` with the warm-up's last rays."""

    def accumulate(self, pipeline, probe_pass, results, distance_results): ...


PARTS = {"planner": RayPlanner, "shader": HitShader, "estimator": Estimator,
         "accumulator": TemporalAccumulator, "encoding": Encoding}
"""The five parts DESIGN names, by name (docs/probes.md)."""

MULTIPASS = {"multipass": MultiPassPlanner, "pass accumulator": PassAccumulator}
"""The two parts of a multi-pass update (ADGI), by name."""


def check_part(kind: str, part) -> None:
    """Raise a TypeError naming the missing interface when ``part`` does not satisfy the protocol ``kind``."""
    proto = PARTS.get(kind) or MULTIPASS.get(kind) or Blend
    if not isinstance(part, proto):
        raise TypeError(f"probe pipeline: {type(part).__name__} is no {kind} (needs {proto.__name__}: "
                        f"{', '.join(n for n in dir(proto) if not n.startswith('_'))})")
