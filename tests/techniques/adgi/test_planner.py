"""ADGI's chain planner under a budget (Sec. 4.9 with our budget rule): the dynamic budget keeps the
highest-guide proxy octants first (a scripted guide), the device counting sort against a NumPy brute
force, and repeated Metropolis states traced once with their multiplicity (against a NumPy brute force)."""
import numpy as np
import pytest

from dyngi.backend import dr, mi


@pytest.fixture()
def planner(backend):
    from dyngi.techniques.adgi import planner
    return planner


def _params(**kw):
    from dyngi.sampling.metropolis import ADGI_DIRECTION_STEP
    p = {"position_step": 0.5, "direction_step": ADGI_DIRECTION_STEP, "burn_in": 4, "iterations": 20,
         "dynamic_position_scale": 3.0, "dynamic_direction_scale": 6.0, "static_chains": 64,
         "dynamic_chains": 1024, "guide_mip": 1, "dynamic_rays": 16}
    p.update(kw)
    return p


def test_budget_keep_matches_a_sort(planner):
    """Highest key first, ties in index order, whole items while the budget lasts: equal to a stable
    host sort + cumulative sum (the reference), on random keys, costs and budgets."""
    rng = np.random.default_rng(3)
    for trial in range(4):
        n = 300
        key = rng.integers(0, 16, n).astype(np.uint32)
        cost = rng.integers(0, 50, n).astype(np.uint32)
        budget = int(rng.integers(0, int(cost.sum()) + 1))
        got = np.asarray(planner.budget_keep(mi.UInt32(key), mi.UInt32(cost), dr.opaque(mi.UInt32, budget), 16))
        # reference: levels in descending key, whole levels while they fit, then the boundary level in order
        want = np.zeros(n, bool)
        spent = 0
        for k in range(15, -1, -1):
            sel = np.flatnonzero(key == k)
            tot = int(cost[sel].sum())
            if spent + tot <= budget:
                want[sel] = True
                spent += tot
                continue
            for i in sel:                      # the boundary level: index order while the budget lasts
                if spent + int(cost[i]) <= budget:
                    want[i] = True
                    spent += int(cost[i])
                else:
                    break
            break
        assert np.array_equal(got, want), trial
        assert cost[got].sum() <= budget


def test_multiplicity_counts_repeated_states(planner):
    """Lane ``j * n + c``: a head (j = 0 or accepted) carries 1 + the rejected moves after it, others 0;
    the multiplicities of each chain sum to its samples."""
    rng = np.random.default_rng(5)
    n, S = 37, 9
    acc = rng.random(n * S) < 0.4
    got = np.asarray(planner.multiplicity(mi.Bool(acc), n, S))
    a = acc.reshape(S, n)
    want = np.zeros((S, n), np.int64)
    for c in range(n):
        head = 0
        for j in range(S):
            if j == 0 or a[j, c]:
                head = j
            want[head, c] += 1
    assert np.array_equal(got.reshape(S, n), want)
    assert np.all(got.reshape(S, n).sum(0) == S)


def test_dynamic_budget_takes_the_highest_guide_first(planner):
    """A scripted f_d on a 9^3 grid (3^3 proxies): every octant 0.05, three proxy octants 1.0, two 0.5.
    A budget for four octants traces exactly the three 1.0 octants and the first 0.5 one (index order),
    not the first four octants the chains marked; without a budget every marked octant traces."""
    from dyngi.probes import ProbeGrid, ProbeVolume
    from dyngi.techniques.adgi.heuristics import OCTANTS, octant_of_np
    vol = ProbeVolume(ProbeGrid((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), (9, 9, 9)), 8, 16)
    pl = planner.ADGIChainPlanner(vol, _params())
    P = vol.n_probes
    fd = np.full((P, OCTANTS), 0.05, np.float32)
    ijk = np.stack(np.meshgrid(np.arange(9), np.arange(9), np.arange(9), indexing="ij"), -1)
    pid = (ijk[..., 0] + 9 * (ijk[..., 1] + 9 * ijk[..., 2])).ravel()
    proxy = ((ijk[..., 0] // 3) + 3 * ((ijk[..., 1] // 3) + 3 * (ijk[..., 2] // 3))).ravel()
    proxy_of = np.empty(P, np.int64)
    proxy_of[pid] = proxy
    high = [(26, 7), (13, 0), (5, 3)]          # (proxy, octant): late indices, so index order would miss them
    mid = [(20, 6), (21, 2)]                   # entry 20*8+6 = 166 < 21*8+2 = 170: the first in index order
    for (q, o), v in [(e, 1.0) for e in high] + [(e, 0.5) for e in mid]:
        fd[proxy_of == q, o] = v
    vin = mi.Float(np.ones(P, np.float32))
    R = 16
    per_octant = 27 * R
    plan = pl.plan(0, 7, stage="dynamic", vin=vin, fd=mi.Float(fd.ravel()), rays=2.0 * per_octant * 4.5,
                   shadow_rate=0.0)
    assert pl.last_samples > 20                # many octants were marked: the budget had to choose
    ray_probe = np.repeat(np.asarray(plan.probe_ids), np.asarray(plan.counts))
    d = np.stack([np.asarray(c) for c in (plan.direction.x, plan.direction.y, plan.direction.z)], -1)
    traced = set(zip(proxy_of[ray_probe].tolist(), octant_of_np(d).tolist()))
    assert traced == set(high) | {mid[0]}, sorted(traced)
    assert plan.n_rays == 4 * per_octant
    pl2 = planner.ADGIChainPlanner(vol, _params())
    free = pl2.plan(0, 7, stage="dynamic", vin=vin, fd=mi.Float(fd.ravel()), rays=None)
    assert free.n_rays == pl2.last_samples * per_octant > plan.n_rays
