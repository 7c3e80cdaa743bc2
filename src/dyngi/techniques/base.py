"""The one technique interface: ``Technique(scene, params).step(frame) -> FrameResult``.

Parameters are declared per class as :class:`Param` entries; unknown names and
invalid values raise :class:`~dyngi.errors.DyngiError` listing the valid
choices (pbrt-v4's "unused parameter is fatal"). Values may be given as
strings (``--set key=value`` on the command line) and are parsed by type.

Technique specs
---------------
Wherever a technique is named (``dyngi compare --techniques``, ``dyngi render
--technique``), a *spec* ``NAME[:KEY=VALUE...]`` names it together with
settings: ``ddgi``, ``ddgi:hysteresis=0.9``, ``path:spp=4:max_depth=3``.
:func:`parse_spec` is the one parser; the spec text as typed is the label of
that run in tables, plots and output files, so two settings of one technique
compare side by side.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from ..backend import dr
from ..errors import DyngiError, unknown_choice
from ..registry import Param, discover_modules  # noqa: F401  (Param re-exported)
from ..timing import StageTimer, maybe_stage  # noqa: F401  (re-exported)


def resolve_params(cls, params: dict | None) -> dict:
    """Defaults of ``cls.PARAMS`` overridden by ``params`` (validated; errors name the technique)."""
    params = dict(params or {})
    spec = cls.PARAMS
    unknown = [k for k in params if k not in spec]
    if unknown:
        raise DyngiError(f"unknown parameter '{unknown[0]}' for technique '{cls.name}'; valid parameters: "
                         + (", ".join(sorted(spec)) or "(none)"))
    out = {k: p.default for k, p in spec.items()}
    for k, v in params.items():
        try:
            out[k] = spec[k].parse(k, v)
        except DyngiError as e:
            raise DyngiError(f"technique '{cls.name}': {e}; valid parameters: {', '.join(sorted(spec))}") from None
    return out


@dataclass(frozen=True)
class TechniqueSpec:
    """A technique with settings, as named by a spec ``NAME[:KEY=VALUE...]``.

    ``label`` is the spec exactly as typed (the key in tables and files),
    ``name`` the registered technique, ``params`` the spec's own settings
    (already validated against the technique's :class:`Param` types).
    """

    label: str
    name: str
    params: dict = field(default_factory=dict)
    denoise: bool = False    # reserved spec key ``denoise=true``: also report the frames denoised (OIDN)

    def merged(self, base: dict | None) -> dict:
        """``base`` settings (``--set``) overridden by the spec's own."""
        return {**(base or {}), **self.params}

    def with_settings(self, base: dict | None) -> "TechniqueSpec":
        """This spec with ``base`` settings (``--set``, validated here, at the edge) under its own."""
        if not base:
            return self
        checked = resolve_params(get_technique(self.name), base)
        return TechniqueSpec(self.label, self.name, {**{k: checked[k] for k in base}, **self.params},
                             self.denoise)


def as_spec(spec: "str | TechniqueSpec") -> "TechniqueSpec":
    """A :class:`TechniqueSpec` as given, or parsed from its text (the one place a spec text is parsed)."""
    return spec if isinstance(spec, TechniqueSpec) else parse_spec(spec)


def split_spec_list(text: str) -> list[str]:
    """Split a comma-separated list of specs; a comma inside a value stays (``ddgi:probe_counts=4,4,4,path``).

    A piece starts a new spec when its name part (before any ``:``) is a registered technique or the
    previous piece set no value; otherwise it continues the previous piece's last value.
    """
    names = set(technique_names())
    out: list[str] = []
    for piece in str(text).split(","):
        head = piece.split(":", 1)[0].strip()
        if out and head not in names and "=" in out[-1] and "=" not in piece.split(":", 1)[0]:
            out[-1] += "," + piece
        else:
            out.append(piece)
    return [x.strip() for x in out if x.strip()]


def parse_spec(text: str) -> TechniqueSpec:
    """Parse ``NAME[:KEY=VALUE...]``; values are parsed by the technique's ``Param`` types.

    The key ``denoise`` (``path:denoise=true``) is reserved for every technique: it asks ``compare`` and
    ``render`` for the frames denoised too (as ``--denoise`` does for all), and is not a technique parameter.

    Errors (one :class:`DyngiError`) name the technique, the key and the valid
    keys: ``unknown technique``, ``unknown parameter 'x' for technique 'ddgi'``,
    a malformed ``KEY=VALUE`` item, a key given twice, or a value of the wrong
    type or out of range.
    """
    label = str(text).strip()
    if not label:
        raise DyngiError("empty technique spec; use NAME[:KEY=VALUE...], e.g. ddgi:hysteresis=0.9")
    name, *items = label.split(":")
    name = name.strip()
    cls = get_technique(name)
    raw = {}
    for it in items:
        if "=" not in it or not it.split("=", 1)[0].strip():
            raise DyngiError(f"technique spec '{label}': '{it}' is not KEY=VALUE; valid keys for '{name}': "
                             + (", ".join(sorted(cls.PARAMS)) or "(none)"))
        k, v = (x.strip() for x in it.split("=", 1))
        if k in raw:
            raise DyngiError(f"technique spec '{label}' sets '{k}' twice")
        raw[k] = v
    denoise = False
    if "denoise" in raw and "denoise" not in cls.PARAMS:     # reserved key, handled by compare/render
        v = raw.pop("denoise").lower()
        if v not in ("true", "false", "1", "0", "yes", "no"):
            raise DyngiError(f"technique spec '{label}': denoise must be true or false, got '{v}'")
        denoise = v in ("true", "1", "yes")
    resolved = resolve_params(cls, raw)
    return TechniqueSpec(label, name, {k: resolved[k] for k in raw}, denoise)


@dataclass
class Frame:
    """One frame to render: the scene is already animated to ``time``."""

    index: int
    time: float
    camera: Any              # dyngi.scene.Camera
    res: tuple[int, int]     # (width, height)
    seed: int = 0
    ray_budget: int | None = None       # rays this frame may trace (equal-ray comparisons)
    time_budget_ms: float | None = None  # wall time this frame may take (equal-time comparisons)
    static: bool = False     # True when nothing moved since the previous frame


@dataclass
class FrameResult:
    image: np.ndarray                       # H x W x 3 linear float32
    indirect: np.ndarray | None = None      # H x W x 3, indirect light only (where separated)
    stats: dict = field(default_factory=lambda: {"ms": {}, "rays": {}})


class Technique:
    """Base class: subclasses set ``name``, ``description``, ``PARAMS`` and implement ``step``."""

    name: ClassVar[str] = ""
    description: ClassVar[str] = ""
    PARAMS: ClassVar[dict[str, Param]] = {}
    #: comparison budgets this technique adapts to ('equal-rays', 'equal-time'); others run their defaults
    BUDGETS: ClassVar[tuple] = ()
    #: whether ``step`` fills ``FrameResult.indirect`` (``dyngi compare --indirect``); None: not declared
    HAS_INDIRECT: ClassVar[bool | None] = None
    #: whether the technique traces a DDGI probe volume (dyngi.probes): :func:`probe_technique_names`
    #: lists these; the probe-leak tests run on every one of them
    PROBE_TECHNIQUE: ClassVar[bool] = False

    def __init__(self, scene, params: dict | None = None):
        self.scene = scene
        self.params = resolve_params(type(self), params)

    def step(self, frame: Frame) -> FrameResult:  # pragma: no cover - interface
        raise DyngiError(f"technique '{self.name}' does not implement step()")


REGISTRY: dict[str, type[Technique]] = {}


def register(cls: type[Technique]) -> type[Technique]:
    if not cls.name:
        raise ValueError("technique class needs a name")
    REGISTRY[cls.name] = cls
    return cls


_DISCOVERED = False


def _discover() -> None:
    """Import every module of the ``techniques`` package (and of its sub-packages) once, so that each
    technique registers itself with :func:`register`: a new technique is one new module (or package)
    and needs no edit elsewhere, as scenes and reproductions are discovered."""
    global _DISCOVERED
    if _DISCOVERED:
        return
    import importlib

    discover_modules(__package__, importlib.import_module(__package__).__path__, recursive=True)
    _DISCOVERED = True


def technique_names() -> list[str]:
    _discover()
    return sorted(REGISTRY)


def probe_technique_names() -> list[str]:
    """The registered techniques that trace a DDGI probe volume (``PROBE_TECHNIQUE``), sorted."""
    return [n for n in technique_names() if REGISTRY[n].PROBE_TECHNIQUE]


def get_technique(name: str) -> type[Technique]:
    technique_names()
    if name not in REGISTRY:
        raise unknown_choice("technique", name, REGISTRY)
    return REGISTRY[name]


def create_technique(spec: "str | TechniqueSpec", scene, params: dict | None = None) -> Technique:
    """Instantiate a technique from a :class:`TechniqueSpec` (parsed once, at the edge: the CLI or the
    Python API) or from its text (a registered name or ``NAME[:KEY=VALUE...]``, parsed here).

    The spec's own settings override ``params``.
    """
    if isinstance(spec, TechniqueSpec):
        return get_technique(spec.name)(scene, spec.merged(params))
    if ":" in spec:
        spec = parse_spec(spec)
        return get_technique(spec.name)(scene, spec.merged(params))
    return get_technique(spec)(scene, params)


def to_image(values, res: tuple[int, int]) -> np.ndarray:
    """Dr.Jit colour array (row-major pixels, y down) -> H x W x 3 float32 numpy."""
    w, h = res
    return np.asarray(dr.ravel(values), np.float32).reshape(h, w, 3)
