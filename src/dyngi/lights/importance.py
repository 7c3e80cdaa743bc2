"""The importance of an emitter triangle at a shading point, shared by the light tree, the SLL and the VLC.

:func:`triangle_irradiance` (VLC paper Sec. 4: "the unoccluded irradiance of a uniform polygonal
emitter", analytic for a diffuse receiver): Lambert's polygon formula
``E = L/2 * sum_edges theta_e * dot(n, gamma_e)`` (Lambert 1760; Arvo 1995, Eq. 4) of the triangle
clipped to the receiver's upper hemisphere, as a luminance.
"""
from __future__ import annotations

from ..backend import dr, mi
from ..color import luminance


def _luminance(c):
    if isinstance(c, (mi.Float, float, int)):
        return mi.Float(c)
    return luminance(mi.Color3f(c))


def _edge(u, v, n):
    """Lambert edge term ``theta * dot(n, normalize(cross(u, v)))`` for vectors u, v from the receiver.

    Written as ``dot(n, cross(û, v̂)) * theta / sin(theta)`` (stable for short edges: theta/sin -> 1)."""
    uh, vh = dr.normalize(u), dr.normalize(v)
    c = dr.clip(dr.dot(uh, vh), -1.0, 1.0)
    cr = dr.cross(uh, vh)
    s = dr.norm(cr)
    theta = dr.acos(c)
    f = dr.select(s > 1e-7, theta / dr.maximum(s, 1e-7), 1.0)
    return dr.dot(n, cr) * f


def triangle_irradiance(p, n, p0, e1, e2, radiance, active=True):
    """Unoccluded irradiance (luminance) at ``p`` (unit normal ``n``) from a uniform one-sided triangle.

    The triangle (p0, p0+e1, p0+e2) emits ``radiance`` (Color3f, or Float luminance) on the side of
    ``cross(e1, e2)``; a receiver behind its plane gets 0. The triangle is clipped to the receiver's
    upper hemisphere (the plane ``dot(n, x - p) = 0``) edge by edge, adding the horizon edge between the
    exit and entry points, then Lambert's formula ``E = L/2 |sum theta_e dot(n, gamma_e)|`` is exact for
    the clipped polygon (VLC paper Sec. 4 importance; Arvo 1995 Eq. 4). Branch-free: 3 edges + 1 horizon edge.
    """
    active = mi.Bool(active)
    p, n = mi.Point3f(p), mi.Vector3f(n)
    p0, e1, e2 = mi.Point3f(p0), mi.Vector3f(e1), mi.Vector3f(e2)
    ng = dr.cross(e1, e2)
    facing = dr.dot(ng, p - p0) > 0.0            # the receiver is on the emitting side
    a = p0 - p
    verts = [a, a + e1, a + e2]
    h = [dr.dot(n, v) for v in verts]
    total = mi.Float(0.0)
    exit_pt = dr.zeros(mi.Vector3f)
    entry_pt = dr.zeros(mi.Vector3f)
    clipped = mi.Bool(False)
    for i in range(3):
        va, vb = verts[i], verts[(i + 1) % 3]
        ha, hb = h[i], h[(i + 1) % 3]
        up_a, up_b = ha > 0.0, hb > 0.0
        t = ha / dr.select(ha != hb, ha - hb, 1.0)
        x = dr.fma(vb - va, t, va)             # where the edge crosses the horizon
        s0 = dr.select(up_a, va, x)
        s1 = dr.select(up_b, vb, x)
        total += dr.select(up_a | up_b, _edge(s0, s1, n), 0.0)
        leaving = up_a & ~up_b
        entering = ~up_a & up_b
        exit_pt = dr.select(leaving, x, exit_pt)
        entry_pt = dr.select(entering, x, entry_pt)
        clipped |= leaving
    # the horizon edge from the exit point to the entry point closes the clipped polygon
    total += dr.select(clipped, _edge(exit_pt, entry_pt, n), 0.0)
    E = 0.5 * dr.abs(total) * _luminance(radiance)
    return dr.select(active & facing & dr.isfinite(E), E, 0.0)
