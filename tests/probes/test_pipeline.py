"""The probe pipeline: its parts are checked against the protocols, and a planner
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


def test_masked_plan_merges_as_its_host_plan():
    """A masked plan (``RayPlan.masked``: fixed width, invalid lanes, device slots) merged with
    ``ProbePipeline.merge_slots`` gives the atlases, counts and update counts of the same rays as a ragged host
    plan merged with ``merge`` (scatter estimator, bin mode; synthetic radiance, no tracing); ``compact`` packs
    the active lanes in order into a fixed capacity and drops those past it."""
    from dyngi.backend import dr
    from dyngi.probes.estimator import ScatterEstimator
    from dyngi.probes.rays import compact
    from dyngi.probes.trace import ProbeRayResults

    idx, ok = compact(mi.Bool([False, True, True, False, True]), 4)
    assert list(np.asarray(idx)[np.asarray(ok)]) == [1, 2, 4] and not np.asarray(ok)[3]
    idx, ok = compact(mi.Bool([True, True, True]), 2)
    assert list(np.asarray(idx)) == [0, 1] and np.all(np.asarray(ok))

    sc = load_scene("cornell-static")
    rng = np.random.default_rng(3)
    probe = np.sort(rng.choice([1, 5, 6, 20], 40)).astype(np.uint32)
    d = rng.normal(size=(40, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    L = rng.random((40, 3)).astype(np.float32)
    dist = rng.uniform(-0.2, 1.5, 40).astype(np.float32)
    vols = []
    for masked in (False, True):
        vol = ProbeVolume(ProbeGrid.from_scene(sc, (3, 3, 3)), 8, 16)
        pipe = ProbePipeline(vol, WithIdleProbes(1), DiffuseHitShader(), HysteresisBlend(0.9))
        if masked:    # the same rays among invalid lanes (garbage directions), in another order
            perm = rng.permutation(60)
            pr = np.zeros(60, np.uint32)
            dd = rng.normal(size=(60, 3))
            LL, DD = np.ones((60, 3), np.float32), np.ones(60, np.float32)
            valid = np.zeros(60, bool)
            pr[perm[:40]], dd[perm[:40]], LL[perm[:40]], DD[perm[:40]], valid[perm[:40]] = probe, d, L, dist, True
            plan = RayPlan.masked(mi.UInt32(pr), mi.Vector3f(*dd.T.astype(np.float32)), mi.Bool(valid), vol.n_probes)
            res = ProbeRayResults(mi.Color3f(*LL.T), mi.Float(DD), plan)
        else:
            ids, counts = np.unique(probe, return_counts=True)
            plan = RayPlan.ragged(ids, counts, mi.Vector3f(*d.T.astype(np.float32)))
            res = ProbeRayResults(mi.Color3f(*L.T), mi.Float(dist), plan)
        est = ScatterEstimator(50.0, "bin")
        ei, ed = est.irradiance(vol, res), est.distance(vol, res)
        for _ in range(2):     # the second merge blends with the first (history)
            if masked:
                pipe.merge_slots(ei, ed, plan.probe_ids, plan.slot_valid)
                pipe.history_to_host()
            else:
                pipe.merge(ei, ed, plan.probe_ids, plan.counts)
        dr.eval()
        vols.append(vol.state)
    a, b = vols
    assert np.array_equal(a.updates, b.updates) and a.updates[[1, 5, 6, 20]].min() == 2 and a.updates.sum() == 8
    for name in ("irradiance", "distance", "irradiance_count", "distance_count"):
        assert np.allclose(getattr(a, name), getattr(b, name), rtol=1e-6, atol=1e-7), name
