"""Static Light Lists as the VLC paper describes them (Dittebrandt et al. Sec. 7; Quake 2 RTX): ``lights=sll``.

Quake 2 RTX's light lists come from the potentially-visible set (PVS) of its BSP: each BSP leaf
(cluster) knows the clusters potentially visible from it, computed once offline for the static
geometry, conservatively; a leaf's light list holds every light in a potentially visible cluster,
so it "includes many lights that are potentially visible but occluded" (issue 28, the paper's
SLL). NEE traverses the list with a stride so that at most 32 lights are considered, weighted by
the same importance as the VLC (Sec. 7: "so that the techniques mainly differ in how precisely
they capture the set of visible lights"). The traversal, the importance and the exact pmf are
:class:`~dyngi.lights.sll.SLLSelector`'s (this class only builds other lists).

Leaves (our stand-in for BSP leaves): the cells of a coarse uniform grid, ``cells`` cells along the
longest axis of the scene bounds (default 9: 3 m leaves in ``warehouse-rooms``, whose 9 m rooms
are 3 x 3 leaves aligned with the walls). A BSP's leaves follow the walls; a grid cell that
straddles a wall belongs to both sides (more conservative, never less).

PVS, computed once (static geometry; animated shapes ``dynamic_shapes`` are left out of the
occluders, Sec. 7: "only static scene elements can affect visibility"), ``pvs="flood"`` (default):

1. *Portals*: the face between two neighbouring leaves is *closed* when all of its
   ``face_samples`` x ``face_samples`` points lie inside solid static geometry (a point is inside
   when at least 2 of 14 rays from it, along the axes and the diagonals, first hit a back face of a
   closed mesh), else it is an open portal. A one-sided plane never closes a face (conservative).
2. *Monotone portal flood* (Quake's first, conservative vis stage works by portal flooding too;
   Teller's from-region visibility bounds it the same way): a straight segment from a point of leaf
   ``a`` to a point of leaf ``b`` crosses leaf faces in an order that is monotone along each axis
   (its cell index along x, y and z only grows or only shrinks). So ``b`` is potentially visible
   from ``a`` only if ``b`` is reachable from ``a`` through open portals by steps whose signs agree
   with one octant ``(sx, sy, sz)``; the PVS is the union of the eight octants' reachable sets
   (boolean matrix products until a fixed point, no per-leaf loop). Conservative by construction up
   to the face sampling (an opening smaller than the sample spacing, ``leaf / face_samples``, in an
   otherwise solid face is missed; meshes must be closed or consistently oriented shells: back faces
   seen from free space in two directions would close a face); tested: no light that a random unoccluded segment from a point
   of a leaf reaches is missing from that leaf's list. Tighter than "everything connected", looser
   than Quake's exact anti-penumbra clipping: an over-approximation, as the paper's SLL is.

``pvs="sampled"`` (ablation, not conservative): ``pair_samples`` random segments between the
points of each leaf pair, then ``dilate`` rings of the 26 neighbours added to every potentially
visible leaf (measured: it misses lines through two doors in a row, issue 28).

*Lights of a leaf*: light ``l`` is in leaf ``a``'s list if ``l``'s triangle overlaps (its bounding
box, padded by ``1e-3`` of the leaf size) some leaf potentially visible from ``a``, and some corner
of ``a``'s box is on ``l``'s emitting side (a light that faces away from the whole leaf cannot
reach it).

Moving lights: in ``begin_frame`` a light that moved has its leaves and facing recomputed from its
new triangle (no rays: the leaf-to-leaf PVS is static) and the lists are re-uploaded (a host pass,
declared; none when no light moved). Sizes: ``stats()`` reports the mean and maximum list length and
the number of PVS rays.
"""
from __future__ import annotations

import time

import numpy as np

from ..backend import dr, mi
from ..errors import DyngiError
from ..rays import intersect, occluded
from .base import register
from .sll import _RAY_CHUNK, RAY_STAGE, SLLSelector, _static_occluders


_DIRECTIONS = np.concatenate([np.eye(3), -np.eye(3),
                              np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) / np.sqrt(3)])
_INSIDE_VOTES = 2      # back-face first hits (of 14 directions) that make a point inside a solid (our choice)


class PVSLightLists(SLLSelector):
    """``lights=sll``: Quake 2 RTX's static light lists from a conservative leaf-to-leaf PVS (module docstring).

    Parameters (keywords; the rest are accepted and ignored, contract of ``nee-pt``)
    ----------
    tris : EmitterTable            the triangle lights
    mi_scene : mi.Scene            the scene whose static geometry occludes (required)
    bounds : (lo[3], hi[3])        grid bounds (default: the scene's bounding box)
    cells : int = 9                leaves along the longest axis (our choice; BSP-leaf stand-in)
    pvs : str = "flood"            "flood" (conservative portal flood) or "sampled" (ablation)
    face_samples : int = 8         points per side of a leaf face for the portal test (flood)
    pair_samples : int = 256       segments per leaf pair (sampled)
    dilate : int = 1               neighbour rings added to every potentially visible leaf (sampled)
    dynamic_shapes : list[str]     ids of animated shapes, left out of the occluders
    seed : int = 0                 seed of the PVS segments
    update_moving : bool = True    re-place lights that moved, in begin_frame
    """

    name = "sll"
    MAX_LEAVES = 4096

    def __init__(self, tris, mi_scene=None, bounds=None, cells: int = 9, pvs: str = "flood", face_samples: int = 8,
                 pair_samples: int = 256, dilate: int = 1, dynamic_shapes=(), seed: int = 0,
                 update_moving: bool = True, **opts):
        if mi_scene is None:
            raise DyngiError("sll: the potentially-visible set needs the scene (mi_scene=...)")
        for nm, v, lo, hi in (("cells", cells, 1, 128), ("pair_samples", pair_samples, 1, 1 << 16),
                              ("dilate", dilate, 0, 8), ("face_samples", face_samples, 1, 256)):
            if not lo <= int(v) <= hi:
                raise DyngiError(f"sll: {nm} must be in {lo}..{hi}, got {v}")
        self.tris = tris
        self.count = int(tris.count)
        self._grid(mi_scene, bounds, cells)
        if self.n_cells > self.MAX_LEAVES:
            raise DyngiError(f"sll: {self.n_cells} leaves (cells={cells}) exceed {self.MAX_LEAVES}; use fewer cells")
        if pvs not in ("flood", "sampled"):
            raise DyngiError(f"sll: pvs must be 'flood' or 'sampled', got '{pvs}'")
        self.method = pvs
        self.pair_samples, self.dilate, self.face_samples = int(pair_samples), int(dilate), int(face_samples)
        self.update_moving = bool(update_moving)
        self._seed = int(seed)
        t0 = time.perf_counter()
        self._occ = _static_occluders(mi_scene, dynamic_shapes)
        self.leaf_pvs = self._portal_flood() if pvs == "flood" else self._leaf_visibility()
        self._tri_state = self._light_state()
        self._upload_lists(self._lists())
        self.precompute_ms = 1e3 * (time.perf_counter() - t0)
        self.update_ms = 0.0
        self.moved_lights = 0

    # ------------------------------------------------------------------ precompute
    def _boxes(self):
        """(lo[C, 3], hi[C, 3]) float64 of every leaf, in the flat order of ``_cell_of``."""
        c = np.arange(self.n_cells)
        ijk = np.stack([c // (self.res[2] * self.res[1]), (c // self.res[2]) % self.res[1], c % self.res[2]], 1)
        lo = self.lo.astype(np.float64) + ijk * self.cell.astype(np.float64)
        return lo, lo + self.cell.astype(np.float64), ijk

    def _inside(self, P: np.ndarray) -> np.ndarray:
        """Host bool per point: inside closed static geometry. From free space the first hit of any ray is a
        front face of a closed, outward-facing mesh; from inside a solid it is a back face, except where the
        solid touches another one and a coplanar front face wins the tie. So a point is inside when at least
        ``_INSIDE_VOTES`` of the 14 directions (6 axes, 8 diagonals) first hit a back face."""
        n, m = len(P), len(_DIRECTIONS)
        if n == 0:
            return np.zeros(0, bool)
        idx = dr.arange(mi.UInt32, n * m)          # one kernel: lane = (point, direction)
        pts = [mi.Float(np.ascontiguousarray(P[:, k], np.float32)) for k in range(3)]
        dirs = [mi.Float(np.ascontiguousarray(_DIRECTIONS[:, k], np.float32)) for k in range(3)]
        o = mi.Point3f(*[dr.gather(mi.Float, pts[k], idx // m) for k in range(3)])
        d = mi.Vector3f(*[dr.gather(mi.Float, dirs[k], idx % m) for k in range(3)])
        ray = mi.Ray3f(o, d)
        si = intersect(self._occ, ray, stage=RAY_STAGE)
        back = (si.is_valid() & (dr.dot(si.n, ray.d) > 0.0)).numpy().reshape(n, m)
        votes = back.sum(1)
        return votes >= _INSIDE_VOTES

    def _portal_flood(self) -> np.ndarray:
        """Boolean [C, C]: the monotone portal flood (module docstring, flood 1-2)."""
        C, G = self.n_cells, self.face_samples
        lo, hi, ijk = self._boxes()
        uu = (np.arange(G) + 0.5) / G
        res = tuple(int(r) for r in self.res)
        opens = []                         # opens[ax][i, j, k]: the face from leaf (i, j, k) to its +ax neighbour
        self.rays = 0
        n_faces = 0
        for ax in range(3):
            o1, o2 = [k for k in range(3) if k != ax]
            A = np.nonzero(ijk[:, ax] < self.res[ax] - 1)[0]
            P = np.zeros((len(A), G, G, 3))
            P[..., ax] = hi[A, ax][:, None, None]
            P[..., o1] = lo[A, o1][:, None, None] + uu[None, :, None] * (hi[A, o1] - lo[A, o1])[:, None, None]
            P[..., o2] = lo[A, o2][:, None, None] + uu[None, None, :] * (hi[A, o2] - lo[A, o2])[:, None, None]
            closed = self._inside(P.reshape(-1, 3)).reshape(len(A), G * G).all(1) if len(A) else np.zeros(0, bool)
            self.rays += len(_DIRECTIONS) * len(A) * G * G
            op = np.zeros(C, bool)
            op[A[~closed]] = True
            opens.append(op.reshape(res))
            n_faces += len(A)
        self.closed_faces = int(n_faces - sum(int(o.sum()) for o in opens))
        PV = np.zeros((C,) + res, bool)
        lead = (slice(None),)
        for octant in range(8):
            sg = [1 if (octant >> k) & 1 else -1 for k in range(3)]
            R = np.eye(C, dtype=bool).reshape((C,) + res)   # R[a, b]: b reachable from a by this octant's steps
            while True:       # at most sum(res) sweeps: every step moves one leaf along one axis
                before = R.copy()
                for ax in range(3):
                    if res[ax] < 2:
                        continue
                    lo_s = [slice(None)] * 3
                    hi_s = [slice(None)] * 3
                    lo_s[ax], hi_s[ax] = slice(0, res[ax] - 1), slice(1, res[ax])
                    face = opens[ax][tuple(lo_s)][None]
                    if sg[ax] > 0:
                        R[lead + tuple(hi_s)] |= R[lead + tuple(lo_s)] & face
                    else:
                        R[lead + tuple(lo_s)] |= R[lead + tuple(hi_s)] & face
                if np.array_equal(before, R):
                    break
            PV |= R
        PV = PV.reshape(C, C)
        self.sampled_pairs = 0
        return PV

    def _leaf_visibility(self) -> np.ndarray:
        """Boolean [C, C]: leaf-to-leaf potential visibility, sampled then dilated (module docstring, 1-2)."""
        C, S = self.n_cells, self.pair_samples
        lo, hi, ijk = self._boxes()
        a, b = np.triu_indices(C, 1)
        V = np.eye(C, dtype=bool)
        self.rays = int(len(a)) * S
        if len(a):
            lo_d = [mi.Float(np.ascontiguousarray(lo[:, k], np.float32)) for k in range(3)]
            ext = self.cell.astype(np.float64)
            margin = 0.01                    # stay 1% off the leaf faces (walls often lie on them)
            pairs_per_chunk = max(1, _RAY_CHUNK // S)
            for p0 in range(0, len(a), pairs_per_chunk):
                p1 = min(len(a), p0 + pairs_per_chunk)
                n = (p1 - p0) * S
                idx = dr.arange(mi.UInt32, n)
                pa = mi.UInt32(a[p0:p1].astype(np.uint32))
                pb = mi.UInt32(b[p0:p1].astype(np.uint32))
                pair = idx // S
                ca = dr.gather(mi.UInt32, pa, pair)
                cb = dr.gather(mi.UInt32, pb, pair)
                rng = mi.PCG32(size=n, initstate=mi.UInt64(0x5056 + self._seed),
                               initseq=mi.UInt64(idx) + mi.UInt64(p0 * S))

                def point(c):
                    u = [margin + (1.0 - 2.0 * margin) * rng.next_float32() for _ in range(3)]
                    return mi.Point3f(*[dr.gather(mi.Float, lo_d[k], c) + u[k] * float(ext[k]) for k in range(3)])

                o, y = point(ca), point(cb)
                d = y - o
                dist = dr.norm(d)
                ray = mi.Ray3f(o, d / dr.maximum(dist, 1e-12))
                ray.maxt = dist
                hit = occluded(self._occ, ray, dist > 1e-6, stage=RAY_STAGE)
                ok = (~hit).numpy().reshape(p1 - p0, S).any(1)
                V[a[p0:p1][ok], b[p0:p1][ok]] = True
            V |= V.T
        # conservative margin: the 26-neighbourhood (with self) of every potentially visible leaf
        if self.dilate:
            d = np.abs(ijk[:, None, :] - ijk[None, :, :]).max(2)
            N = d <= 1
            for _ in range(self.dilate):
                V = (V.astype(np.float32) @ N.astype(np.float32)) > 0.5
        return V

    def _light_leaves(self, lights: np.ndarray):
        """(overlap [len(lights), C], facing [len(lights), C]) of the given lights (module docstring, 3)."""
        h = self.tris.host_arrays()
        p0 = h["p0"][lights].astype(np.float64)
        p1, p2 = p0 + h["e1"][lights], p0 + h["e2"][lights]
        tlo = np.minimum(np.minimum(p0, p1), p2)
        thi = np.maximum(np.maximum(p0, p1), p2)
        lo, hi, _ = self._boxes()
        eps = 1e-3 * self.cell.astype(np.float64)
        over = np.zeros((len(lights), self.n_cells), bool)
        step = max(1, (1 << 22) // max(1, 3 * self.n_cells))
        for a in range(0, len(lights), step):    # chunks of lights (memory), each an array pass over all leaves
            over[a:a + step] = np.all((tlo[a:a + step, None, :] <= hi[None] + eps) &
                                      (thi[a:a + step, None, :] >= lo[None] - eps), 2)
        ng = np.cross(h["e1"][lights], h["e2"][lights]).astype(np.float64)
        corners = np.stack([np.where(np.array([(k >> j) & 1 for j in range(3)], bool), hi, lo) for k in range(8)], 1)
        # facing: dot(ng, corner - p0) > 0 for some corner = dot(ng, corner) > dot(ng, p0); chunked over lights
        # so that the [lights, leaves, 8] products stay small for scenes with many emitter triangles
        facing = np.zeros((len(lights), self.n_cells), bool)
        off = np.einsum("li,li->l", ng, p0)
        step = max(1, (1 << 22) // max(1, 8 * self.n_cells))
        for a in range(0, len(lights), step):
            dots = np.einsum("cki,li->lck", corners, ng[a:a + step])
            facing[a:a + step] = (dots > off[a:a + step, None, None]).any(2)
        return over, facing

    def _lists(self) -> np.ndarray:
        """Boolean [C, L]: light l is in leaf a's list (PVS overlap and facing)."""
        if self.count == 0:
            return np.zeros((self.n_cells, 0), bool)
        self._over, self._facing = self._light_leaves(np.arange(self.count))
        return self._combine()

    def _combine(self) -> np.ndarray:
        in_pvs = (self.leaf_pvs.astype(np.float32) @ self._over.T.astype(np.float32)) > 0.5     # [C, L]
        return in_pvs & self._facing.T

    # ------------------------------------------------------------------ LightSampler protocol
    def begin_frame(self, ctx) -> None:
        """Lights that moved are re-placed in the leaves (no rays; the leaf PVS is static) and the lists
        re-uploaded (a host pass, only in frames where a light moved)."""
        self.tris = ctx.tris
        if not self.update_moving or self.count == 0:
            return
        t0 = time.perf_counter()
        state = self._light_state()
        moved = np.nonzero(np.any(np.abs(state - self._tri_state) > 1e-6, 1))[0]
        self.moved_lights = int(len(moved))
        if len(moved):
            o, f = self._light_leaves(moved)
            self._over[moved], self._facing[moved] = o, f
            self._tri_state = state
            self._upload_lists(self._combine())
        self.update_ms = 1e3 * (time.perf_counter() - t0)

    def potentially_visible_leaves(self, leaf: int) -> np.ndarray:
        """Host: the leaves potentially visible from ``leaf`` (tests, inspection)."""
        return np.nonzero(self.leaf_pvs[int(leaf)])[0]

    def stats(self) -> dict:
        s = super().stats()
        s.update({"leaves": self.n_cells, "pvs": self.method, "pvs_rays": self.rays,
                  "mean_pvs_leaves": float(self.leaf_pvs.sum(1).mean())})
        return s


register("sll", PVSLightLists, "static light lists from a conservative PVS (VLC paper Sec. 7 baseline)")
