"""The viewer's interactive camera: orbit and fly controls over a :class:`dyngi.scene.Camera`.

The page sends input as small relative moves (a drag in pixels, a wheel step, a fly step of ``dt``
seconds along view axes); :class:`ViewCamera` applies them on the server, so the page holds no
camera state and every client sees the same view.

* **orbit** (left drag): the origin turns about the target, yaw about the scene's up vector and pitch
  about the camera's horizontal axis, kept 2 degrees off the poles;
* **pan** (right or shift drag): origin and target move together in the image plane, scaled by the
  distance to the target so a drag follows the cursor at the target's depth;
* **zoom** (wheel): the distance to the target scales by ``exp(0.1 * steps)``, never below 1e-3 of
  the scene's size;
* **fly** (W/A/S/D, Q/E keys): origin and target move together along the view direction, the
  horizontal axis and up, at ``fly_speed`` (a third of the scene's diagonal per second; shift x4);
* **look** (fly-mode drag, arrow keys): the view direction turns about the origin.

Conventions are those of :class:`dyngi.scene.Camera` (Mitsuba's ``look_at``: ``left = up x dir``);
"right" on screen is ``-left``.
"""
from __future__ import annotations

import math

import numpy as np

from ..scene.camera import Camera

ORBIT_RAD_PER_PX = 0.008
LOOK_RAD_PER_PX = 0.004
ZOOM_PER_STEP = 0.1
POLE_MARGIN = math.radians(2.0)


def _unit(v):
    v = np.asarray(v, np.float64)
    n = np.linalg.norm(v)
    return v / n if n > 0 else v


def _rotate(v, axis, angle):
    """Rodrigues rotation of ``v`` about the unit ``axis``."""
    k = _unit(axis)
    v = np.asarray(v, np.float64)
    c, s = math.cos(angle), math.sin(angle)
    return v * c + np.cross(k, v) * s + k * np.dot(k, v) * (1.0 - c)


class ViewCamera:
    """Mutable look-at camera with orbit/pan/zoom/fly/look moves (see the module docstring)."""

    def __init__(self, camera: Camera, scene_size: float = 1.0):
        self.scene_size = float(max(scene_size, 1e-6))
        self.fly_speed = self.scene_size / 3.0
        self.set(camera)

    # -- state ---------------------------------------------------------------------------------
    def set(self, camera: Camera) -> None:
        self.origin = np.asarray(camera.origin, np.float64).copy()
        self.target = np.asarray(camera.target, np.float64).copy()
        self.world_up = _unit(camera.up)
        self.fov = float(camera.fov)

    def camera(self) -> Camera:
        return Camera(tuple(self.origin), tuple(self.target), tuple(self.world_up), self.fov)

    def signature(self) -> tuple:
        return self.camera().signature()

    @property
    def distance(self) -> float:
        return float(np.linalg.norm(self.target - self.origin))

    def _axes(self):
        d = _unit(self.target - self.origin)
        left = np.cross(self.world_up, d)
        if np.linalg.norm(left) < 1e-9:       # looking along up: any horizontal axis
            left = np.cross(_unit(self.world_up + 1e-3 * np.array([1.0, 0.3, 0.7])), d)
        left = _unit(left)
        return d, -left, np.cross(d, left)    # dir, right, up (screen)

    def _clamp_pitch(self, d_new, d_old):
        """``d_new`` unless it comes within POLE_MARGIN of the up axis (then ``d_old``)."""
        cos_up = float(np.dot(_unit(d_new), self.world_up))
        return d_new if abs(cos_up) < math.cos(POLE_MARGIN) else d_old

    # -- moves ---------------------------------------------------------------------------------
    def orbit(self, dx: float, dy: float) -> None:
        """Turn the origin about the target by a drag of (dx, dy) pixels."""
        off = self.origin - self.target
        off = _rotate(off, self.world_up, -dx * ORBIT_RAD_PER_PX)
        _, right, _ = self._axes()
        new = _rotate(off, right, -dy * ORBIT_RAD_PER_PX)
        off = -self._clamp_pitch(-new, -off)
        self.origin = self.target + off

    def look(self, dx: float, dy: float) -> None:
        """Turn the view direction about the origin by a drag of (dx, dy) pixels."""
        dist = self.distance
        d, right, _ = self._axes()
        d2 = _rotate(d, self.world_up, -dx * LOOK_RAD_PER_PX)
        d3 = _rotate(d2, right, -dy * LOOK_RAD_PER_PX)
        d = self._clamp_pitch(d3, d2)
        self.target = self.origin + _unit(d) * dist

    def pan(self, dx: float, dy: float, height_px: float = 400.0) -> None:
        """Move origin and target in the image plane by a drag of (dx, dy) pixels on a view ``height_px`` tall."""
        _, right, up = self._axes()
        scale = 2.0 * self.distance * math.tan(math.radians(self.fov) / 2.0) / max(height_px, 1.0)
        delta = (-dx * right + dy * up) * scale
        self.origin = self.origin + delta
        self.target = self.target + delta

    def zoom(self, steps: float) -> None:
        """Scale the distance to the target by ``exp(ZOOM_PER_STEP * steps)`` (positive: away)."""
        off = self.origin - self.target
        dist = max(np.linalg.norm(off) * math.exp(ZOOM_PER_STEP * float(steps)), 1e-3 * self.scene_size)
        self.origin = self.target + _unit(off) * dist

    def fly(self, forward: float, right: float, up: float, dt: float, fast: bool = False) -> None:
        """Move origin and target along the view axes for ``dt`` seconds (each axis in [-1, 1])."""
        d, r, _ = self._axes()
        v = np.clip([forward, right, up], -1.0, 1.0)
        step = self.fly_speed * (4.0 if fast else 1.0) * float(np.clip(dt, 0.0, 0.5))
        delta = (v[0] * d + v[1] * r + v[2] * self.world_up) * step
        self.origin = self.origin + delta
        self.target = self.target + delta

    def apply(self, msg: dict) -> None:
        """Apply one camera message from the page (``op``: orbit, look, pan, zoom, fly, set)."""
        op = msg.get("op")
        saved = (self.origin.copy(), self.target.copy(), self.fov)
        try:
            self._apply(op, msg)
        except Exception:
            self.origin, self.target, self.fov = saved
            raise

    def _apply(self, op, msg: dict) -> None:
        num = lambda k, d=0.0: float(msg.get(k, d))  # noqa: E731
        if op == "orbit":
            self.orbit(num("dx"), num("dy"))
        elif op == "look":
            self.look(num("dx"), num("dy"))
        elif op == "pan":
            self.pan(num("dx"), num("dy"), num("height", 400.0))
        elif op == "zoom":
            self.zoom(num("steps"))
        elif op == "fly":
            self.fly(num("forward"), num("right"), num("up"), num("dt"), bool(msg.get("fast", False)))
        elif op == "set":
            cam = Camera(tuple(map(float, msg["origin"])), tuple(map(float, msg["target"])),
                         tuple(self.world_up), float(msg.get("fov", self.fov)))
            self.set(cam)
        else:
            raise ValueError(f"unknown camera op '{op}'; valid: orbit, look, pan, zoom, fly, set, reset")
        if not (np.all(np.isfinite(self.origin)) and np.all(np.isfinite(self.target))):
            raise ValueError("camera move gave a non-finite position")
