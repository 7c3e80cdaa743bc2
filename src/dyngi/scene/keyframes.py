"""Keyframes for any Mitsuba XML scene: a TOML sidecar that animates the XML's objects by ``id``.

A sidecar ``<stem>.anim.toml`` beside ``<stem>.xml`` (found by :func:`sidecar_for`, or named on the
command line) holds keyframed tracks (:class:`~dyngi.scene.animation.Track`, interpolation ``step``,
``linear`` or ``smooth``) for

* ``[shapes.<id>]``: a rigid-plus-scale transform relative to the XML pose, ``x' = M(t) (x - pivot) +
  pivot + d(t)`` with ``M = R(axis, rotate) S(scale)`` (:class:`ShapeKeyframes`; meshes get new vertex
  positions and normals, analytic shapes -- rectangle, disk, sphere, cylinder -- a new ``to_world``);
* ``[emitters.<id>]``: a radiance / intensity / irradiance ``scale`` (an area light is named by its
  shape's id; it moves as a shape), the ``translate`` of a ``point`` or ``spot`` light, the sun's
  ``elevation`` / ``azimuth`` of a ``directional`` or ``sunsky`` emitter, the ``rotate`` angle of an
  ``envmap`` about ``axis``;
* ``[camera]``: ``position``, ``target``, ``up``, ``fov`` (horizontal, degrees).

The animation lasts until the last keyframe (``duration``); ``fps`` and ``loop`` are optional.
docs/keyframes.md is the reference of every key, its units and an example. Everything in the file is
checked before any work: each problem (unknown id, unknown property, non-increasing times, NaN/Inf,
a shape that Mitsuba cannot transform in place) is one line of the raised
:class:`~dyngi.errors.DyngiError`.

Mitsuba 3.9 merges the top-level meshes that share a BSDF when it loads an XML file (its parser's
``merge_meshes`` pass, part of ``mi.load_file(optimize=True)``), and the merged mesh has no id: the
cube ``ShortBox`` of the Cornell box becomes part of an anonymous mesh. :func:`attach` therefore
reloads the XML through ``mi.parser`` when the sidecar names a shape that the loaded scene no longer
has, with the named shapes taken out of that pass (every other pass, and the merging of every other
mesh, as Mitsuba does it); the ids of emitters and of the sensor survive either way.

The conventions are ours (no paper defines a sidecar): elevation and azimuth are measured in world
space about the file's ``up`` axis (default +Y, as in the Mitsuba XML scenes we ship), azimuth from
"north" (+Z for +Y up) towards "east" (+X), so the direction towards the sun is
``(cos(el) sin(az), sin(el), cos(el) cos(az))`` (:func:`sun_vector`). Mitsuba 3.9's ``sunsky`` takes its
``sun_direction`` in world space and has its own up at ``to_world`` applied to +Z (identity: +Z up), so a
sunsky whose up is not the file's ``up`` is an error, as is one placed by date and time (its
``sun_direction`` is read-only then). Rotations are right-handed, in degrees.
"""
from __future__ import annotations

import math
import os
import tomllib
from dataclasses import dataclass, field

import numpy as np

from ..backend import mi
from ..errors import DyngiError
from .animation import INTERPOLATIONS, Animator, SunMotion, Track, rotation_matrix
from .camera import Camera
from .core import Scene, default_probe_grid, scene_bounds

SIDECAR_SUFFIX = ".anim.toml"
TOP_KEYS = ("fps", "loop", "interpolation", "up", "shapes", "emitters", "camera")
SHAPE_TABLE = ("pivot", "axis", "interpolation", "keys")
SHAPE_KEYS = ("t", "translate", "rotate", "scale")
CAMERA_TABLE = ("interpolation", "keys")
CAMERA_KEYS = ("t", "position", "target", "up", "fov")
EMITTER_TABLE = ("axis", "interpolation", "keys")
#: key properties per emitter kind (besides ``t``)
EMITTER_KEYS = {
    "area": ("scale",), "point": ("scale", "translate"), "spot": ("scale", "translate"), "constant": ("scale",),
    "directional": ("scale", "elevation", "azimuth"), "sunsky": ("scale", "elevation", "azimuth"),
    "envmap": ("scale", "rotate"),
}
BOUNDS_SAMPLES = 64
"""Times (uniform over the animation, plus every keyframe) at which the animated shapes' boxes are
unioned into the probe box (ours: a rotation between two keys can sweep outside both keys' boxes)."""


def sidecar_for(xml_path: str) -> str | None:
    """The sidecar ``<stem>.anim.toml`` beside ``xml_path`` if it exists, else None."""
    stem = os.path.splitext(os.fspath(xml_path))[0]
    p = stem + SIDECAR_SUFFIX
    return p if os.path.isfile(p) else None


# -- animators -------------------------------------------------------------------------------------

@dataclass
class ShapeKeyframes(Animator):
    """One shape's keyframed transform ``x' = M(t) (x - pivot) + pivot + d(t)``, ``M = R S``.

    ``transform(t) -> (M 3x3, d)`` is the interface of the G-buffer's per-shape motion. A mesh
    (``<id>.vertex_positions`` in ``mi.traverse``) gets new vertex positions and normals (by the inverse
    transpose of ``M``, renormalised); another shape (``<id>.to_world``) a new ``to_world``
    ``A(t) @ to_world_xml``. Both from the values captured at bind time, so ``apply`` is idempotent.
    """

    shape: str
    pivot: tuple = (0.0, 0.0, 0.0)
    axis: tuple = (0.0, 1.0, 0.0)
    translate: Track | None = None
    rotate: Track | None = None      # degrees about ``axis`` through ``pivot``
    scale: Track | None = None       # 3 factors about ``pivot`` (before the rotation)
    _base_p: np.ndarray | None = field(default=None, repr=False)
    _base_n: np.ndarray | None = field(default=None, repr=False)
    _base_T: np.ndarray | None = field(default=None, repr=False)

    def bind(self, params):
        key = f"{self.shape}.vertex_positions"
        if key in params:
            self._base_p = np.array(params[key], dtype=np.float64).reshape(-1, 3)
            nkey = f"{self.shape}.vertex_normals"
            n = np.array(params[nkey], dtype=np.float64) if nkey in params else np.zeros(0)
            self._base_n = n.reshape(-1, 3) if n.size == self._base_p.size else None
        elif f"{self.shape}.to_world" in params:
            self._base_T = _matrix(params[f"{self.shape}.to_world"])
        else:
            raise DyngiError(f"shape '{self.shape}' cannot be transformed in place (mi.traverse exposes "
                             "neither its vertex_positions nor its to_world)")

    def transform(self, t: float):
        R = rotation_matrix(self.axis, math.radians(float(self.rotate(t)[0]))) \
            if self.rotate is not None else np.eye(3)
        S = np.diag(self.scale(t)) if self.scale is not None else np.eye(3)
        d = self.translate(t) if self.translate is not None else np.zeros(3)
        return R @ S, d

    def affine(self, t: float) -> np.ndarray:
        """The 4x4 world-space matrix of the transform at ``t``."""
        M, d = self.transform(t)
        piv = np.asarray(self.pivot, np.float64)
        A = np.eye(4)
        A[:3, :3] = M
        A[:3, 3] = piv + d - M @ piv
        return A

    def apply(self, params, t):
        M, d = self.transform(t)
        piv = np.asarray(self.pivot, dtype=np.float64)
        if self._base_p is not None:
            p = (self._base_p - piv) @ M.T + piv + d
            params[f"{self.shape}.vertex_positions"] = p.astype(np.float32).ravel()
            if self._base_n is not None:
                n = self._base_n @ np.linalg.inv(M)        # rows: (M^-T n)^T
                n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
                params[f"{self.shape}.vertex_normals"] = n.astype(np.float32).ravel()
        else:
            params[f"{self.shape}.to_world"] = mi.ScalarTransform4f(self.affine(t) @ self._base_T)

    def signature(self, t):
        M, d = self.transform(t)
        return tuple(np.round(np.concatenate([M.ravel(), d]), 9))


@dataclass
class ScaleKeyframes(Animator):
    """Scales emitter parameters (``keys``: radiance, intensity, irradiance, envmap or sun/sky scale) by
    a track of 1 or 3 factors, from the values captured at bind time."""

    keys: tuple
    track: Track
    _base: list = field(default_factory=list, repr=False)

    def bind(self, params):
        self._base = [(k, type(params[k]), np.array(params[k], dtype=np.float64).ravel()) for k in self.keys]

    def apply(self, params, t):
        f = self.track(t)
        for k, typ, base in self._base:
            if typ is float:
                params[k] = float(base[0] * f[0])
            elif base.size == 3:
                params[k] = mi.Color3f(*(base * np.broadcast_to(f, 3)).tolist())
            else:
                params[k] = typ((base * f[0]).astype(np.float32))

    def signature(self, t):
        return tuple(np.round(self.track(t), 9))


@dataclass
class SunskyKeyframes(Animator):
    """Writes a ``sunsky`` emitter's ``sun_direction`` (world space in Mitsuba 3.9, in the XML and in
    ``mi.traverse`` alike; the sky's own up is its ``to_world`` applied to +Z)."""

    emitter: str
    direction: object                  # t -> unit world direction towards the sun

    def apply(self, params, t):
        d = self.direction(t)
        params[f"{self.emitter}.sun_direction"] = mi.Vector3f(*(d / np.linalg.norm(d)).tolist())

    def signature(self, t):
        return tuple(np.round(self.direction(t), 9))


@dataclass
class RotateKeyframes(Animator):
    """An emitter's ``to_world`` rotated about ``axis`` (through the origin) by a track of degrees."""

    emitter: str
    axis: tuple
    rotate: Track
    _base_T: np.ndarray | None = field(default=None, repr=False)

    def bind(self, params):
        self._base_T = _matrix(params[f"{self.emitter}.to_world"])

    def apply(self, params, t):
        A = np.eye(4)
        A[:3, :3] = rotation_matrix(self.axis, math.radians(float(self.rotate(t)[0])))
        params[f"{self.emitter}.to_world"] = mi.ScalarTransform4f(A @ self._base_T)

    def signature(self, t):
        return tuple(np.round(self.rotate(t), 9))


@dataclass
class LightMoveKeyframes(Animator):
    """A point light's ``position`` or a spot light's ``to_world`` offset by a track (world units) from the
    XML's, captured at bind time."""

    emitter: str
    translate: Track
    _base: np.ndarray | None = field(default=None, repr=False)
    _key: str = ""

    def bind(self, params):
        pkey = f"{self.emitter}.position"
        if pkey in params:
            self._key, self._base = pkey, np.array(params[pkey], np.float64).ravel()
        else:
            self._key, self._base = f"{self.emitter}.to_world", _matrix(params[f"{self.emitter}.to_world"])

    def apply(self, params, t):
        d = self.translate(t)
        if self._base.ndim == 1:
            params[self._key] = mi.Point3f(*(self._base + d).tolist())
        else:
            T = self._base.copy()
            T[:3, 3] += d
            params[self._key] = mi.ScalarTransform4f(T)

    def signature(self, t):
        return tuple(np.round(self.translate(t), 9))


class _SunDirection:
    """t -> the unit direction towards the sun (times ``sign``) from elevation / azimuth tracks (degrees)."""

    def __init__(self, elevation: Track, azimuth: Track, up=(0.0, 1.0, 0.0), sign: float = 1.0):
        self.elevation, self.azimuth, self.up, self.sign = elevation, azimuth, tuple(up), sign

    def __call__(self, t):
        return self.sign * sun_vector(float(self.elevation(t)[0]), float(self.azimuth(t)[0]), self.up)


@dataclass
class KeyframedCameraPath:
    """A camera path whose position, target, up and fov each follow a track (``CameraPath``'s interface)."""

    origin: Track
    target: Track | None    # None: the XML camera's view direction kept, ``target = origin(t) + view``
    up: Track
    fov: Track
    view: tuple = (0.0, 0.0, 1.0)

    def __call__(self, t: float) -> Camera:
        o = self.origin(t)
        target = self.target(t) if self.target is not None else o + np.asarray(self.view, np.float64)
        return Camera(tuple(o), tuple(target), tuple(self.up(t)), float(self.fov(t)[0]))


def sky_frame(up=(0.0, 1.0, 0.0)):
    """(up, north, east): the unit frame elevation and azimuth are measured in. ``north`` is world +Z made
    orthogonal to ``up`` (world +Y when ``up`` is along Z), ``east = up x north``; for the default
    ``up = +Y`` that is north +Z, east +X."""
    u = np.asarray(up, np.float64)
    u = u / np.linalg.norm(u)
    ref = np.array([0.0, 0.0, 1.0]) if abs(u[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
    n = ref - (ref @ u) * u
    n /= np.linalg.norm(n)
    return u, n, np.cross(u, n)


def sun_vector(elevation_deg: float, azimuth_deg: float, up=(0.0, 1.0, 0.0)) -> np.ndarray:
    """World direction towards the sun: ``cos(el) (cos(az) north + sin(az) east) + sin(el) up``
    (:func:`sky_frame`); for ``up = +Y``: ``(cos el sin az, sin el, cos el cos az)``."""
    u, n, e = sky_frame(up)
    el, az = math.radians(elevation_deg), math.radians(azimuth_deg)
    return math.cos(el) * (math.cos(az) * n + math.sin(az) * e) + math.sin(el) * u


def sun_angles(d, up=(0.0, 1.0, 0.0)) -> tuple[float, float]:
    """(elevation, azimuth) in degrees of a direction towards the sun; the inverse of :func:`sun_vector`."""
    u, n, e = sky_frame(up)
    d = np.asarray(d, np.float64) / np.linalg.norm(d)
    return (math.degrees(math.asin(float(np.clip(d @ u, -1, 1)))),
            math.degrees(math.atan2(float(d @ e), float(d @ n))))


def _matrix(T) -> np.ndarray:
    return np.array(T.matrix, dtype=np.float64).reshape(4, 4)


# -- reading and checking the sidecar --------------------------------------------------------------

class _Problems:
    """Collects one line per problem; :meth:`raise_if_any` raises them as one DyngiError."""

    def __init__(self, path: str):
        self.path, self.lines = path, []

    def add(self, where: str, msg: str):
        self.lines.append(f"{self.path}: {where}: {msg}")

    def raise_if_any(self):
        if self.lines:
            raise DyngiError("\n".join(self.lines))


SCALAR_OK = ("scale",)
"""Key properties of 3 numbers that also take one number (broadcast to all three)."""


def _vector(v, n: int, scalar_ok: bool = False):
    """v as a float array of n entries (one number broadcast to 3 where ``scalar_ok``), or None."""
    if isinstance(v, bool):
        return None
    if isinstance(v, (int, float)):
        return np.full(n, float(v)) if n == 1 or scalar_ok else None
    if isinstance(v, list) and len(v) == n and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                   for x in v):
        return np.asarray(v, np.float64)
    return None


def _read_keys(prob: _Problems, where: str, table: dict, allowed: tuple, sizes: dict,
               interp: str, loop: bool) -> dict:
    """{property: Track} from ``table['keys']``; problems are added to ``prob``."""
    keys = table.get("keys")
    if not isinstance(keys, list) or not keys or not all(isinstance(k, dict) for k in keys):
        prob.add(where, "needs 'keys', a non-empty list of tables such as { t = 0.0, ... }")
        return {}
    times, ok = [], True
    for i, k in enumerate(keys):
        t = k.get("t")
        if isinstance(t, bool) or not isinstance(t, (int, float)):
            prob.add(f"{where}.keys[{i}]", "needs a time 't' in seconds (a number)")
            ok = False
            continue
        if not math.isfinite(t):
            prob.add(f"{where}.keys[{i}]", f"t = {t} is not finite")
            ok = False
        times.append(float(t))
        for name in k:
            if name not in allowed:
                prob.add(f"{where}.keys[{i}]", f"unknown property '{name}'; valid: {', '.join(allowed)}")
                ok = False
    if ok and any(b <= a for a, b in zip(times, times[1:])):
        prob.add(where, f"key times must be strictly increasing, got {', '.join(f'{t:g}' for t in times)}")
        ok = False
    if ok and times[0] < 0:
        prob.add(where, f"key times must be >= 0, got {times[0]:g}")
        ok = False
    tracks = {}
    for name, n in sizes.items():
        ts, vs = [], []
        for i, k in enumerate(keys):
            if name not in k:
                continue
            v = _vector(k[name], n, name in SCALAR_OK)
            if v is None:
                shape = "a number" if n == 1 else f"a list of {n} numbers" + (" or a number" if name == "scale" else "")
                prob.add(f"{where}.keys[{i}]", f"'{name}' must be {shape}")
                ok = False
                continue
            if not np.all(np.isfinite(v)):
                prob.add(f"{where}.keys[{i}]", f"'{name}' has NaN or infinite values")
                ok = False
                continue
            ts.append(float(k["t"]))
            vs.append(v)
        if ok and ts:
            tracks[name] = Track(ts, vs, interp, loop)
    if ok and not tracks:
        prob.add(where, f"no key sets any of: {', '.join(sizes)}")
    return tracks if ok else {}


def _interp(prob, where, table, default):
    v = table.get("interpolation", default)
    if v not in INTERPOLATIONS:
        prob.add(where, f"unknown interpolation '{v}'; valid: {', '.join(INTERPOLATIONS)}")
        return default
    return v


def _unknown(prob, where, table, allowed):
    for k in table:
        if k not in allowed:
            prob.add(where, f"unknown setting '{k}'; valid: {', '.join(allowed)}")


def _table_vec(prob, where, table, name, default):
    if name not in table:
        return None if default is None else np.asarray(default, np.float64)
    v = _vector(table[name], 3)
    if v is None or not np.all(np.isfinite(v)):
        prob.add(where, f"'{name}' must be a list of 3 finite numbers")
        return None
    if name == "axis" and np.linalg.norm(v) == 0:
        prob.add(where, "'axis' must not be the zero vector")
        return None
    return v


# -- the scene's objects by id ---------------------------------------------------------------------

def _shape_ids(mi_scene) -> dict:
    return {sh.id(): sh for sh in mi_scene.shapes() if sh.id()}


def _emitter_entries(mi_scene, params) -> dict:
    """{id: (kind, prefix)} of the scene's emitters: area lights by their shape's id."""
    out = {}
    for e in mi_scene.emitters():
        cls = e.class_name()
        sh = e.get_shape() if hasattr(e, "get_shape") else None
        if sh is not None:
            if sh.id():
                out[sh.id()] = ("area", f"{sh.id()}.emitter")
            continue
        if not e.id():
            continue
        kind = {"PointLight": "point", "SpotLight": "spot", "DirectionalEmitter": "directional",
                "SunskyEmitter": "sunsky", "EnvironmentMapEmitter": "envmap",
                "ConstantBackgroundEmitter": "constant"}.get(cls, cls)
        out[e.id()] = (kind, e.id())
    return out


def _scale_keys(kind, prefix, params):
    cands = {"area": ["radiance.value"], "point": ["intensity.value"], "spot": ["intensity.value"],
             "constant": ["radiance.value"], "directional": ["irradiance.value"], "envmap": ["scale"],
             "sunsky": ["sun_scale", "sky_scale"]}.get(kind, [])
    keys = [f"{prefix}.{c}" for c in cands]
    return tuple(keys) if keys and all(k in params for k in keys) else None


def _xml_shape_ids(path: str) -> list:
    """The ids of the top-level shapes of the XML file (parsed, not instantiated), for error messages."""
    cfg = mi.parser.ParserConfig(mi.variant())
    cfg.merge_meshes = False
    state = mi.parser.parse_file(cfg, os.path.abspath(path))
    mi.parser.transform_all(cfg, state)
    props = (state.root() if callable(state.root) else state.root).props
    ids = []
    for name in props.keys():
        if props.type(name) == mi.Properties.Type.ResolvedReference:
            node = state.nodes[props[name].index()]
            if node.type == mi.ObjectType.Shape and node.props.id():
                ids.append(node.props.id())
    return ids


def _reload_keeping(path: str, keep: set):
    """``mi.load_file(path)`` with the shapes whose ids are in ``keep`` left out of the parser's
    ``merge_meshes`` pass (they keep their ids; every other top-level mesh is merged as Mitsuba does)."""
    cfg = mi.parser.ParserConfig(mi.variant())
    cfg.merge_meshes = False
    old = mi.file_resolver()
    fr = mi.FileResolver(old)
    fr.prepend(os.path.dirname(os.path.abspath(path)))
    mi.set_file_resolver(fr)
    try:
        state = mi.parser.parse_file(cfg, os.path.abspath(path))
        mi.parser.transform_all(cfg, state)
        root = state.root() if callable(state.root) else state.root
        props, kept = root.props, {}
        for name in list(props.keys()):
            if props.type(name) != mi.Properties.Type.ResolvedReference:
                continue
            ref = props[name]
            node = state.nodes[ref.index()]
            if node.type == mi.ObjectType.Shape and node.props.id() in keep:
                kept[name] = ref
                del props[name]
        mi.parser.transform_merge_meshes(cfg, state)
        for name, ref in kept.items():
            props[name] = ref
        return mi.parser.instantiate(cfg, state)
    finally:
        mi.set_file_resolver(old)


def read_sidecar(toml_path: str) -> dict:
    """The parsed TOML (one-line DyngiError when missing or malformed)."""
    if not os.path.isfile(toml_path):
        raise DyngiError(f"animation file '{toml_path}' does not exist")
    try:
        with open(toml_path, "rb") as f:
            return tomllib.load(f)
    except tomllib.TOMLDecodeError as e:
        raise DyngiError(f"{toml_path}: not valid TOML: {e}") from None


def attach(scene: Scene, toml_path: str) -> Scene:
    """``scene`` animated by the sidecar ``toml_path`` (a new :class:`Scene`; see the module docstring).

    Every problem of the file is checked before any work and raised as one DyngiError, a line each.
    """
    doc = read_sidecar(toml_path)
    prob = _Problems(toml_path)
    _unknown(prob, "top level", doc, TOP_KEYS)
    loop = doc.get("loop", False)
    if not isinstance(loop, bool):
        prob.add("loop", "must be true or false")
        loop = False
    fps = doc.get("fps", scene.fps)
    if isinstance(fps, bool) or not isinstance(fps, (int, float)) or not (math.isfinite(fps) and fps > 0):
        prob.add("fps", f"must be a positive number, got {fps!r}")
        fps = scene.fps
    interp = _interp(prob, "top level", doc, "linear")
    up = _table_vec(prob, "top level", doc, "up", (0.0, 1.0, 0.0))
    if up is not None and np.linalg.norm(up) == 0:
        prob.add("top level", "'up' must not be the zero vector")
    up = (0.0, 1.0, 0.0) if up is None or np.linalg.norm(up) == 0 else tuple(up / np.linalg.norm(up))
    shapes_doc = doc.get("shapes", {})
    emitters_doc = doc.get("emitters", {})
    cam_doc = doc.get("camera")
    for name, v in (("shapes", shapes_doc), ("emitters", emitters_doc)):
        if not isinstance(v, dict) or not all(isinstance(x, dict) for x in v.values()):
            prob.add(name, f"must be tables [{name}.<id>]")
    if cam_doc is not None and not isinstance(cam_doc, dict):
        prob.add("camera", "must be a table [camera]")
        cam_doc = None
    prob.raise_if_any()

    # -- the Mitsuba scene: reloaded without mesh merging when a named shape was merged --
    mis = scene.mi_scene
    known = None        # the ids to list when a named shape is unknown
    if any(sid not in _shape_ids(mis) for sid in shapes_doc) and str(scene.source).lower().endswith(".xml") \
            and os.path.isfile(scene.source):
        known = _xml_shape_ids(scene.source)
        if all(sid in known for sid in shapes_doc):      # else: reported below, before any loading
            mis = _reload_keeping(scene.source, set(shapes_doc))
    params = mi.traverse(mis)
    shapes = _shape_ids(mis)
    known = sorted(known if known is not None else shapes)
    emitters = _emitter_entries(mis, params)

    animators = []
    moving = {}          # shape id -> (animator, base box lo, hi)
    for sid, table in shapes_doc.items():
        where = f"shapes.{sid}"
        if sid not in shapes:
            prob.add(where, f"unknown shape id '{sid}'; the file's shape ids: {', '.join(known) or '(none)'}")
            continue
        _unknown(prob, where, table, SHAPE_TABLE)
        sh = shapes[sid]
        bb = sh.bbox()
        lo, hi = np.array(bb.min, np.float64), np.array(bb.max, np.float64)
        pivot = _table_vec(prob, where, table, "pivot", 0.5 * (lo + hi))
        axis = _table_vec(prob, where, table, "axis", (0.0, 1.0, 0.0))
        tr = _read_keys(prob, where, table, SHAPE_KEYS, {"translate": 3, "rotate": 1, "scale": 3},
                        _interp(prob, where, table, interp), loop)
        mesh = f"{sid}.vertex_positions" in params
        if not mesh and f"{sid}.to_world" not in params:
            prob.add(where, f"shape '{sid}' ({sh.class_name()}) cannot be transformed in place: mi.traverse "
                     "exposes neither its vertex_positions nor its to_world")
            continue
        if "scale" in tr:
            s = tr["scale"].values
            if np.any(s <= 0):
                prob.add(where, "'scale' factors must be positive")
            elif sh.class_name() == "Sphere" and np.any(np.ptp(s, axis=1) > 0):
                prob.add(where, f"shape '{sid}' is a sphere: Mitsuba scales it only uniformly (one 'scale' number)")
        if pivot is None or axis is None or not tr:
            continue
        a = ShapeKeyframes(sid, tuple(pivot), tuple(axis), tr.get("translate"), tr.get("rotate"), tr.get("scale"))
        animators.append(a)
        moving[sid] = (a, lo, hi)

    for eid, table in emitters_doc.items():
        where = f"emitters.{eid}"
        if eid not in emitters:
            prob.add(where, f"unknown emitter id '{eid}'; the file's emitter ids (area lights by their shape's "
                     f"id): {', '.join(sorted(emitters)) or '(none)'}")
            continue
        kind, prefix = emitters[eid]
        allowed = EMITTER_KEYS.get(kind)
        if allowed is None:
            prob.add(where, f"emitter '{eid}' of type {kind} cannot be animated; animatable types: "
                     f"{', '.join(EMITTER_KEYS)}")
            continue
        _unknown(prob, where, table, EMITTER_TABLE if kind == "envmap" else ("interpolation", "keys"))
        axis = _table_vec(prob, where, table, "axis", (0.0, 1.0, 0.0))
        sizes = {"scale": 3, "elevation": 1, "azimuth": 1, "rotate": 1, "translate": 3}
        tr = _read_keys(prob, where, table, ("t",) + allowed, {k: sizes[k] for k in allowed},
                        _interp(prob, where, table, interp), loop)
        if "scale" in tr:
            keys = _scale_keys(kind, prefix, params)
            if keys is None:
                prob.add(where, f"the {kind} emitter '{eid}' has a textured radiance: 'scale' needs a constant one")
            elif np.any(tr["scale"].values < 0):
                prob.add(where, "'scale' factors must be >= 0")
            elif kind in ("envmap", "sunsky") and np.any(np.ptp(tr["scale"].values, axis=1) > 0):
                prob.add(where, f"the {kind} emitter '{eid}' scales by one number, not red, green and blue")
            else:
                animators.append(ScaleKeyframes(keys, tr["scale"]))
        if "elevation" in tr or "azimuth" in tr:
            T = _matrix(params[f"{prefix}.to_world"])
            if kind == "sunsky":
                d0 = np.array(params[f"{prefix}.sun_direction"], np.float64).ravel()
                sky_up = T[:3, 2] / np.linalg.norm(T[:3, 2])      # Mitsuba's sunsky: local +Z is up
                if params.properties[f"{prefix}.sun_direction"][3] & mi.ParamFlags.ReadOnly:
                    prob.add(where, f"the sunsky '{eid}' places its sun by date, time and location (Mitsuba then "
                             "makes sun_direction read-only): give it a <vector name=\"sun_direction\" .../> "
                             "in the XML to animate elevation / azimuth")
                    continue
                if float(sky_up @ np.asarray(up)) < 0.999:
                    prob.add(where, f"the sunsky's up axis (its to_world applied to +Z) is "
                             f"{np.round(sky_up, 3).tolist()}, the sidecar's 'up' is {np.round(up, 3).tolist()}: "
                             f"set up = {np.round(sky_up, 3).tolist()} at the top of the file")
                    continue
            else:
                d0 = -T[:3, 2]
            el0, az0 = sun_angles(d0, up)
            el = tr.get("elevation", Track.constant([el0]))
            az = tr.get("azimuth", Track.constant([az0]))
            if kind == "sunsky":
                animators.append(SunskyKeyframes(prefix, _SunDirection(el, az, up)))
            else:
                animators.append(SunMotion(prefix, _SunDirection(el, az, up, -1.0)))
        if "rotate" in tr and axis is not None:
            animators.append(RotateKeyframes(prefix, tuple(axis), tr["rotate"]))
        if "translate" in tr:
            animators.append(LightMoveKeyframes(prefix, tr["translate"]))

    cam_path = scene.camera_path
    cam_tracks = {}
    if cam_doc is not None:
        _unknown(prob, "camera", cam_doc, CAMERA_TABLE)
        cam_tracks = _read_keys(prob, "camera", cam_doc, CAMERA_KEYS,
                                {"position": 3, "target": 3, "up": 3, "fov": 1},
                                _interp(prob, "camera", cam_doc, interp), loop)
        if "fov" in cam_tracks and np.any((cam_tracks["fov"].values <= 0) | (cam_tracks["fov"].values >= 180)):
            prob.add("camera", "'fov' must be in (0, 180) degrees")
    prob.raise_if_any()

    # -- duration: the last keyframe --
    last = [float(tr.times[-1]) for tr in _all_tracks(animators)] + [float(t.times[-1]) for t in cam_tracks.values()]
    if not last:
        raise DyngiError(f"{toml_path}: no keyframes: name shapes, emitters or the camera with 'keys'")
    duration = max(last)
    if duration <= 0:
        raise DyngiError(f"{toml_path}: every keyframe is at t = 0: nothing moves (add a later key)")
    if cam_tracks:
        c0 = scene.camera_path(0.0)
        cam_path = KeyframedCameraPath(cam_tracks.get("position", Track.constant(c0.origin)),
                                       cam_tracks.get("target"),
                                       cam_tracks.get("up", Track.constant(c0.up)),
                                       cam_tracks.get("fov", Track.constant([c0.fov])),
                                       tuple(np.subtract(c0.target, c0.origin)))
        for t in np.unique(np.concatenate([tr.times for tr in cam_tracks.values()])):
            try:
                cam_path(float(t)).frame()
            except DyngiError as e:
                prob.add("camera", f"at t = {t:g}: {e}")
        prob.raise_if_any()

    # -- the probe box over the animation's bounds --
    lo, hi = animated_bounds(mis, moving.values(), duration)
    box, counts = default_probe_grid(lo, hi)
    out = Scene(name=scene.name, mi_scene=mis, camera_path=cam_path, animators=list(scene.animators) + animators,
                description=scene.description + f" animated by {toml_path}", stands_for=scene.stands_for,
                duration=duration, fps=float(fps), probe_box=box, probe_counts=counts, source=scene.source)
    out.meta.bounds = (tuple(lo), tuple(hi))
    out.meta.dynamic_shapes = sorted(set(out.meta.dynamic_shapes) | set(moving))
    out.keyframes_file = toml_path
    return out


def _all_tracks(animators):
    for a in animators:
        for name in ("translate", "rotate", "scale", "track"):
            tr = getattr(a, name, None)
            if isinstance(tr, Track):
                yield tr
        d = getattr(a, "direction", None)
        if isinstance(d, _SunDirection):
            yield d.elevation
            yield d.azimuth


def animated_bounds(mi_scene, movers, duration: float, samples: int = BOUNDS_SAMPLES):
    """(lo, hi): the scene's bounds at load united with the boxes of the moving shapes over the animation.

    ``movers`` are ``(ShapeKeyframes, lo, hi)`` with the shape's box at load; its 8 corners are moved
    by the shape's transform at every keyframe and at ``samples`` uniform times (a conservative box).
    """
    lo, hi = scene_bounds(mi_scene)
    for a, blo, bhi in movers:
        ts = [np.linspace(0.0, duration, samples)]
        ts += [tr.times for tr in (a.translate, a.rotate, a.scale) if tr is not None]
        corners = np.array([[x, y, z] for x in (blo[0], bhi[0]) for y in (blo[1], bhi[1]) for z in (blo[2], bhi[2])])
        for t in np.unique(np.concatenate(ts)):
            A = a.affine(float(t))
            c = corners @ A[:3, :3].T + A[:3, 3]
            lo, hi = np.minimum(lo, c.min(axis=0)), np.maximum(hi, c.max(axis=0))
    return lo, hi
