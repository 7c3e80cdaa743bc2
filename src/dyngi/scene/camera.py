"""Pinhole camera whose primary rays match Mitsuba's ``perspective`` sensor.

Conventions (Mitsuba 3): ``look_at(origin, target, up)`` builds the frame
``left = normalize(cross(up, dir))``, ``up' = cross(dir, left)``; the field of
view ``fov`` (degrees) spans the image *width* (``fov_axis='x'``); pixel (0, 0)
is the top-left corner. A film position ``p`` in [0, 1]^2 maps to the camera
space direction ``((1 - 2 p.x) tan(fov/2), (1 - 2 p.y) tan(fov/2) / aspect, 1)``.

Camera parameters enter the ray-generation kernel as opaque Dr.Jit values,
so a moving camera never recompiles it. :meth:`Camera.to_sensor` builds the
equivalent Mitsuba sensor (box reconstruction filter, so a pixel is the plain
average over its footprint, as in our own renderer) for reference renders.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..backend import dr, mi
from ..errors import DyngiError
from .animation import Track


@dataclass
class Camera:
    origin: tuple
    target: tuple
    up: tuple = (0.0, 1.0, 0.0)
    fov: float = 45.0  # degrees, horizontal

    def __post_init__(self):
        vals = np.concatenate([np.ravel(self.origin), np.ravel(self.target), np.ravel(self.up), [self.fov]])
        if not np.all(np.isfinite(vals)):
            raise DyngiError("camera has NaN/Inf parameters")
        if not (0.0 < self.fov < 180.0):
            raise DyngiError(f"camera fov must be in (0, 180) degrees, got {self.fov}")
        if np.linalg.norm(np.subtract(self.target, self.origin)) == 0:
            raise DyngiError("camera origin and target coincide")

    def frame(self):
        """(left, up, dir) orthonormal basis as numpy vectors."""
        o = np.asarray(self.origin, np.float64)
        d = np.asarray(self.target, np.float64) - o
        d /= np.linalg.norm(d)
        left = np.cross(np.asarray(self.up, np.float64), d)
        if np.linalg.norm(left) < 1e-9:
            raise DyngiError("camera up vector is parallel to the view direction")
        left /= np.linalg.norm(left)
        up = np.cross(d, left)
        return left, up, d

    def project(self, res: tuple[int, int], pts: np.ndarray):
        """Host: image-plane coordinates ``(x, y)`` and depth ``z`` (along the view direction) of world points
        ``pts`` (N, 3), the inverse of :meth:`sample_rays`' camera model: ``x = (v . left) / (z tan(fov/2))``,
        ``y = (v . up) / (z tan(fov/2) / aspect)`` with ``v`` the point relative to the origin, so the image
        spans ``|x|, |y| <= 1`` for ``z > 0`` and the film position is ``((1 - x) / 2, (1 - y) / 2)`` (pixel
        (0, 0) top-left). Points at ``z = 0`` give inf/nan (no warning). The one projection of the camera
        (the probes' frustum test, the VPLs' visibility, the viewer's overlays)."""
        left, up, d = self.frame()
        w, h = res
        tanx = float(np.tan(np.radians(self.fov) * 0.5))
        tany = tanx / (w / h)
        v = np.asarray(pts, np.float64) - np.asarray(self.origin, np.float64)
        z = v @ d
        with np.errstate(divide="ignore", invalid="ignore"):
            x = (v @ left) / (z * tanx)
            y = (v @ up) / (z * tany)
        return x, y, z

    def signature(self) -> tuple:
        return tuple(np.round(np.concatenate([np.ravel(self.origin), np.ravel(self.target),
                                              np.ravel(self.up), [self.fov]]), 9))

    def sample_rays(self, res: tuple[int, int], pixel_index, sample2) -> "mi.Ray3f":
        """Primary rays for flat pixel indices (row-major, y down) and a 2D jitter in [0,1)^2."""
        w, h = res
        left, up, d = self.frame()
        tanx = float(np.tan(np.radians(self.fov) * 0.5))
        aspect = w / h
        x = mi.Float(pixel_index % w) + sample2.x
        y = mi.Float(pixel_index // w) + sample2.y
        px, py = x * (1.0 / w), y * (1.0 / h)
        # opaque camera parameters: a moving camera reuses the same kernel
        def opaque3(cls, v):
            return dr.opaque(cls, [float(c) for c in v])

        L = opaque3(mi.Vector3f, left * tanx)
        U = opaque3(mi.Vector3f, up * (tanx / aspect))
        D = opaque3(mi.Vector3f, d)
        O = opaque3(mi.Point3f, np.asarray(self.origin, np.float64))
        dirn = dr.normalize(L * (1.0 - 2.0 * px) + U * (1.0 - 2.0 * py) + D)
        return mi.Ray3f(O, dirn)

    def to_sensor(self, res: tuple[int, int], spp: int = 1) -> "mi.Sensor":
        w, h = res
        return mi.load_dict({
            "type": "perspective",
            "fov": float(self.fov),
            "fov_axis": "x",
            "to_world": mi.ScalarTransform4f().look_at(
                origin=list(map(float, self.origin)), target=list(map(float, self.target)),
                up=list(map(float, self.up))),
            "near_clip": 1e-3,
            "far_clip": 1e5,
            "sampler": {"type": "independent", "sample_count": int(spp)},
            "film": {"type": "hdrfilm", "width": int(w), "height": int(h),
                     "rfilter": {"type": "box"}, "pixel_format": "rgb"},
        })


def camera_from_bounds(lo, hi) -> Camera:
    """A camera looking at the box ``[lo, hi]`` from its +z side, a little above (45 degrees, horizontal): the
    default of a scene file without a camera."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    c = 0.5 * (lo + hi)
    r = 0.5 * np.linalg.norm(hi - lo)
    return Camera(tuple(c + [0.0, 0.2 * r, 2.2 * r]), tuple(c), (0, 1, 0), 45.0)


@dataclass
class CameraPath:
    """Camera animated by origin/target tracks (fov and up fixed)."""

    origin: Track
    target: Track
    up: tuple = (0.0, 1.0, 0.0)
    fov: float = 45.0

    @staticmethod
    def fixed(cam: Camera) -> "CameraPath":
        return CameraPath(Track.constant(cam.origin), Track.constant(cam.target), tuple(cam.up), cam.fov)

    def __call__(self, t: float) -> Camera:
        return Camera(tuple(self.origin(t)), tuple(self.target(t)), self.up, self.fov)


@dataclass
class PoseCameraPath:
    """Camera whose pose is a camera-to-world matrix function of time, looking down its local -Z with +Y up
    (a glTF camera node, Sec. 3.10 of the glTF 2.0 specification); ``fov`` horizontal, as :class:`Camera`'s."""

    pose: Callable[[float], np.ndarray]
    fov: float = 45.0

    @staticmethod
    def fixed_pose(M, fov: float) -> "PoseCameraPath":
        M = np.array(M, np.float64)
        return PoseCameraPath(lambda t: M, fov)

    def __call__(self, t: float) -> Camera:
        M = np.asarray(self.pose(float(t)), np.float64)
        o = M[:3, 3]
        fwd = -M[:3, 2] / np.linalg.norm(M[:3, 2])
        up = M[:3, 1] / np.linalg.norm(M[:3, 1])
        return Camera(tuple(o), tuple(o + fwd), tuple(up), self.fov)
