"""The probe pipeline (issue 23 item 1): its parts are checked against the protocols, and a planner
alone (docs/probes.md's example) makes a probe technique: warm-up, ragged plans, the scatter estimator
and relocation/classification grouped by ray count."""
import numpy as np
import pytest

from dyngi.backend import mi
from dyngi.probes import DiffuseHitShader, HysteresisBlend, ProbeGrid, ProbeQuery, ProbeStates, ProbeVolume, RayPlan
from dyngi.probes.pipeline import ProbePipeline
from dyngi.sampling.octahedral import texel_directions
from dyngi.scene import load_scene


class UpperHemisphere:
    """docs/probes.md: every probe traces ``n`` cosine-distributed rays around +y, weighted 1/pdf."""

    def __init__(self, n: int):
        self.n = n

    def counts(self, probe_ids):
        return np.full(len(probe_ids), self.n)

    def plan(self, frame, seed, probe_ids, previous=None, **hints):
        counts = self.counts(probe_ids)
        rng = np.random.default_rng([seed, frame])
        u = rng.random((int(counts.sum()), 2))
        r, phi = np.sqrt(u[:, 0]), 2 * np.pi * u[:, 1]
        cos = np.sqrt(1 - u[:, 0])
        d = np.stack([r * np.cos(phi), cos, r * np.sin(phi)], 1).astype(np.float32)
        w = (np.pi / np.maximum(cos, 1e-6)).astype(np.float32)            # 1 / pdf, pdf = cos / pi
        return RayPlan.ragged(probe_ids, counts, mi.Vector3f(*[mi.Float(d[:, k]) for k in range(3)]),
                              weight=mi.Float(w))


class WithIdleProbes(UpperHemisphere):
    """Every fourth probe traces no ray (a ragged plan: states are grouped by ray count)."""

    def counts(self, probe_ids):
        return np.where(np.asarray(probe_ids) % 4 == 0, 0, self.n)


def test_a_planner_alone_makes_a_probe_technique():
    sc = load_scene("cornell-static")
    vol = ProbeVolume(ProbeGrid.from_scene(sc, (4, 4, 4)), 8, 16)
    with pytest.raises(TypeError, match="planner"):
        ProbePipeline(vol, object(), DiffuseHitShader(), HysteresisBlend())
    pipe = ProbePipeline(vol, WithIdleProbes(32), DiffuseHitShader("sun"), HysteresisBlend(), ProbeStates(),
                         ProbeQuery(vol))
    rays = pipe.warm_up(sc, 2, seed=0)
    assert rays["trace probes"] > 0
    for f in range(2):
        info = pipe.update(sc, f, 0)
    plan = pipe.last_results.plan
    assert info["rays"] == plan.n_rays > 0
    assert vol.state.is_finite()
    idle = plan.probe_ids[plan.counts == 0]
    assert len(idle) and np.all(vol.state.updates[idle] == 0)      # no rays: no history, no texels
    assert np.all(vol.state.irradiance[idle] == 0.0)
    assert pipe.blender.last_estimator == "scatter"
    # the texels facing the ceiling light of the probes that traced are lit
    traced = plan.probe_ids[plan.counts > 0]
    up = texel_directions(8)[1:-1, 1:-1, 1] > 0.8
    assert vol.state.irradiance[traced][:, 1:-1, 1:-1][:, up].mean() > 0.0
