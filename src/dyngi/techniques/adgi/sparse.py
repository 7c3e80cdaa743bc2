"""ADGI's sparse merges: a pass's samples reduced per (probe, texel) key, and Algorithm 3 applied only to the
texels that received samples (Datta et al. 2022, Algorithms 2-4: each sample updates "the closest entry";
Algorithm 4 does it with atomics on the device).

Why: an S-stage probe holds 1-3 samples of a frame, but a dense merge builds a table over every texel of
every traced probe (36 radiance texels, 256 bordered distance texels each) and runs Algorithm 3 through the
encoding on all of them. Here the work follows the samples:

1. **keys compacted** (:meth:`SparseKeys.reduce`): each sample's key ``probe * T2 + texel`` claims an owner
   lane in a persistent per-key table by an atomic minimum (``dr.scatter_reduce(Min)``, Algorithm 4's atomic on
   the device); the owners are compacted (the frame's unique keys, ``U`` of them: ``dr.compress`` on the host
   path, :func:`~dyngi.probes.rays.compact` to a fixed width on the device path), each key's table entry is
   set to its unique index, and the samples are **reduced** into ``U`` slots with the deterministic fixed-point
   sums of :func:`~dyngi.probes.estimator.fixed_point_sum` (the same bits whatever the order of the atomics);
   the table entries are reset to "no owner" afterwards (``U`` lanes), so the table is never cleared whole;
2. **Algorithm 3 on the U texels** (:mod:`.moving_average`'s batch rule): the radiance layer's texels
   (:meth:`.radiance.RadianceUpdate.merge`) and the visibility texels through the volume's encoding, each
   written to its interior texel and to the border texels that copy it (:func:`border_copies`), and the
   probes' update counts raised as the dense merge does (:func:`merge_distance_sparse`).

The result equals the dense merge's (the same sums, the same per-texel rule; tests/techniques/adgi/
test_sparse_merge.py), at a cost that follows the samples instead of the traced probes' texels. Memory: one
UInt32 owner per key (``P x (T-2)^2`` per table: 0.8 MB per 1k probes for the 14x14 visibility interior).
"""
from __future__ import annotations

import functools

import numpy as np

from ...backend import dr, mi
from ...probes.arrays import upload
from ...probes.accumulator import pull_from
from ...probes.estimator import fixed_point_sum
from ...probes.rays import compact
from ...sampling.octahedral import border_source_index, direction_to_texel_coords

NO_OWNER = 0xFFFFFFFF


def texel_of(direction, texels: int):
    """Interior texel (row-major in the ``(T-2)^2`` interior) of an octahedral map that ``direction`` falls in
    (the binned estimator's rule: directions on the border clamp to the nearest interior texel)."""
    c = direction_to_texel_coords(direction, texels)
    ix = dr.clip(mi.Int32(dr.floor(c.x)) - 1, 0, texels - 3)
    iy = dr.clip(mi.Int32(dr.floor(c.y)) - 1, 0, texels - 3)
    return mi.UInt32(iy * (texels - 2) + ix)


@functools.lru_cache(maxsize=None)
def border_copies(texels: int) -> tuple[int, "mi.UInt32"]:
    """Per interior texel ``t`` (row-major) the bordered texels (``y * T + x``) that hold its value: the texel
    itself and the border texels that copy it (:func:`~dyngi.sampling.octahedral.border_source_index`), as a
    flat table of ``K`` entries per interior texel (``K`` = the most copies; short rows repeat the texel
    itself, which writes the same value twice). Returns ``(K, table)``."""
    T = int(texels)
    src = border_source_index(T).ravel()
    sy, sx = src // T, src % T
    interior = (sy - 1) * (T - 2) + (sx - 1)
    rows = [[] for _ in range((T - 2) ** 2)]
    for b, t in enumerate(interior):
        rows[t].append(b)
    K = max(len(r) for r in rows)
    table = np.array([r + [r[0]] * (K - len(r)) for r in rows], np.uint32)
    return K, upload(table.ravel(), mi.UInt32)


class SparseKeys:
    """The frame's (probe, texel) keys of one table (``n_keys`` = probes x interior texels) compacted and
    reduced (module docstring, step 1)."""

    def __init__(self, n_keys: int):
        self.n_keys = int(n_keys)
        self._owner = None

    @property
    def owner(self):
        if self._owner is None:         # allocated on first use (a technique without merges needs none)
            self._owner = dr.full(mi.UInt32, NO_OWNER, self.n_keys)
        return self._owner

    def reduce(self, key, values, weight, active, device: bool = False):
        """Per unique key of the active lanes: ``(ukey, u_ok, sums, sw, cnt, slot)`` -- the keys (UInt32, ``U``
        lanes; with ``device`` (no host read) the lanes' width, ``u_ok`` marking the used ones), the
        fixed-point sums of ``weight * value`` per channel and of ``weight`` (Float64), the sample counts
        (UInt32), and per lane its key's unique index ``slot`` (valid where active)."""
        owner = self.owner
        n = dr.width(key)
        lane = dr.arange(mi.UInt32, n)
        active = active & (weight > 0.0)
        # -- each key's lowest active lane owns it (an atomic minimum: Algorithm 4's atomics) --
        dr.scatter_reduce(dr.ReduceOp.Min, owner, lane, key, active, mode=dr.ReduceMode.Local)
        head = active & (dr.gather(mi.UInt32, owner, key, active) == lane)
        if device:
            heads, u_ok = compact(head, max(n, 1))
        else:
            heads = dr.compress(head)
            if dr.width(heads) == 0:        # no sample: nothing claimed (the owners are left as they were)
                dr.scatter(owner, mi.UInt32(NO_OWNER), key, active)
                dr.eval(owner)
                empty = dr.zeros(mi.UInt32, 0)
                return empty, dr.zeros(mi.Bool, 0), [dr.zeros(mi.Float64, 0) for _ in values], \
                    dr.zeros(mi.Float64, 0), empty, dr.zeros(mi.UInt32, n)
            u_ok = dr.full(mi.Bool, True, dr.width(heads))
        U = dr.width(heads)
        ukey = dr.gather(mi.UInt32, key, heads, u_ok)
        # -- the owner entry becomes the key's unique index; the samples reduce into the U slots --
        dr.scatter(owner, dr.arange(mi.UInt32, U), ukey, u_ok)
        slot = dr.gather(mi.UInt32, owner, key, active)
        sums, sw, cnt = fixed_point_sum(values, weight, slot, U, active)
        dr.eval(ukey, u_ok, sw, cnt, slot, *sums)
        dr.scatter(owner, mi.UInt32(NO_OWNER), ukey, u_ok)          # reset: U lanes, never the whole table
        dr.eval(owner)
        return ukey, u_ok, sums, sw, cnt, slot


def merge_distance_sparse(keys: SparseKeys, volume, results, accumulator, encoding, history=None,
                          device: bool = False, lazy_cap=None, frame: int = 0) -> None:
    """The distances of ``results`` (a ProbeRayResults along ``-w``) into the visibility texels they fall in:
    moments ``(|d| clamped to the volume's max distance, its square)`` reduced per (probe, texel) key, then
    the accumulator (Algorithm 3) through ``encoding`` on those texels only, written to each texel and its
    border copies. ``history`` (device UInt32 per probe): the device path's update counts (a probe with 0 has
    no history; each probe with a sample adds 1), else the host's (``volume.state.updates``). A sample of
    weight ``m`` (the static plan's multiplicity) counts ``m`` times, as the dense merge's. ``device``: no host
    read (the keys compacted to a fixed width). ``lazy_cap`` (:class:`LazyCountCap` over the interior distance
    texel keys): the outer count cap, applied to the counts read and stamped with ``frame``."""
    plan = results.plan
    if plan.n_rays == 0:
        return
    T = volume.distance_texels
    T2 = (T - 2) ** 2
    d = dr.minimum(dr.abs(results.distance), dr.opaque(mi.Float, volume.max_distance))
    active = mi.Bool(True) if plan.valid is None else plan.valid
    active = active & (d >= 0.0)
    w = (mi.Float(1.0) if plan.weight is None else plan.weight) + dr.zeros(mi.Float, plan.n_rays)
    key = plan.probe * T2 + texel_of(plan.direction, T)
    ukey, u_ok, (s1, s2), sw, cnt, _ = keys.reduce(key, [d, d * d], w, active, device=device or plan.is_masked)
    if dr.width(ukey) == 0:
        return
    probe = ukey // T2
    t = ukey - probe * T2
    inv = dr.select(sw > 0.0, dr.rcp(sw), 0.0)
    new = mi.Vector2f(mi.Float(s1 * inv), mi.Float(s2 * inv))
    m = cnt if plan.weight is None else mi.UInt32(dr.round(mi.Float(sw)))
    K, copies = border_copies(T)
    TT = T * T
    centre = probe * TT + dr.gather(mi.UInt32, copies, t * K)       # the interior texel itself (row's first)
    dev = volume.device
    old = dr.gather(mi.Vector2f, dev.distance, centre, u_ok)
    n_old = dr.gather(mi.UInt32, dev.distance_count, centre, u_ok)
    if lazy_cap is not None:
        n_old = lazy_cap.count(n_old, ukey, probe, u_ok)
    if history is not None:
        fresh = dr.gather(mi.UInt32, history, probe, u_ok) == 0
    else:
        fresh = dr.gather(mi.UInt32, upload((volume.state.updates == 0).astype(np.uint32), mi.UInt32),
                          probe, u_ok) != 0
    val, c = accumulator.distance(old, new, n_old, m, fresh, int(encoding.count_max))
    ref = dr.select(fresh, val, old) if getattr(accumulator, "keeps_history", True) else None
    val, c = encoding.roundtrip_distance(val, c, dr.opaque(mi.Float, volume.grid.cell_diagonal), ref)
    ok = u_ok & dr.all(dr.isfinite(new))
    val = dr.select(ok, val, old)
    c = dr.select(ok, mi.UInt32(c), n_old)
    dr.eval(val, c, ok)
    # the gathers of the atlas must not outlive this point: a pending read of an array makes the scatter into it
    # copy the whole array first (at 98k probes 200 MB per merge)
    del old, n_old, ref
    if lazy_cap is not None:
        lazy_cap.touched(ukey, ok, frame)
    for k in range(K):
        g = probe * TT + dr.gather(mi.UInt32, copies, t * K + k)
        dr.scatter(dev.distance, val, g, ok)
        dr.scatter(dev.distance_count, c, g, ok)
    dr.eval(dev.distance, dev.distance_count)
    volume.state.device_is_newer(pull_from(dev))


class LazyCountCap:
    """Sec. 4.8's ``N <- min(N, cap)`` for the probes of ``V_out - V_in``, applied lazily at merge: per probe
    the last frame it was in ``V_out - V_in`` (``outer``, frame + 1; 0: never), per texel key the frame of its
    last update (``stamp``, frame + 1). A merge reads a texel's count as ``min(N, cap)`` where the probe was
    in ``V_out - V_in`` on or after the frame of the texel's last update (the eager cap runs after a frame's
    updates, so a frame's own cap counts for texels updated in it), which is what an eager cap of every such
    probe's texels at the end of every frame would have stored. The frame's work: a scatter over the probes of
    ``V_out - V_in`` and two gathers per merged key, instead of passes over every texel of the grid. Readers
    other than the merges (the convolution's counts) see the uncapped N; only the merges' Algorithm 3 uses
    it."""

    def __init__(self, n_probes: int, n_keys: int, cap: int):
        self.cap = int(cap)
        self.outer = dr.zeros(mi.UInt32, int(n_probes))
        self.stamp = dr.zeros(mi.UInt32, int(n_keys))
        dr.make_opaque(self.outer, self.stamp)

    def count(self, n_old, key, probe, active):
        """The counts ``n_old`` of texel keys ``key`` (of ``probe``) as the merge reads them."""
        o = dr.gather(mi.UInt32, self.outer, probe, active)
        s = dr.gather(mi.UInt32, self.stamp, key, active)
        return dr.select((o > 0) & (o >= s), dr.minimum(n_old, self.cap), n_old)

    def touched(self, key, active, frame: int) -> None:
        """The keys ``key`` (where ``active``) were updated on ``frame``."""
        dr.scatter(self.stamp, dr.opaque(mi.UInt32, int(frame) + 1), key, active)

    def mark_outer(self, probe_ids: np.ndarray, frame: int) -> None:
        """The probes ``probe_ids`` (host) are in ``V_out - V_in`` on ``frame`` (after its updates)."""
        if len(probe_ids):
            dr.scatter(self.outer, dr.opaque(mi.UInt32, int(frame) + 1),
                       upload(np.asarray(probe_ids, np.uint32), mi.UInt32))
            dr.eval(self.outer)
