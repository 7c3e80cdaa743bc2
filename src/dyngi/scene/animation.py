"""Keyframed animation tracks and the animators that apply them to Mitsuba parameters.

A :class:`Track` maps time (seconds) to a vector by piecewise-linear (or
smoothstep, or step) interpolation between keyframes; ``loop=True`` wraps time
by the last key's time. Animators own a track and write one parameter of the
``mi.traverse`` dictionary of the scene, always from a base value captured at
load time, so ``scene.at(t)`` is idempotent and order independent.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field

import numpy as np

from ..errors import DyngiError

INTERPOLATIONS = ("linear", "smooth", "step")


@dataclass
class Track:
    """Keyframes ``values[k]`` at ``times[k]`` (strictly increasing)."""

    times: np.ndarray
    values: np.ndarray
    interp: str = "linear"
    loop: bool = False

    def __post_init__(self):
        self.times = np.asarray(self.times, dtype=np.float64).ravel()
        v = np.asarray(self.values, dtype=np.float64)
        self.values = v.reshape(len(self.times), -1)
        if len(self.times) == 0:
            raise DyngiError("animation track has no keyframes")
        if np.any(np.diff(self.times) <= 0):
            raise DyngiError("animation track times must be strictly increasing")
        if self.interp not in INTERPOLATIONS:
            raise DyngiError(f"unknown interpolation '{self.interp}'; valid: {', '.join(INTERPOLATIONS)}")
        if not np.all(np.isfinite(self.values)):
            raise DyngiError("animation track has NaN/Inf keyframe values")

    def __call__(self, t: float) -> np.ndarray:
        times, vals = self.times, self.values
        if len(times) == 1:
            return vals[0].copy()
        if self.loop and times[-1] > 0:
            t = float(np.mod(t, times[-1]))
        if t <= times[0]:
            return vals[0].copy()
        if t >= times[-1]:
            return vals[-1].copy()
        k = int(np.searchsorted(times, t, side="right") - 1)
        a = (t - times[k]) / (times[k + 1] - times[k])
        if self.interp == "step":
            a = 0.0
        elif self.interp == "smooth":
            a = a * a * (3.0 - 2.0 * a)
        return (1.0 - a) * vals[k] + a * vals[k + 1]

    @staticmethod
    def constant(value) -> "Track":
        return Track([0.0], [np.asarray(value, dtype=np.float64)])


def rotation_matrix(axis, angle_rad: float) -> np.ndarray:
    """Rodrigues rotation about a unit axis (3x3)."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle_rad) * K + (1 - np.cos(angle_rad)) * (K @ K)


class Animator(ABC):
    """Writes animated values into a ``mi.traverse`` parameter dict."""

    #: the shape id this animator moves (None for emitter-only animators)
    shape: str | None = None

    def bind(self, params) -> None:
        """Capture base values from the freshly loaded scene's parameters."""

    @abstractmethod
    def apply(self, params, t: float) -> None:
        """Write the state at time t into ``params`` (no ``update()``)."""

    @abstractmethod
    def signature(self, t: float) -> tuple:
        """Values that determine the state at t (to detect a static scene)."""


@dataclass
class RigidMotion(Animator):
    """Rigid transform of one mesh: translation track and rotation about ``pivot``.

    Writes ``<shape>.vertex_positions`` (and normals when present) from the
    vertices captured at bind time; the acceleration structure is rebuilt by
    ``params.update()`` (Mitsuba has no refit).
    """

    shape: str
    translate: Track | None = None
    angle: Track | None = None  # radians about `axis` through `pivot`
    axis: tuple = (0.0, 1.0, 0.0)
    pivot: tuple = (0.0, 0.0, 0.0)
    _base_p: np.ndarray | None = field(default=None, repr=False)
    _base_n: np.ndarray | None = field(default=None, repr=False)

    def bind(self, params):
        key = f"{self.shape}.vertex_positions"
        if key not in params:
            raise DyngiError(f"animated shape '{self.shape}' is not a mesh of this scene")
        self._base_p = np.array(params[key], dtype=np.float64).reshape(-1, 3)
        nkey = f"{self.shape}.vertex_normals"
        n = np.array(params[nkey], dtype=np.float64) if nkey in params else np.zeros(0)
        self._base_n = n.reshape(-1, 3) if n.size == self._base_p.size else None

    #: ``transform`` returns an orthonormal R (the G-buffer inverts it by its transpose)
    rigid = True

    def transform(self, t: float):
        R = rotation_matrix(self.axis, float(self.angle(t)[0])) if self.angle is not None else np.eye(3)
        d = self.translate(t) if self.translate is not None else np.zeros(3)
        return R, d

    def apply(self, params, t):
        R, d = self.transform(t)
        piv = np.asarray(self.pivot, dtype=np.float64)
        p = (self._base_p - piv) @ R.T + piv + d
        params[f"{self.shape}.vertex_positions"] = p.astype(np.float32).ravel()
        if self._base_n is not None:
            params[f"{self.shape}.vertex_normals"] = (self._base_n @ R.T).astype(np.float32).ravel()

    def signature(self, t):
        R, d = self.transform(t)
        return tuple(np.round(np.concatenate([R.ravel(), d]), 9))


@dataclass
class AffineMotion(Animator):
    """An affine motion of one mesh: ``p(t) = M(t) (p_base - pivot) + pivot + d(t)``.

    The public interface the G-buffer's motion reprojection reads (and any shape animator can mirror):
    ``shape`` (the mesh's id), ``pivot`` (3,) and ``transform(t) -> (M 3x3, d 3)``; here ``transform`` is the
    callable ``motion``. ``M`` need not be orthonormal (scale, shear; a glTF node's world matrix), normals
    move by its inverse transpose and are renormalised. ``base`` gives the positions ``p_base`` (and
    ``base_normals`` the normals) the map applies to, e.g. a glTF mesh in its node's local space with
    ``pivot = 0`` so that ``M, d`` are the node's world matrix; without them the positions loaded into the
    scene are captured at bind time. Like :class:`RigidMotion` it writes every vertex per frame and Mitsuba
    rebuilds the mesh's acceleration structure (no refit).
    """

    shape: str
    motion: object = None           # t -> (M (3, 3), d (3,))
    pivot: tuple = (0.0, 0.0, 0.0)
    base: np.ndarray | None = field(default=None, repr=False)
    base_normals: np.ndarray | None = field(default=None, repr=False)

    def bind(self, params):
        key = f"{self.shape}.vertex_positions"
        if key not in params:
            raise DyngiError(f"animated shape '{self.shape}' is not a mesh of this scene")
        if self.base is None:
            self.base = np.array(params[key], dtype=np.float64).reshape(-1, 3)
            nkey = f"{self.shape}.vertex_normals"
            n = np.array(params[nkey], dtype=np.float64) if nkey in params else np.zeros(0)
            self.base_normals = n.reshape(-1, 3) if n.size == self.base.size else None
        self.base = np.asarray(self.base, np.float64).reshape(-1, 3)
        self._has_n = f"{self.shape}.vertex_normals" in params and self.base_normals is not None

    def transform(self, t: float):
        M, d = self.motion(float(t))
        return np.asarray(M, np.float64).reshape(3, 3), np.asarray(d, np.float64).reshape(3)

    def apply(self, params, t):
        M, d = self.transform(t)
        piv = np.asarray(self.pivot, dtype=np.float64)
        p = (self.base - piv) @ M.T + piv + d
        params[f"{self.shape}.vertex_positions"] = p.astype(np.float32).ravel()
        if self._has_n:
            n = self.base_normals @ np.linalg.inv(M)     # (M^-T n) as rows
            n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
            params[f"{self.shape}.vertex_normals"] = n.astype(np.float32).ravel()

    def signature(self, t):
        M, d = self.transform(t)
        return tuple(np.round(np.concatenate([M.ravel(), d]), 9))


@dataclass
class ParamTrack(Animator):
    """Drives one parameter (``key``) by a track, optionally as a scale of its base value.

    ``mode='scale'`` multiplies the loaded value (emitter intensity, on/off as a
    step track of 0/1); ``mode='set'`` writes the track value (point-light
    position, environment colour).
    """

    key: str
    track: Track
    mode: str = "scale"
    _base: np.ndarray | None = field(default=None, repr=False)

    def bind(self, params):
        if self.key not in params:
            raise DyngiError(f"animated parameter '{self.key}' does not exist in this scene")
        self._base = np.array(params[self.key], dtype=np.float64).ravel()

    def apply(self, params, t):
        v = self.track(t)
        val = self._base * v if self.mode == "scale" else v
        params[self.key] = val.astype(np.float32).tolist() if val.size <= 4 else val.astype(np.float32)

    def signature(self, t):
        return tuple(np.round(self.track(t), 9))


@dataclass
class SunMotion(Animator):
    """A directional emitter whose direction (towards the scene, i.e. light travel) follows a track."""

    emitter: str
    direction: Track

    def apply(self, params, t):
        import mitsuba as mi  # variant already selected by dyngi.backend

        d = self.direction(t)
        d = d / np.linalg.norm(d)
        up = [0.0, 0.0, 1.0] if abs(d[1]) > 0.99 else [0.0, 1.0, 0.0]
        params[f"{self.emitter}.to_world"] = mi.ScalarTransform4f().look_at(
            origin=[0.0, 0.0, 0.0], target=d.tolist(), up=up)

    def signature(self, t):
        return tuple(np.round(self.direction(t), 9))
