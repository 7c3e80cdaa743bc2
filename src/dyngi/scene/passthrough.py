"""Rays that pass through glass: ``dielectric``, ``thindielectric`` and ``null`` surfaces.

Real-time GI engines treat window panes, lamp shades and other clear surfaces
as *transparent occluders* for diffuse GI: shadow rays and probe rays go
straight through them, attenuated by their transmittance, instead of being
blocked (an opaque pane would keep the sun out of a room) or refracted (which
needs a path tracer). We do the same, **a deliberate bias**:

* a ray continues straight through up to :data:`MAX_GLASS_LAYERS` such
  surfaces (a double-glazed window is 4 interfaces); a ray that meets more
  is treated as blocked;
* the attenuation per surface is Mitsuba's own straight-through transmittance
  of that BSDF: ``null`` 1; ``thindielectric`` its null-lobe transmission
  (``bsdf.eval_null_transmission``, ``1 - R'`` of the slab with both
  interfaces and their interreflection); ``dielectric`` (one interface per
  hit) ``1 - F(cos)``, read as the weight of a delta-transmission-only
  ``bsdf.sample`` in importance mode (no ``1/eta^2`` radiance scaling; for a
  pane the two interfaces' scalings cancel anyway);
* neither refraction (the ray is not bent), nor light reflected by the glass,
  nor caustics are modelled.

A surface passes rays when its BSDF has only delta and null lobes and at
least one transmitting one (the three plugins above); a ``mask`` (null +
opaque lobes), ``roughdielectric`` or ``principled`` surface is opaque here.
Primary (camera) rays pass only *thin* clear surfaces (null lobe:
``thindielectric``, ``null``), where the image behind is unshifted; a solid
``dielectric`` seen by the camera is shaded as an opaque surface without a
diffuse lobe (black apart from NEE through it), our choice.

Scenes without any such surface take the plain ``ray_test`` /
``ray_intersect`` path (:func:`scene_has_glass`), so they pay nothing.

Every ray is traced through :mod:`dyngi.rays` and counted there (issue 40): the first ray and each
continuation through a clear surface; a per-lane counter of the loop is added after it (:func:`count_lanes`).
"""
from __future__ import annotations

from .. import rays
from ..backend import dr, mi

MAX_GLASS_LAYERS = 4     # clear surfaces a shadow/probe ray passes at most (our choice: a double-glazed window)

F = mi.BSDFFlags
_CLEAR_LOBES = F.Null | F.DeltaReflection | F.DeltaTransmission


def clear_mask(bsdf, thin_only: bool = False):
    """Per lane: does ``bsdf`` (a BSDFPtr) let rays pass straight through (see the module docstring)?
    With ``thin_only`` only null-lobe surfaces (``thindielectric``, ``null``) count."""
    lobes = mi.UInt32(bsdf.flags()) & mi.UInt32(int(F.All))
    only_clear = (lobes & ~mi.UInt32(int(_CLEAR_LOBES))) == 0
    passing = mi.UInt32(int(F.Null)) if thin_only else mi.UInt32(int(F.Null | F.DeltaTransmission))
    return (bsdf != None) & only_clear & ((lobes & passing) != 0)   # noqa: E711


def clear_transmittance(bsdf, si, active):
    """Straight-through transmittance of a clear surface hit at ``si`` (see the module docstring).

    Both faces of a solid pane are evaluated as seen from outside (``|cos|``): the unbent ray leaves a
    pane at its entry angle, where the inside's total internal reflection would wrongly stop it, and a
    slab's two interfaces transmit equally."""
    outside = mi.SurfaceInteraction3f(si)
    outside.wi = mi.Vector3f(si.wi.x, si.wi.y, dr.abs(si.wi.z))
    T = mi.Color3f(bsdf.eval_null_transmission(outside, active))
    ctx = mi.BSDFContext(mi.TransportMode.Importance, F.DeltaTransmission)
    delta_t = active & mi.has_flag(bsdf.flags(), F.DeltaTransmission)
    _, w = bsdf.sample(ctx, outside, 0.5, mi.Point2f(0.5), delta_t)
    return T + dr.select(delta_t, mi.Color3f(w), 0.0)


_HAS_GLASS: dict = {}     # the most recent scene -> bool


def count_lanes(stage: str, n, lanes: bool = False, schedule: bool = True) -> None:
    """Add the per-lane ray counter ``n`` of a loop (after the loop) to the open ray ledgers
    (:func:`dyngi.rays.add`), unless ``lanes``: the caller counts them (a caller inside a symbolic loop
    of its own). The counter is read when a ledger's total is asked for (no reduction, no wait here);
    ``schedule``: computed by the next kernel (with the loop's other outputs; for a counter the caller does
    not evaluate itself: left unevaluated, reading it would trace the loop again)."""
    if lanes:
        return
    if dr.flag(dr.JitFlag.SymbolicScope):
        raise RuntimeError(f"rays ({stage}): a ray traced in a symbolic loop needs lanes=True and a per-lane "
                           "counter added after the loop (dyngi.rays.add)")
    n = mi.UInt32(n)
    if schedule:
        dr.schedule(n)
    rays.add(stage, n)


def scene_has_glass(mi_scene) -> bool:
    """Host check, cached for the latest scene: does any shape carry a pass-through BSDF?"""
    key = _HAS_GLASS.get("scene")
    if key is not mi_scene:
        found = False
        for shape in mi_scene.shapes():
            b = shape.bsdf()
            if b is None:
                continue
            lobes = int(b.flags()) & int(F.All)
            if lobes and not (lobes & ~int(_CLEAR_LOBES)) and lobes & int(F.Null | F.DeltaTransmission):
                found = True
                break
        _HAS_GLASS.clear()
        _HAS_GLASS.update(scene=mi_scene, value=found)
    return _HAS_GLASS["value"]


@dr.syntax
def intersect_through_glass(scene, ray, active, thin_only: bool = False, layers: int = MAX_GLASS_LAYERS,
                            stage: str = "trace"):
    """First opaque hit along ``ray``, passing up to ``layers`` clear surfaces.

    Returns ``(si, throughput, t, passes)``: the surface interaction of the
    first opaque surface (invalid on a miss; where more than ``layers`` clear
    surfaces were met, the last one with throughput 0), the product of the
    clear surfaces' transmittances on the way, the total distance from the
    original origin (``inf`` on a miss) and the number of continuation rays
    per lane. A Dr.Jit symbolic loop; its rays are counted under ``stage``
    (:mod:`dyngi.rays`).
    """
    active = mi.Bool(active)
    ray = mi.Ray3f(ray)
    si = rays.intersect(scene, ray, mi.RayFlags.All, False, active, stage=stage, lanes=True)
    n_rays = mi.UInt32(active)
    throughput = mi.Color3f(1.0)
    t = mi.Float(0.0)
    depth = mi.UInt32(0)
    bsdf = si.bsdf(ray)
    clear = active & si.is_valid() & clear_mask(bsdf, thin_only)
    while clear:
        throughput *= clear_transmittance(bsdf, si, clear)
        depth += 1
        blocked = clear & (depth > layers)
        throughput[blocked] = mi.Color3f(0.0)
        go = clear & ~blocked
        t[go] = t + si.t
        ray[go] = si.spawn_ray(ray.d)
        si[go] = rays.intersect(scene, ray, mi.RayFlags.All, False, go, stage=stage, lanes=True)
        n_rays[go] = n_rays + 1
        bsdf = si.bsdf(ray)
        clear = go & si.is_valid() & clear_mask(bsdf, thin_only)
    count_lanes(stage, n_rays)
    t_out = dr.select(si.is_valid(), t + si.t, dr.inf)
    return si, throughput, t_out, depth


@dr.syntax
def shadow_transmittance(scene, ray, active, layers: int = MAX_GLASS_LAYERS, stage: str = "shadow",
                         lanes: bool = False):     # (no keyword-only parameters: @dr.syntax drops their defaults)
    """Visibility along a shadow ray segment (up to ``ray.maxt``): 0 where an opaque surface (or more
    than ``layers`` clear ones) blocks it, else the product of the transmittances of the clear surfaces
    passed. A Dr.Jit symbolic loop. Its rays are counted under ``stage`` (:mod:`dyngi.rays`); with
    ``lanes`` (a caller inside a symbolic loop of its own) they are not, and the result is a pair
    ``(visibility, rays traced per lane)`` for the caller's count."""
    active = mi.Bool(active)
    ray = mi.Ray3f(ray)
    si = rays.intersect(scene, ray, mi.RayFlags.All, False, active, stage=stage, lanes=True)
    n_rays = mi.UInt32(active)
    throughput = mi.Color3f(1.0)
    depth = mi.UInt32(0)
    bsdf = si.bsdf(ray)
    clear = active & si.is_valid() & clear_mask(bsdf)
    while clear:
        throughput[clear] = throughput * clear_transmittance(bsdf, si, clear)
        depth[clear] = depth + 1
        go = clear & (depth <= layers)
        remaining = ray.maxt - si.t
        ray[go] = si.spawn_ray(ray.d)
        ray.maxt[go] = remaining
        si[go] = rays.intersect(scene, ray, mi.RayFlags.All, False, go, stage=stage, lanes=True)
        n_rays[go] = n_rays + 1
        bsdf = si.bsdf(ray)
        clear = go & si.is_valid() & clear_mask(bsdf)
    vis = dr.select(active & ~si.is_valid(), throughput, 0.0)
    count_lanes(stage, n_rays, lanes)
    return (vis, n_rays) if lanes else vis
