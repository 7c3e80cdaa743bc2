"""Motion vectors for moving meshes: a hit point's previous-frame position (Dittebrandt et al. Sec. 6.3).

The VLC and the CDQ sample with the estimators of the octree leaf of a shading point's *previous*
position (the leaf the previous frame's samples were recorded in, carried over by ``prev_leaf``)
and place this frame's samples at its current position (``AdaptiveOctree.lookup_pair``). For static
geometry both positions coincide; on a moving mesh the previous position is the same point of the
surface one frame earlier.

:class:`MotionVectors` keeps, for the triangles of the scene's animated meshes (``dynamic_shapes``),
their current and previous vertex positions as device arrays, indexed like
:class:`~dyngi.lights.emitter_table.EmitterTable` by an offset table over the shape's registry
id plus ``prim_index``. :meth:`previous` re-expresses a hit point in the barycentric coordinates of its
current triangle and evaluates them on the previous triangle (exact for rigid and deformed meshes
alike); points on static shapes, and every point in the first frame, keep their current position.

Per frame, :meth:`advance` (before tracing) moves current -> previous and re-reads the animated meshes'
vertices from the scene: a host read of the dynamic meshes only (declared fast path: our animation
updates the meshes through ``mi.traverse`` on the host anyway); nothing for scenes without dynamic meshes.
"""
from __future__ import annotations

import numpy as np

from ..backend import dr, mi
from ..scene.geometry import mesh_triangles, to_point

NO_TRIANGLE = 0xFFFFFFFF
"""Offset-table entry of a shape that is not an animated mesh."""


def _pad(a):
    return a if a.shape[0] >= 2 else np.concatenate([a, np.zeros((2 - a.shape[0],) + a.shape[1:])])


class MotionVectors:
    """Previous-frame positions of hit points on the scene's animated meshes (module docstring)."""

    def __init__(self, mi_scene, dynamic_shapes=()):
        dyn = set(dynamic_shapes or ())
        self._shapes = [sh for sh in mi_scene.shapes() if sh.id() in dyn and sh.is_mesh() and sh.face_count() > 0]
        self.count = int(sum(int(sh.face_count()) for sh in self._shapes))
        offs = np.concatenate([[0], np.cumsum([int(sh.face_count()) for sh in self._shapes])]).astype(np.int64)
        if self._shapes:
            rids = np.asarray(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(self._shapes)), np.int64)
            table = np.full(max(int(rids.max()) + 1, 2), NO_TRIANGLE, np.uint32)
            table[rids] = offs[:-1].astype(np.uint32)
        else:
            table = np.full(2, NO_TRIANGLE, np.uint32)
        self._offset_by_rid = mi.UInt32(table)
        self._table_size = int(table.size)
        self._cur = self._read()
        self._prev = self._cur
        self.frames = 0

    def _read(self):
        if not self.count:
            z = np.zeros((0, 3))
            p0 = e1 = e2 = z
        else:
            tri = [mesh_triangles(sh) for sh in self._shapes]
            p0 = np.concatenate([t[0] for t in tri])
            e1 = np.concatenate([t[1] for t in tri]) - p0
            e2 = np.concatenate([t[2] for t in tri]) - p0
        arrs = (to_point(_pad(p0)), to_point(_pad(e1), mi.Vector3f), to_point(_pad(e2), mi.Vector3f))
        dr.eval(*arrs)
        return arrs

    @property
    def active(self) -> bool:
        """True when the scene has animated meshes (else :meth:`previous` returns the current points)."""
        return self.count > 0

    def advance(self, mi_scene=None) -> None:
        """New frame: the current positions become the previous ones; the animated meshes are re-read."""
        if not self.count:
            return
        self._prev = self._cur
        self._cur = self._read()
        self.frames += 1

    def previous(self, si, active=True):
        """``si.p`` one frame earlier (``mi.Point3f``): on an animated mesh through its triangle's barycentric
        coordinates, elsewhere (and before the second frame) ``si.p`` itself."""
        p = mi.Point3f(si.p)
        if not self.count or self.frames == 0:
            return p
        active = mi.Bool(active) & si.is_valid()
        rid = dr.reinterpret_array(mi.UInt32, si.shape)
        ok = active & (rid < self._table_size)
        off = dr.gather(mi.UInt32, self._offset_by_rid, rid, ok)
        ok &= off != NO_TRIANGLE
        k = off + si.prim_index
        c0, c1, c2 = (dr.gather(type(a), a, k, ok) for a in self._cur)
        q0, q1, q2 = (dr.gather(type(a), a, k, ok) for a in self._prev)
        # barycentrics (b1, b2) of p in the current triangle c0 + b1 c1 + b2 c2 (least squares in its plane)
        d = p - c0
        d11, d12, d22 = dr.dot(c1, c1), dr.dot(c1, c2), dr.dot(c2, c2)
        r1, r2 = dr.dot(d, c1), dr.dot(d, c2)
        den = d11 * d22 - d12 * d12
        inv = dr.select(dr.abs(den) > 0.0, dr.rcp(den), 0.0)
        b1 = (d22 * r1 - d12 * r2) * inv
        b2 = (d11 * r2 - d12 * r1) * inv
        pp = q0 + b1 * q1 + b2 * q2
        return dr.select(ok & (dr.abs(den) > 0.0), mi.Point3f(pp), p)
