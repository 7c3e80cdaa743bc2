"""Procedural triangle meshes (numpy) and their conversion to Mitsuba meshes; a mesh's triangles read
back (:func:`mesh_triangles`) and uploaded as Dr.Jit points (:func:`to_point`), shared by the emitter table
(:mod:`dyngi.lights.emitter_table`) and the motion vectors (:mod:`dyngi.directions.motion`).

All built-in geometry is triangle meshes so that every shape can be moved the
same way (``vertex_positions``) and every shape has a stable id (its key in the
scene dictionary). Builders return ``(V, F)``: float (n, 3) vertices and int
(m, 3) counter-clockwise faces seen from the outside (normal = front).
"""
from __future__ import annotations

import numpy as np

from ..backend import mi, upload
from ..errors import DyngiError


def quad(center, u, v):
    """Parallelogram ``center +- u +- v``; normal along ``cross(u, v)``."""
    c, u, v = (np.asarray(a, np.float64) for a in (center, u, v))
    V = np.array([c - u - v, c + u - v, c + u + v, c - u + v])
    F = np.array([[0, 1, 2], [0, 2, 3]])
    return V, F


def box(lo, hi, inward: bool = False):
    """Axis-aligned box [lo, hi] as 12 triangles, normals outward (inward=True flips)."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    c = 0.5 * (lo + hi)
    e = 0.5 * (hi - lo)
    parts = []
    for ax in range(3):
        for s in (-1.0, 1.0):
            n = np.zeros(3); n[ax] = s
            a1, a2 = (ax + 1) % 3, (ax + 2) % 3
            u = np.zeros(3); u[a1] = e[a1]
            v = np.zeros(3); v[a2] = e[a2]
            if s < 0:
                u, v = v, u
            parts.append(quad(c + n * e[ax], u, v))
    V, F = merge(parts)
    if inward:
        F = F[:, ::-1]
    return V, F


def uv_sphere(center, radius, n_theta: int = 16, n_phi: int = 32, inward: bool = False):
    """Latitude-longitude sphere (flat-shaded triangles)."""
    th = np.linspace(0.0, np.pi, n_theta + 1)
    ph = np.linspace(0.0, 2 * np.pi, n_phi + 1)
    T, P = np.meshgrid(th, ph, indexing="ij")
    V = np.stack([np.sin(T) * np.cos(P), np.cos(T), np.sin(T) * np.sin(P)], -1).reshape(-1, 3)
    V = V * radius + np.asarray(center, np.float64)
    idx = np.arange((n_theta + 1) * (n_phi + 1)).reshape(n_theta + 1, n_phi + 1)
    a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    c, d = idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    F = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    # drop degenerate triangles at the poles
    A, B, C = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    F = F[np.linalg.norm(np.cross(B - A, C - A), axis=1) > 1e-12]
    if inward:
        F = F[:, ::-1]
    return V, F


def cylinder(center, radius, height, n: int = 32, inward: bool = False, caps: bool = True):
    """Vertical (y) cylinder, base at center.y, optionally capped."""
    c = np.asarray(center, np.float64)
    ang = np.linspace(0, 2 * np.pi, n, endpoint=False)
    ring = np.stack([np.cos(ang) * radius, np.zeros(n), np.sin(ang) * radius], 1)
    V = np.concatenate([ring + c, ring + c + [0, height, 0]])
    i = np.arange(n); j = (i + 1) % n
    F = np.concatenate([np.stack([i, n + j, j], 1), np.stack([i, n + i, n + j], 1)])
    if caps:
        V = np.concatenate([V, [c, c + [0, height, 0]]])
        b, t = 2 * n, 2 * n + 1
        F = np.concatenate([F, np.stack([np.full(n, b), i, j], 1), np.stack([np.full(n, t), n + j, n + i], 1)])
    if inward:
        F = F[:, ::-1]
    return V, F


def merge(parts):
    """Concatenate several (V, F) into one mesh."""
    Vs, Fs, off = [], [], 0
    for V, F in parts:
        Vs.append(V); Fs.append(F + off); off += len(V)
    return np.concatenate(Vs), np.concatenate(Fs)


def check_finite(V, name: str) -> None:
    if not np.all(np.isfinite(V)):
        bad = int(np.sum(~np.all(np.isfinite(V), axis=1)))
        raise DyngiError(f"mesh '{name}' has {bad} vertices with NaN/Inf coordinates")


def make_mesh(name: str, V, F, bsdf, emitter=None) -> "mi.Mesh":
    """A Mitsuba mesh from numpy arrays with a BSDF (and optional area emitter)."""
    V = np.asarray(V, np.float32)
    F = np.asarray(F, np.uint32)
    check_finite(V, name)
    if F.size and F.max() >= len(V):
        raise DyngiError(f"mesh '{name}' has face indices out of range")
    props = mi.Properties()
    props["bsdf"] = bsdf if not isinstance(bsdf, dict) else mi.load_dict(bsdf)
    if emitter is not None:
        props["emitter"] = emitter if not isinstance(emitter, dict) else mi.load_dict(emitter)
    m = mi.Mesh(name, len(V), len(F), props, has_vertex_normals=False)
    p = mi.traverse(m)
    p["vertex_positions"] = mi.Float(V.ravel())
    p["faces"] = mi.UInt32(F.ravel())
    p.update()
    return m


def diffuse(rgb) -> dict:
    return {"type": "diffuse", "reflectance": {"type": "rgb", "value": list(map(float, rgb))}}


def area_light(rgb) -> dict:
    return {"type": "area", "radiance": {"type": "rgb", "value": list(map(float, rgb))}}


def mesh_triangles(sh):
    """(p0, p1, p2) float64 arrays [F, 3] of a mesh's triangles (current vertex positions)."""
    V = np.asarray(sh.vertex_positions_buffer(), np.float64).reshape(-1, 3)
    F = np.asarray(sh.faces_buffer(), np.int64).reshape(-1, 3)
    return V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]


def to_point(a, cls=mi.Point3f):
    """NumPy [N, 3] (any float type) -> a Dr.Jit 3-vector of type ``cls`` (float32, in Dr.Jit's own memory:
    :func:`dyngi.backend.upload`)."""
    a = np.asarray(a, np.float32).reshape(-1, 3)
    return cls(*upload(mi.Float, a[:, 0], a[:, 1], a[:, 2]))
