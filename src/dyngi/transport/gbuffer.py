"""Screen-space G-buffer with motion vectors and a disocclusion mask (issue 14, item 1).

One primary hit per pixel: position, shading and geometric normal (both
turned to face the camera), diffuse
albedo, roughness (the BSDF's ``alpha`` attribute; 1 for a BSDF without one,
e.g. ``diffuse``), shape id, depth (distance from the camera origin along the
unit ray) and whether the BSDF transmits. :class:`GBufferHistory` keeps the
previous frame's G-buffer and camera and computes, per pixel:

* ``prev_pos``: the hit point where it was at the previous frame's time. A
  point on a shape moved by a :class:`~dyngi.scene.animation.RigidMotion` is
  mapped back by that shape's own transforms, ``p' = A_prev A_cur^-1 p`` (the
  animation is affine: ``A(t) x = M(t)(x - pivot) + pivot + d(t)``, rigid for the
  built-in scenes, with scale for glTF nodes; :class:`ShapeMotion`); points on
  static shapes stay put. This is exact for affine motion; deforming meshes
  (glTF skinning, morph targets) would need per-vertex history and are treated
  as static here (approximate).
* ``motion``: previous film position (pixels, continuous) of ``prev_pos``
  through the previous camera, minus this pixel's centre;
* ``reproj_valid``: the disocclusion mask -- False where the previous pixel
  lies outside the image, or the previous G-buffer at the nearest previous
  pixel holds another surface: relative depth difference above
  ``depth_tol`` (0.1) or normals differing by more than ``normal_tol_deg``
  (25 degrees) -- the thresholds of Bitterli et al. 2020, Sec. 6 (their
  neighbour test), used here for reprojection as well, our choice.

Everything is Dr.Jit arrays of one lane per pixel; per-shape motion is a small
table gathered by the shape's registry id, rebuilt per frame on the host (one
21-float row per shape), so a new frame compiles nothing new.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..backend import dr, mi
from ..rays import intersect

DEPTH_TOL = 0.1
"""Relative depth tolerance of the disocclusion / neighbour test (Bitterli et al. 2020, Sec. 6)."""
NORMAL_TOL_DEG = 25.0
"""Normal-angle tolerance of the disocclusion / neighbour test (Bitterli et al. 2020, Sec. 6)."""


@dataclass
class GBuffer:
    """Per-pixel primary-hit attributes (one lane per pixel, row-major, y down)."""

    res: tuple
    camera: object
    time: float
    ray: "mi.Ray3f"
    si: "mi.SurfaceInteraction3f"     # the full interaction, for shading this frame
    valid: "mi.Bool"
    pos: "mi.Point3f"
    n_sh: "mi.Vector3f"
    n_geo: "mi.Vector3f"
    albedo: "mi.Color3f"
    roughness: "mi.Float"
    shape_id: "mi.UInt32"            # shape registry id (0: no hit)
    prim: "mi.UInt32"
    depth: "mi.Float"                # distance from the camera origin (inf: no hit)
    transmissive: "mi.Bool"          # BSDF has a transmission lobe

    def arrays(self):
        return (self.valid, self.pos, self.n_sh, self.n_geo, self.albedo, self.roughness, self.shape_id,
                self.prim, self.depth, self.transmissive)


def render_gbuffer(scene, camera, res, pixel_jitter, time: float = 0.0, material: bool = True) -> GBuffer:
    """Trace one primary ray per pixel through ``pixel_jitter`` (Point2f in [0,1)^2 per pixel).

    ``material=False`` skips albedo and roughness (left 0 and 1): two BSDF virtual calls whose cost
    grows with the number of BSDFs in the scene, for consumers that do not read them."""
    w, h = res
    mscene = scene.mi_scene if hasattr(scene, "mi_scene") else scene
    idx = dr.arange(mi.UInt32, w * h)
    ray = camera.sample_rays(res, idx, pixel_jitter)
    si = intersect(mscene, ray, mi.RayFlags.All, True, stage="gbuffer")
    valid = si.is_valid()
    bsdf = si.bsdf(ray)
    if material:
        albedo = dr.select(valid, bsdf.eval_diffuse_reflectance(si, valid), 0.0)
        alpha = bsdf.eval_attribute_1("alpha", si, valid)
        roughness = dr.select(alpha > 0.0, alpha, 1.0)
    else:
        albedo, roughness = dr.zeros(mi.Color3f, w * h), dr.full(mi.Float, 1.0, w * h)
    transmissive = valid & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Transmission)
    shape_id = dr.select(valid, dr.reinterpret_array(mi.UInt32, si.shape), 0)
    depth = dr.select(valid, si.t, dr.inf)
    # normals face the viewer (a two-sided surface seen from its back reflects on that side)
    n_sh = dr.select(dr.dot(si.sh_frame.n, ray.d) > 0.0, -si.sh_frame.n, si.sh_frame.n)
    n_geo = dr.select(dr.dot(si.n, ray.d) > 0.0, -si.n, si.n)
    gb = GBuffer(res, camera, float(time), ray, si, valid, mi.Point3f(si.p), mi.Vector3f(n_sh),
                 mi.Vector3f(n_geo), mi.Color3f(albedo), mi.Float(roughness), mi.UInt32(shape_id),
                 mi.UInt32(si.prim_index), mi.Float(depth), mi.Bool(transmissive))
    dr.eval(*gb.arrays())
    return gb


def project(camera, res, p):
    """Continuous pixel coordinates (x, y) of world points ``p`` through ``camera``, and in-front mask.

    Inverse of :meth:`~dyngi.scene.Camera.sample_rays` (pixel (x, y) = film position * resolution)."""
    w, h = res
    left, up, d = camera.frame()
    tanx = float(np.tan(np.radians(camera.fov) * 0.5))
    aspect = w / h
    L = dr.opaque(mi.Vector3f, [float(c) for c in left])
    U = dr.opaque(mi.Vector3f, [float(c) for c in up])
    D = dr.opaque(mi.Vector3f, [float(c) for c in d])
    O = dr.opaque(mi.Point3f, [float(c) for c in camera.origin])
    v = p - O
    z = dr.dot(v, D)
    inv_z = dr.rcp(z)
    fx = 0.5 * (1.0 - dr.dot(v, L) * inv_z * dr.opaque(mi.Float, 1.0 / tanx))
    fy = 0.5 * (1.0 - dr.dot(v, U) * inv_z * dr.opaque(mi.Float, aspect / tanx))
    return fx * w, fy * h, z > 0.0


class ShapeMotion:
    """Per-shape affine map from time ``t`` to time ``t_prev``, gathered by shape id.

    An animator with ``shape``, ``pivot`` and ``transform(t) -> (M, d)`` moves its mesh as
    ``p(t) = M(t) (p_base - pivot) + pivot + d(t)`` (:class:`~dyngi.scene.animation.RigidMotion`: ``M = R``
    orthonormal; :class:`~dyngi.scene.animation.AffineMotion`: any invertible ``M``, e.g. a glTF node's
    world matrix with scale). A point at ``t`` maps back by ``A = M_prev M_cur^-1``,
    ``p' = A (p - pivot - d_cur) + pivot + d_prev``, and a normal by ``A^-T`` (``= A`` when rigid: an
    animator that declares ``rigid`` is inverted by its transpose, so rigid scenes get the same table as
    before). Deforming meshes (skinning, morph targets) have no such map and stay put here: their
    reprojection is approximate (the disocclusion test rejects what moved too far).
    """

    def __init__(self, scene):
        mscene = scene.mi_scene
        shapes = list(mscene.shapes())
        self.ids = np.asarray(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(shapes)), np.int64)
        self.names = [s.id() for s in shapes]
        self.movers = {a.shape: a for a in getattr(scene, "animators", []) if hasattr(a, "transform") and a.shape}
        self.size = max(int(self.ids.max()) + 1 if len(self.ids) else 1, 2)

    def table(self, t_cur: float, t_prev: float) -> "mi.Float":
        """Flat rows of 21 floats per registry id: the 3x3 point matrix row-major, the offset, then the 3x3
        normal matrix row-major."""
        rows = np.zeros((self.size, 21), np.float64)
        rows[:, [0, 4, 8]] = 1.0
        rows[:, [12, 16, 20]] = 1.0
        for rid, name in zip(self.ids, self.names):
            a = self.movers.get(name)
            if a is None:
                continue
            M1, d1 = a.transform(t_cur)
            M0, d0 = a.transform(t_prev)
            piv = np.asarray(a.pivot, np.float64)
            if getattr(a, "rigid", False):
                A = M0 @ M1.T
                N = A
            else:
                A = M0 @ np.linalg.inv(M1)
                N = np.linalg.inv(A).T
            off = piv + d0 - A @ (piv + d1)
            rows[rid, :9] = A.ravel()
            rows[rid, 9:12] = off
            rows[rid, 12:] = N.ravel()
        return mi.Float(rows.ravel().astype(np.float32))

    @staticmethod
    def apply(table, shape_id, p, n):
        """(previous position, previous normal) of points ``p`` with normals ``n`` on shapes ``shape_id``
        (the normal is renormalised only where the map is not rigid: a rigid row leaves it as before)."""
        base = shape_id * 21
        m = [dr.gather(mi.Float, table, base + k) for k in range(21)]
        px = m[0] * p.x + m[1] * p.y + m[2] * p.z + m[9]
        py = m[3] * p.x + m[4] * p.y + m[5] * p.z + m[10]
        pz = m[6] * p.x + m[7] * p.y + m[8] * p.z + m[11]
        nx = m[12] * n.x + m[13] * n.y + m[14] * n.z
        ny = m[15] * n.x + m[16] * n.y + m[17] * n.z
        nz = m[18] * n.x + m[19] * n.y + m[20] * n.z
        nn = mi.Vector3f(nx, ny, nz)
        nn = dr.select(dr.abs(dr.squared_norm(nn) - 1.0) > 1e-4, dr.normalize(nn), nn)
        return mi.Point3f(px, py, pz), nn


@dataclass
class Reprojection:
    """Per-pixel reprojection of the current G-buffer into the previous one."""

    prev_pos: "mi.Point3f"
    prev_normal: "mi.Vector3f"
    prev_xy: "mi.Point2f"        # continuous pixel coordinates in the previous frame
    motion: "mi.Vector2f"        # prev_xy - this pixel's centre (pixels)
    prev_pixel: "mi.UInt32"      # nearest previous pixel (flat index; 0 where invalid)
    valid: "mi.Bool"             # not disoccluded (the disocclusion mask is ~valid on valid hits)


def similar(depth_a, n_a, depth_b, n_b, valid_b, depth_tol=DEPTH_TOL, normal_tol_deg=NORMAL_TOL_DEG):
    """Bitterli's neighbour similarity test: relative depth within ``depth_tol``, normals within the angle."""
    cos_tol = float(np.cos(np.radians(normal_tol_deg)))
    return valid_b & (dr.abs(depth_a - depth_b) <= depth_tol * depth_a) & (dr.dot(n_a, n_b) >= cos_tol)


class GBufferHistory:
    """Keeps the previous frame's G-buffer and camera; computes motion and the disocclusion mask."""

    def __init__(self, scene, depth_tol: float = DEPTH_TOL, normal_tol_deg: float = NORMAL_TOL_DEG):
        self.scene = scene
        self.motion = ShapeMotion(scene)
        self.depth_tol = depth_tol
        self.normal_tol_deg = normal_tol_deg
        self.prev: GBuffer | None = None
        self.cur: GBuffer | None = None

    def push(self, gb: GBuffer) -> None:
        """Make ``gb`` the current G-buffer; the current one becomes the previous."""
        self.prev, self.cur = self.cur, gb

    def reproject(self, gb: GBuffer | None = None, prev: GBuffer | None = None) -> Reprojection:
        gb = gb if gb is not None else self.cur
        prev = prev if prev is not None else self.prev
        w, h = gb.res
        n = w * h
        if prev is None or tuple(prev.res) != tuple(gb.res):
            z = dr.zeros(mi.Point3f, n)
            return Reprojection(z, dr.zeros(mi.Vector3f, n), dr.zeros(mi.Point2f, n), dr.zeros(mi.Vector2f, n),
                                dr.zeros(mi.UInt32, n), dr.full(mi.Bool, False, n))
        table = self.motion.table(gb.time, prev.time)
        p0, n0 = ShapeMotion.apply(table, gb.shape_id, gb.pos, gb.n_sh)
        x, y, front = project(prev.camera, prev.res, p0)
        idx = dr.arange(mi.UInt32, n)
        cx = mi.Float(idx % w) + 0.5
        cy = mi.Float(idx // w) + 0.5
        inside = front & (x >= 0.0) & (x < w) & (y >= 0.0) & (y < h) & gb.valid
        ix = mi.UInt32(dr.clip(mi.Int32(dr.floor(x)), 0, w - 1))
        iy = mi.UInt32(dr.clip(mi.Int32(dr.floor(y)), 0, h - 1))
        pp = dr.select(inside, iy * w + ix, 0)
        prev_depth = dr.gather(mi.Float, prev.depth, pp, inside)
        prev_n = dr.gather(mi.Vector3f, prev.n_sh, pp, inside)
        prev_valid = dr.gather(mi.Bool, prev.valid, pp, inside)
        o_prev = dr.opaque(mi.Point3f, [float(c) for c in prev.camera.origin])
        depth_expect = dr.norm(p0 - o_prev)
        ok = inside & similar(depth_expect, n0, prev_depth, prev_n, prev_valid, self.depth_tol,
                              self.normal_tol_deg)
        r = Reprojection(p0, n0, mi.Point2f(x, y), mi.Vector2f(x - cx, y - cy), pp, ok)
        dr.eval(r.prev_pos, r.prev_normal, r.prev_xy, r.motion, r.prev_pixel, r.valid)
        return r
