"""What a ray sees at its first hit, shaded from the ray's side: one owner of the side rules that the probes,
the VPLs, the light samplers and the path walk share (issue 37; formerly ``probes.trace.shading_side``,
``lights.nee.shading_normal`` and ``vpl.points._surface``).

* :func:`shading_side`: the lanes whose surface is shaded from the ray's side (the geometric normal's test,
  with two-sided BSDFs shaded from behind), and the shading normal on that side;
* :func:`shading_normal`: the shading normal turned to the side of ``si.wi`` (the shading frame's test,
  used by the path walk and its light samplers at every vertex);
* :func:`diffuse_surface`: the first hit with its front mask, side normal and diffuse albedo.
"""
from __future__ import annotations

from ..backend import dr, mi
from ..rays import intersect
from ..sampling.diffuse import diffuse_albedo


def shading_side(si, ray, bsdf, hit):
    """(facing, n): the lanes whose surface is shaded from the ray's side, and the shading normal on it.

    A surface faces the ray where its geometric normal does (``dot(n, d) < 0``) or, seen from behind,
    where its BSDF reflects on both sides (``BSDFFlags.BackSide``: ``twosided``, as real scenes model
    single walls); there the shading normal is flipped to the ray's side. Our choice: Mitsuba shades
    the back of a two-sided surface like its front, so must the probes and the primary shading. The
    probe-ray distance sign is another matter: :func:`dyngi.probes.trace.probe_hit_front` (the two-sided rule).
    """
    geo_front = dr.dot(si.n, ray.d) < 0.0
    two_sided = mi.has_flag(bsdf.flags(), mi.BSDFFlags.BackSide) & (bsdf != None)   # noqa: E711
    facing = hit & (geo_front | two_sided)
    n = dr.select(geo_front, si.sh_frame.n, -si.sh_frame.n)
    return facing, n


def shading_normal(si):
    """The shading normal turned to the side of ``si.wi``."""
    return mi.Vector3f(dr.select(mi.Frame3f.cos_theta(si.wi) >= 0.0, si.sh_frame.n, -si.sh_frame.n))


def diffuse_surface(mscene, ray, active, *, stage: str = "trace", lanes: bool = False):
    """(si, front mask, shading normal facing the ray, diffuse albedo) of the first hit (the ray counted under
    ``stage``, :mod:`dyngi.rays`; ``lanes``: not counted here, the caller inside a symbolic loop counts it per
    lane and adds the count after its loop)."""
    si = intersect(mscene, ray, mi.RayFlags.All, False, active, stage=stage, lanes=lanes)
    hit = si.is_valid() & active
    bsdf = si.bsdf(ray)
    front, n = shading_side(si, ray, bsdf, hit)
    alb = diffuse_albedo(bsdf, si, front)
    ok = front & (dr.max(alb) > 0.0)
    return si, ok, n, alb
