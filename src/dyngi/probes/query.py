"""Irradiance query of a probe volume, usable inside any Dr.Jit kernel.

Follows DDGI's shading query (Majercik et al., JCGT 2019, Sec. 4 and its
reference GLSL; biases as in Majercik et al., JCGT 2021, Sec. 4):

1. bias the shading point: ``x' = x + normal_bias * n + view_bias * wo``
   (both in units of the smallest probe spacing; ``wo`` points to the viewer);
2. trilinear weights over the 8 probes of the cell containing ``x'``;
3. per probe: the smooth back-face ("wrap") weight ``((dot(dir_to_probe, n) + 1) / 2)^2 + 0.2``;
   Chebyshev visibility from the distance moments read in the direction from
   the probe to ``x'`` (one-sided, ``max(p^3, 0.05)`` as in the reference code);
   weights under 0.2 are crushed (``w * w^2 / 0.2^2``); inactive probes get 0;
4. the irradiance texels are read bilinearly in the lookup direction (the
   normal, or any direction for glossy lookups) and blended by the weights.

5. **fallback** (our choice; the DDGI papers and the RTXGI SDK return the
   zero-weight blend, i.e. black): when the 8 weights sum to (nearly) zero --
   all 8 probes inactive, as behind a thin wall whose probes were all
   classified away -- the lookup reads the ``FALLBACK_PROBES`` active probes
   nearest to the cell's centre instead, weighted by the wrap weight times
   the inverse squared distance to ``x'`` times the corners' Chebyshev factor;
   a candidate that the corners' visibility test would reject -- ``x'`` farther
   than its stored mean distance, that mean short of the distance clamp (a
   surface stored in between) and ``p^3`` at or below the floor
   (:data:`CHEBYSHEV_FLOOR`), i.e. behind a wall as seen from it -- gets no
   weight at all (issue 22: without the test, the nearest active probes of a
   cell inside a sealed room were those on the sunlit roof). A lane none of
   whose candidates is visible gets 0 (black), as the papers' blend does. The
   test reads the candidate's own moments towards ``x'``, so it means the same
   outside the cell as inside it. The candidate table (per cell,
   built on the host with a k-d tree) is rebuilt only when the probe states
   change (:meth:`ProbeQuery.fallback_table`); in the kernel it is
   a second symbolic loop that only the lanes needing it enter.

The result is the irradiance ``E`` (W/m^2); the stored texels hold ``E / pi``
(see :mod:`dyngi.probes.volume`). Interpolation is linear in ``E`` (DDGI's
optional perceptual "gamma" interpolation is not used: it biases the mean).

**Stochastic filtering** (``sampler=`` given): step 4 is replaced by one texel
of one probe, the probe drawn with probability ``w_i / sum w`` (weighted
reservoir sampling over the 8 corners with one uniform number, rescaled after
each decision) and the texel of its bilinear footprint drawn with the
bilinear weights -- stochastic texture filtering (Pharr, Wronski, Salvi and
Fajardo, "Filtering After Shading With Stochastic Texture Filtering", I3D
2024, Sec. 3). The expectation is exactly the filtered value of step 4 for
the same weights (which are still computed from the bilinearly filtered
distance moments), so a consumer that averages many lookups -- the probe
update, whose texels average hundreds of ray hits and ~1/(1-hysteresis)
frames -- converges to the same probes while reading 1 instead of 32
irradiance texels per lookup. The fallback of step 5 draws its probe the same
way, so the stochastic lookup keeps the filtered value as its expectation.
"""
from __future__ import annotations

import numpy as np

from ..backend import dr, mi
from ..sampling.octahedral import direction_to_texel_coords
from .arrays import upload
from .volume import ProbeVolume

WRAP_OFFSET = 0.2          # constant added to the wrap weight so back-side probes still count a little
CHEBYSHEV_FLOOR = 0.05     # lower bound of the Chebyshev visibility factor
CRUSH_THRESHOLD = 0.2      # weights below this are crushed towards zero
MIN_WEIGHT = 1e-6
ONE_MINUS_EPS = 0.99999994   # largest float32 below 1
FALLBACK_WEIGHT = 1e-20      # a cell whose 8 weights sum to at most this falls back to the nearest active probes
FALLBACK_PROBES = 4          # active probes per cell that the fallback reads
FALLBACK_MIN_DISTANCE = 0.01  # floor of the fallback's inverse-distance weight, in units of the smallest spacing
FALLBACK_OPEN = 0.999        # a candidate's stored mean distance at this fraction of the clamp: no wall that way


def bilinear_gather(atlas, probe, coords, texels: int, channels: int):
    """Bilinear read of a bordered probe square: ``atlas`` flat Float, ``probe`` UInt32, ``coords`` texel coords.

    Returns a Vector2f (2 channels) or Color3f (3 channels). Unmasked: masked
    gathers made the query slower in Dr.Jit's LLVM backend (docs/techniques/ddgi.md),
    so callers point lanes they do not need at a valid, cached texel instead.
    """
    cls = mi.Color3f if channels == 3 else mi.Vector2f
    x = coords.x - 0.5
    y = coords.y - 0.5
    x0f = dr.clip(dr.floor(x), 0.0, texels - 2.0)
    y0f = dr.clip(dr.floor(y), 0.0, texels - 2.0)
    fx = dr.clip(x - x0f, 0.0, 1.0)
    fy = dr.clip(y - y0f, 0.0, 1.0)
    # integer clamps too: whatever float reaches here, no index leaves the probe's square
    x0 = dr.minimum(mi.UInt32(x0f), texels - 2)
    y0 = dr.minimum(mi.UInt32(y0f), texels - 2)
    base = probe * (texels * texels) + y0 * texels + x0
    v00 = dr.gather(cls, atlas, base)
    v01 = dr.gather(cls, atlas, base + 1)
    v10 = dr.gather(cls, atlas, base + texels)
    v11 = dr.gather(cls, atlas, base + texels + 1)
    return dr.lerp(dr.lerp(v00, v01, fx), dr.lerp(v10, v11, fx), fy)


class ProbeQuery:
    """Irradiance lookup in a :class:`ProbeVolume` (reads the volume's *current* device mirror).

    Parameters
    ----------
    normal_bias : float = 0.05   offset along the normal, in units of the smallest probe spacing
    view_bias : float = 0.2      offset towards the viewer, same units
    visibility : bool = True     Chebyshev visibility test
    wrap : bool = True           smooth back-face weighting
    unroll : bool = False        unroll the 8 corners in Python (default: one symbolic Dr.Jit loop; same
                                 kernel speed, 4x less time spent tracing the kernel per call)

    :meth:`irradiance` filters the 8 probes x 4 texels (DDGI), or, given a
    ``sampler``, reads one stochastically chosen texel with the same
    expectation (see the module docstring).
    """

    def __init__(self, volume: ProbeVolume, normal_bias: float = 0.05, view_bias: float = 0.2,
                 visibility: bool = True, wrap: bool = True, unroll: bool = False):
        self.volume = volume
        self.normal_bias = float(normal_bias)
        self.view_bias = float(view_bias)
        self.visibility = bool(visibility)
        self.wrap = bool(wrap)
        self.unroll = bool(unroll)
        self._fb_key = None      # the probe states the fallback table was built for
        self._fb_table = None
        self.fallback_table()    # built here, outside any kernel being recorded

    def fallback_table(self):
        """Per grid cell, the ``FALLBACK_PROBES`` active probes nearest to the cell's centre (flat UInt32,
        ``cell * FALLBACK_PROBES + j``, cells numbered like probes with ``counts - 1``) for the cells whose
        8 corners are all inactive; for the others their own live corners (used only where all of them
        have zero trilinear weight).

        Built on the host (k-d tree over the active probes' positions) and cached
        until the probe states change; relocation alone (offsets under half a
        cell) does not rebuild it, the kernel weighs the candidates at their
        current positions. Same size every time, so kernels reading it do not
        recompile. Fewer active probes than ``FALLBACK_PROBES``: the nearest one
        repeats; none: every entry is probe 0, which is inactive and carries no
        weight.
        """
        vol = self.volume
        states = vol.state.states
        if self._fb_table is not None and np.array_equal(self._fb_key, states):
            return self._fb_table
        key = states.copy()
        g = vol.grid
        cx, cy, cz = (int(c) - 1 for c in g.counts)
        K = FALLBACK_PROBES
        cell = np.arange(cx * cy * cz)
        cc = np.stack([cell % cx, (cell // cx) % cy, cell // (cx * cy)], -1)
        table = np.zeros((len(cell), K), np.uint32)
        # cells with a live corner reach the fallback only when all live corners have zero trilinear
        # weight (the point on a face of the cell): their candidates are those live corners themselves
        corners = np.stack([g.probe_index(cc + [(c & 1), (c >> 1) & 1, (c >> 2) & 1]) for c in range(8)], 1)
        live = states[corners] != 0
        some = live.any(1)
        rank = np.argsort(~live, axis=1, kind="stable")[:, :K]          # live corners first, in corner order
        n_live = np.minimum(live.sum(1), K)
        pick = np.where(np.arange(K)[None, :] < n_live[:, None], rank, rank[:, :1])   # repeat the first live one
        table[some] = np.take_along_axis(corners, pick, 1)[some]
        # cells without one: the active probes nearest to the cell's centre
        act = np.flatnonzero(states != 0)
        dead = np.flatnonzero(~some)
        if len(act) and len(dead):
            from scipy.spatial import cKDTree

            centres = np.asarray(g.origin) + (cc[dead] + 0.5) * g.spacing_np
            k = min(K, len(act))
            _, nn = cKDTree(vol.positions()[act]).query(centres, k)
            nn = np.asarray(nn).reshape(len(dead), k)
            table[dead, :k] = act[nn]
            table[dead, k:] = act[nn[:, :1]]
        self._fb_table = upload(table, mi.UInt32)
        self._fb_key = key
        return self._fb_table

    def irradiance(self, pos, normal, wo, direction=None, active=True, sampler=None):
        """Irradiance ``E`` (Color3f) at ``pos`` for a surface with ``normal`` seen from ``wo`` (towards viewer).

        ``direction`` (default: ``normal``) selects the octahedral texel read;
        pass another direction to read the irradiance field around it (e.g. a
        reflection direction for glossy lookups, as in DDGI Resampling).
        ``sampler`` (a ``mi.Sampler``, 3 dimensions drawn): stochastic
        filtering -- one texel of one probe, unbiased for the filtered value.
        """
        vol = self.volume
        dev = vol.device
        g = vol.grid
        nx, ny, nz = (int(c) for c in g.counts)
        origin, spacing, inv_spacing = g.opaque_params()
        scale = g.min_spacing
        lookup = normal if direction is None else direction
        # lanes with a non-finite input (misses; a NaN shading normal of a degenerate triangle) become
        # inactive and get harmless inputs: a NaN survives the float clamps (NaN-propagating min/max) and
        # would turn into an out-of-bounds index of an unmasked gather
        finite = dr.all(dr.isfinite(pos)) & dr.all(dr.isfinite(normal)) & dr.all(dr.isfinite(wo))
        if direction is not None:
            finite &= dr.all(dr.isfinite(direction))
        active = mi.Bool(active) & finite
        pos = dr.select(active, pos, origin)
        normal = dr.select(active, normal, mi.Vector3f(0.0, 0.0, 1.0))
        wo = dr.select(active, wo, mi.Vector3f(0.0, 0.0, 1.0))
        lookup = dr.select(active, lookup, mi.Vector3f(0.0, 0.0, 1.0))

        # -- biased position and base cell --
        bias = normal * (self.normal_bias * scale) + wo * (self.view_bias * scale)
        bpos = pos + bias
        rel = (bpos - origin) * inv_spacing
        cmax = mi.Vector3f(nx - 2, ny - 2, nz - 2)
        base_f = dr.clip(dr.floor(rel), 0.0, cmax)
        alpha = dr.clip(rel - base_f, 0.0, 1.0)
        base = dr.minimum(mi.Vector3u(base_f), mi.Vector3u(nx - 2, ny - 2, nz - 2))

        irr_coords = direction_to_texel_coords(lookup, vol.irradiance_texels)

        def chebyshev(probe, ppos):
            """(visible, factor): is the biased point no farther than the mean distance the probe's
            moments store towards it, and the one-sided Chebyshev bound ``p^3`` where it is farther."""
            bvec = ppos - bpos
            bdist = dr.norm(bvec)
            # the octahedral map is scale-invariant: -bvec needs no normalisation
            dc = direction_to_texel_coords(-bvec, vol.distance_texels)
            mom = bilinear_gather(dev.distance, probe, dc, vol.distance_texels, 2)
            mean = mom.x
            var = dr.abs(mom.y - mean * mean)
            diff = dr.maximum(bdist - mean, 0.0)
            cheb = var / dr.maximum(var + diff * diff, 1e-12)
            return bdist <= mean, cheb * cheb * cheb, mean

        def corner_weight(ox, oy, oz):
            """Index and weight of one of the 8 cell corners (ox, oy, oz in {0, 1})."""
            probe = (base.x + ox) + nx * ((base.y + oy) + ny * (base.z + oz))
            tri = (dr.select(ox != 0, alpha.x, 1.0 - alpha.x) * dr.select(oy != 0, alpha.y, 1.0 - alpha.y)
                   * dr.select(oz != 0, alpha.z, 1.0 - alpha.z))
            # position and state in one packet gather: the query is bound by gather throughput
            pdata = dr.gather(mi.Vector4f, dev.probe_data, probe, active)
            ppos = mi.Point3f(pdata.x, pdata.y, pdata.z)
            live = active & (pdata.w > 0.0)

            w = mi.Float(1.0)
            if self.wrap:
                to_probe = ppos - pos      # dot(normalize(v), n) without the divisions
                cos = dr.dot(to_probe, normal) * dr.rsqrt(dr.maximum(dr.squared_norm(to_probe), 1e-20))
                w = dr.square((cos + 1.0) * 0.5) + WRAP_OFFSET
            if self.visibility:
                # dead corners read probe 0 (a cached line) instead of a masked gather (slower in Dr.Jit)
                seen, cheb, _ = chebyshev(dr.select(live, probe, 0), ppos)
                w *= dr.select(seen, 1.0, dr.maximum(cheb, CHEBYSHEV_FLOOR))
            w = dr.maximum(w, MIN_WEIGHT)
            w = dr.select(w < CRUSH_THRESHOLD, w * w * w * (1.0 / (CRUSH_THRESHOLD * CRUSH_THRESHOLD)), w)
            return probe, dr.select(live, w * tri, 0.0)

        def corner(c):
            return corner_weight(c & 1, (c >> 1) & 1, (c >> 2) & 1)

        # -- fallback (step 5): the visible active probes nearest to the cell --
        table = self.fallback_table()
        clamp = dr.opaque(mi.Float, FALLBACK_OPEN * vol.max_distance)
        cell = base.x + (nx - 1) * (base.y + (ny - 1) * base.z)

        def fallback_weight(j, need):
            """Index and weight of fallback candidate ``j`` of the cell (lanes in ``need`` only)."""
            probe = dr.gather(mi.UInt32, table, cell * FALLBACK_PROBES + j, need)
            pdata = dr.gather(mi.Vector4f, dev.probe_data, probe, need)
            ppos = mi.Point3f(pdata.x, pdata.y, pdata.z)
            # inverse squared distance in units of the spacing
            w = (scale * scale) / dr.maximum(dr.squared_norm(ppos - bpos), (FALLBACK_MIN_DISTANCE * scale) ** 2)
            if self.wrap:
                to_probe = ppos - pos
                cos = dr.dot(to_probe, normal) * dr.rsqrt(dr.maximum(dr.squared_norm(to_probe), 1e-20))
                w *= dr.square((cos + 1.0) * 0.5) + WRAP_OFFSET
            ok = need & (pdata.w > 0.0)
            if self.visibility:
                # the corners' test, without its floor: a candidate it would reject behind a wall -- a
                # surface stored nearer than x' -- is out; moments at the clamp (nothing nearer than it in
                # that direction) put no wall in between
                seen, cheb, mean = chebyshev(dr.select(ok, probe, 0), ppos)
                seen |= mean >= clamp
                w *= dr.select(seen, 1.0, cheb)
                ok &= seen | (cheb > CHEBYSHEV_FLOOR)
            return probe, dr.select(ok, w, 0.0)

        def irradiance_of(probe, w):
            probe = dr.select(w > 0.0, probe, 0)      # zero-weight corners read a cached line
            return bilinear_gather(dev.irradiance, probe, irr_coords, vol.irradiance_texels, 3)

        if sampler is not None:
            return self._stochastic(corner, fallback_weight, irr_coords, active, sampler)
        if self.unroll:
            E = mi.Color3f(0.0)
            wsum = mi.Float(0.0)
            for c in range(8):
                probe, w = corner(c)
                E += irradiance_of(probe, w) * w
                wsum += w
        else:
            # a symbolic loop over the corners: one copy of the code in the kernel (8x less to trace)
            def body(c, E, wsum):
                probe, w = corner(c)
                return c + 1, dr.fma(irradiance_of(probe, w), w, E), wsum + w
            _, E, wsum = dr.while_loop((mi.UInt32(0), mi.Color3f(0.0), mi.Float(0.0)),
                                       lambda c, E, wsum: c < 8, body, labels=("corner", "E", "wsum"))
        # lanes whose 8 corners carry no weight replace the blend by the fallback's (only they loop)
        need = active & (wsum <= FALLBACK_WEIGHT)

        def fb_body(j, E, wsum):
            probe, w = fallback_weight(j, need)
            return j + 1, dr.fma(irradiance_of(probe, w), w, E), wsum + w
        _, E_fb, wsum_fb = dr.while_loop((mi.UInt32(0), mi.Color3f(0.0), mi.Float(0.0)),
                                         lambda j, E, wsum: need & (j < FALLBACK_PROBES), fb_body,
                                         labels=("fallback", "E", "wsum"))
        E = dr.select(need, E_fb, E)
        wsum = dr.select(need, wsum_fb, wsum)
        return dr.select(wsum > 0.0, E * (dr.pi / dr.maximum(wsum, 1e-30)), mi.Color3f(0.0))

    def _stochastic(self, corner, fallback_weight, irr_coords, active, sampler):
        """One texel of one probe: the corner by weighted reservoir sampling, the texel by its bilinear weight.

        Lanes whose corners carry no weight run the same reservoir over the
        fallback candidates, from the same uniform number (a fresh one for them).
        """
        vol = self.volume
        u_probe = sampler.next_1d(active)
        u_texel = sampler.next_2d(active)

        def reservoir_step(probe, w, wsum, chosen, u):
            wsum = wsum + w
            p = dr.select(wsum > 0.0, w / dr.maximum(wsum, 1e-30), 0.0)   # P(replace the choice so far)
            take = u < p
            chosen = dr.select(take, probe, chosen)
            # rescale u to a fresh uniform number on the branch taken (one uniform serves all 8 draws)
            u = dr.select(take, u / dr.maximum(p, 1e-30), (u - p) / dr.maximum(1.0 - p, 1e-30))
            return wsum, chosen, dr.clip(u, 0.0, ONE_MINUS_EPS)

        def body(c, wsum, chosen, u):
            probe, w = corner(c)
            return (c + 1, *reservoir_step(probe, w, wsum, chosen, u))

        if self.unroll:
            state = (mi.UInt32(0), mi.Float(0.0), mi.UInt32(0), mi.Float(u_probe))
            for c in range(8):
                state = body(c, *state[1:])
            _, wsum, chosen, _ = state
        else:
            _, wsum, chosen, _ = dr.while_loop(
                (mi.UInt32(0), mi.Float(0.0), mi.UInt32(0), mi.Float(u_probe)),
                lambda c, wsum, chosen, u: c < 8, body, labels=("corner", "wsum", "chosen", "u"))
        # -- fallback (step 5 of the module docstring), only for the lanes that need it --
        need = active & (wsum <= FALLBACK_WEIGHT)

        def fb_body(j, wsum, chosen, u):
            probe, w = fallback_weight(j, need)
            return (j + 1, *reservoir_step(probe, w, wsum, chosen, u))
        _, wsum_fb, chosen_fb, _ = dr.while_loop(
            (mi.UInt32(0), mi.Float(0.0), mi.UInt32(0), mi.Float(u_probe)),
            lambda j, wsum, chosen, u: need & (j < FALLBACK_PROBES), fb_body,
            labels=("fallback", "wsum", "chosen", "u"))
        wsum = dr.select(need, wsum_fb, wsum)
        chosen = dr.select(need, chosen_fb, chosen)
        t = vol.irradiance_texels
        x = irr_coords.x - 0.5
        y = irr_coords.y - 0.5
        x0 = dr.clip(dr.floor(x), 0.0, t - 2.0)
        y0 = dr.clip(dr.floor(y), 0.0, t - 2.0)
        xi = dr.minimum(mi.UInt32(x0), t - 2) + mi.UInt32(u_texel.x < dr.clip(x - x0, 0.0, 1.0))
        yi = dr.minimum(mi.UInt32(y0), t - 2) + mi.UInt32(u_texel.y < dr.clip(y - y0, 0.0, 1.0))
        ok = active & (wsum > 0.0)
        irr = dr.gather(mi.Color3f, vol.device.irradiance, chosen * (t * t) + yi * t + xi, ok)
        return dr.select(ok, irr * dr.pi, mi.Color3f(0.0))
