"""The one emitter table: every emitter triangle of a scene as one light (Dittebrandt et al., VLC paper
Sec. 7), and the one emitter classification (:func:`emitter_kind`).

The VLC paper's lights are triangles: "a light" is one emitter triangle, so a
built-in quad light is two lights, and every light is a *uniform* emitter
(constant radiance over its surface) sampled by plain area sampling (Sec. 7).
:class:`EmitterTable` flattens every triangle-mesh shape that carries an
``area`` emitter into device arrays indexed by a global *light id*:

* ids follow ``mi_scene.shapes()`` order and each mesh's triangle order, so
  they are stable across frames of an animated scene (the shapes are animated
  in place; :meth:`EmitterTable.refresh` re-reads the positions and keeps
  the count and ids);
* ``radiance`` is the emitter's radiance evaluated once per triangle at its
  centroid (exact for the uniform emitters of Sec. 7; a textured emitter is
  approximated by its value at each triangle's centroid: our choice, documented);
* emitters are one-sided as in Mitsuba's ``area`` light: they emit on the side
  of the geometric normal ``normalize(cross(e1, e2))`` (a mesh with
  ``flip_normals`` is not detected: our choice, rare in practice).

Emitters that are not on triangle meshes (Mitsuba's analytic ``sphere``,
``disk``, ``cylinder`` shapes, delta lights, the environment) are not lights
here; ``nee-pt`` handles them the same way for every light selector
(:mod:`dyngi.techniques.neept`). Mitsuba 3.9's ``rectangle`` and ``cube``
shapes are meshes and are included (a rectangle is two lights).
"""
from __future__ import annotations

import numpy as np

from ..backend import dr, mi, upload
from ..color import luminance
from ..scene.geometry import mesh_triangles, to_point

INVALID = 0xFFFFFFFF
"""Light id of "no light" (off emitter triangles, nothing chosen)."""

AREA, ENVIRONMENT, DELTA_POSITION, DELTA_DIRECTION = 0, 1, 2, 3
KIND_NAMES = ("area", "environment", "delta-position", "delta-direction")


def emitter_kind(e) -> int:
    """The one emitter classification: ``AREA``, ``ENVIRONMENT``, ``DELTA_POSITION`` or ``DELTA_DIRECTION``
    (the measure a light sample of ``e`` lives in, :mod:`dyngi.lights.candidates`)."""
    f = e.flags()
    if mi.has_flag(f, mi.EmitterFlags.DeltaDirection):
        return DELTA_DIRECTION
    if mi.has_flag(f, mi.EmitterFlags.DeltaPosition):
        return DELTA_POSITION
    if mi.has_flag(f, mi.EmitterFlags.Infinite):
        return ENVIRONMENT
    return AREA


def _mesh_emitter_shapes(mi_scene):
    """The scene's shapes that are triangle meshes with an area emitter, in ``shapes()`` order."""
    out = []
    for sh in mi_scene.shapes():
        em = sh.emitter()
        if em is None or not sh.is_mesh() or sh.face_count() == 0:
            continue
        if not mi.has_flag(em.flags(), mi.EmitterFlags.Surface):
            continue
        out.append(sh)
    return out


def _triangle_radiance(sh, p, n):
    """Radiance [F, 3] of mesh ``sh``'s emitter at the points ``p`` (centroids) with normals ``n``."""
    em = sh.emitter()
    F = p.shape[0]
    si = dr.zeros(mi.SurfaceInteraction3f, F)
    si.p = mi.Point3f(*(p[:, k].astype(np.float32) for k in range(3)))
    nn = mi.Normal3f(*(n[:, k].astype(np.float32) for k in range(3)))
    si.n = nn
    si.sh_frame = mi.Frame3f(nn)
    si.wi = mi.Vector3f(0.0, 0.0, 1.0)      # local: seen from the front
    si.uv = mi.Point2f(0.5, 0.5)
    si.t = mi.Float(1.0)
    val = em.eval(si, mi.Bool(True))
    if not F:
        return np.zeros((0, 3))
    val = mi.Color3f(val) + dr.zeros(mi.Color3f, F)      # a constant texture evaluates to width 1
    return np.asarray(dr.ravel(val), np.float64).reshape(F, 3)


class EmitterTable:
    """Every emitter triangle of the scene is one light (VLC paper Sec. 7; a quad light = 2 lights).

    Attributes (device arrays of size ``count``): ``p0``, ``e1``, ``e2`` (vertex
    0 and the edges p1 - p0, p2 - p0), ``normal`` (unit geometric normal, the
    emitting side), ``area``, ``radiance`` (constant emitted radiance),
    ``power`` (pi * area * luminance(radiance), one-sided), ``centroid``.
    ``count`` may be 0 (no triangle area lights): the arrays are padded to at least
    2 entries (zeros) so that gathers compile, and every sample is inactive.
    """

    def __init__(self, mi_scene):
        self._shapes = _mesh_emitter_shapes(mi_scene)
        self._counts = [int(sh.face_count()) for sh in self._shapes]
        self.count = int(sum(self._counts))
        offs = np.concatenate([[0], np.cumsum(self._counts)]).astype(np.int64)
        self._offsets = offs[:-1]
        # light id of (shape, prim): offset table indexed by the shape's registry id (what a ShapePtr holds)
        if self._shapes:
            rids = np.asarray(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(self._shapes)), np.int64)
            table = np.full(int(rids.max()) + 1, INVALID, np.uint32)
            table[rids] = self._offsets.astype(np.uint32)
        else:
            table = np.full(2, INVALID, np.uint32)
        if table.size < 2:
            table = np.concatenate([table, np.full(1, INVALID, np.uint32)])
        self._offset_by_rid = mi.UInt32(table)
        self._table_size = int(table.size)
        self._read(recompute_radiance=True)

    # -- host-side build ---------------------------------------------------
    def _read(self, recompute_radiance: bool):
        P0, P1, P2, RAD = [], [], [], []
        for sh in self._shapes:
            p0, p1, p2 = mesh_triangles(sh)
            P0.append(p0), P1.append(p1), P2.append(p2)
        if self.count:
            p0 = np.concatenate(P0)
            e1 = np.concatenate(P1) - p0
            e2 = np.concatenate(P2) - p0
        else:
            p0 = e1 = e2 = np.zeros((0, 3))
        cr = np.cross(e1, e2)
        area2 = np.linalg.norm(cr, axis=1) if self.count else np.zeros(0)
        n = cr / np.maximum(area2, 1e-30)[:, None]
        area = 0.5 * area2
        cen = p0 + (e1 + e2) / 3.0
        if recompute_radiance or not hasattr(self, "_rad_host"):
            if self.count:
                for sh, o, c in zip(self._shapes, self._offsets, self._counts):
                    RAD.append(_triangle_radiance(sh, cen[o:o + c], n[o:o + c]))
                self._rad_host = np.maximum(np.concatenate(RAD), 0.0)
            else:
                self._rad_host = np.zeros((0, 3))
        rad = self._rad_host
        lum = luminance(rad)
        power = np.pi * area * lum
        self._host = dict(p0=p0, e1=e1, e2=e2, normal=n, area=area, radiance=rad, power=power, centroid=cen)
        # padded to >= 2 entries: a 1-element array may enter a kernel as a literal (then another kernel)
        pad = (lambda a: a if a.shape[0] >= 2 else np.concatenate([a, np.zeros((2 - a.shape[0],) + a.shape[1:])]))
        self.p0 = to_point(pad(p0))
        self.e1 = to_point(pad(e1), mi.Vector3f)
        self.e2 = to_point(pad(e2), mi.Vector3f)
        self.normal = to_point(pad(n), mi.Normal3f)
        self.area = upload(mi.Float, pad(area))
        self.radiance = to_point(pad(rad), mi.Color3f)
        self.power = upload(mi.Float, pad(power))
        self.centroid = to_point(pad(cen))
        dr.eval(self.p0, self.e1, self.e2, self.normal, self.area, self.radiance, self.power, self.centroid)

    def host_arrays(self) -> dict:
        """NumPy (float64) copies: p0, e1, e2, normal, area, radiance, power, centroid (size ``count``)."""
        return {k: v.copy() for k, v in self._host.items()}

    def shape_slices(self) -> list:
        """[(shape id string, first light id, triangle count)] per emitter mesh, in id order."""
        return [(sh.id(), int(o), int(c)) for sh, o, c in zip(self._shapes, self._offsets, self._counts)]

    def refresh(self, mi_scene) -> None:
        """Re-read the vertex positions after animation (same shapes and counts, so ids stay stable).

        Radiance is kept (emitters are uniform; a changed radiance needs a new object)."""
        counts = [int(sh.face_count()) for sh in self._shapes]
        if counts != self._counts:
            raise ValueError("EmitterTable.refresh: the emitter meshes changed their triangle counts")
        self._read(recompute_radiance=False)

    # -- device queries ----------------------------------------------------
    def light_id(self, si, active=True) -> "mi.UInt32":
        """Light id of the emitter triangle ``si`` lies on; ``INVALID`` off emitter triangles."""
        active = mi.Bool(active) & si.is_valid()
        rid = dr.reinterpret_array(mi.UInt32, si.shape)
        ok = active & (rid < self._table_size)
        off = dr.gather(mi.UInt32, self._offset_by_rid, rid, ok)
        ok &= off != INVALID
        return dr.select(ok, off + si.prim_index, mi.UInt32(INVALID))

    def sample_point(self, light_id, u2, active=True):
        """Uniform point on triangle ``light_id``: (p, n, pdf_area = 1 / area)."""
        active = mi.Bool(active) & (light_id < max(self.count, 1)) & (self.count > 0)
        p0 = dr.gather(mi.Point3f, self.p0, light_id, active)
        e1 = dr.gather(mi.Vector3f, self.e1, light_id, active)
        e2 = dr.gather(mi.Vector3f, self.e2, light_id, active)
        n = dr.gather(mi.Normal3f, self.normal, light_id, active)
        a = dr.gather(mi.Float, self.area, light_id, active)
        b = mi.warp.square_to_uniform_triangle(u2)
        p = dr.fma(e1, b.x, dr.fma(e2, b.y, p0))
        pdf = dr.select(active & (a > 0), dr.rcp(a), 0.0)
        return mi.Point3f(p), mi.Normal3f(n), pdf

    def gather_radiance(self, light_id, active=True) -> "mi.Color3f":
        """Constant radiance of triangle ``light_id`` (0 where inactive)."""
        return dr.gather(mi.Color3f, self.radiance, light_id, mi.Bool(active))
