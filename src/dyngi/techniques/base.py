"""The one technique interface: ``Technique(scene, params).step(frame) -> FrameResult``.

Parameters are declared per class as :class:`Param` entries; unknown names and
invalid values raise :class:`~dyngi.errors.DyngiError` listing the valid
choices (pbrt-v4's "unused parameter is fatal"). Values may be given as
strings (``--set key=value`` on the command line) and are parsed by type.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from ..backend import dr
from ..errors import DyngiError, unknown_choice
from ..timing import StageTimer, maybe_stage  # noqa: F401  (re-exported)


@dataclass(frozen=True)
class Param:
    default: Any
    doc: str = ""
    choices: tuple | None = None
    min: float | None = None
    max: float | None = None

    def parse(self, name: str, value):
        typ = type(self.default)
        try:
            if typ is bool and isinstance(value, str):
                if value.lower() not in ("1", "0", "true", "false", "yes", "no", "on", "off"):
                    raise ValueError
                v = value.lower() in ("1", "true", "yes", "on")
            elif typ is int and isinstance(value, float) and not value.is_integer():
                raise ValueError
            else:
                v = typ(value)
        except (TypeError, ValueError):
            raise DyngiError(f"parameter '{name}' must be of type {typ.__name__}, got '{value}'") from None
        if isinstance(v, float) and not np.isfinite(v):
            raise DyngiError(f"parameter '{name}' must be finite, got {value}")
        if self.choices is not None and v not in self.choices:
            raise DyngiError(f"parameter '{name}' = '{v}' is invalid; valid values: "
                             + ", ".join(map(str, self.choices)))
        if self.min is not None and v < self.min:
            raise DyngiError(f"parameter '{name}' = {v} is below its minimum {self.min}")
        if self.max is not None and v > self.max:
            raise DyngiError(f"parameter '{name}' = {v} is above its maximum {self.max}")
        return v


def resolve_params(cls, params: dict | None) -> dict:
    """Defaults of ``cls.PARAMS`` overridden by ``params`` (validated)."""
    params = dict(params or {})
    spec = cls.PARAMS
    unknown = [k for k in params if k not in spec]
    if unknown:
        raise DyngiError(f"unknown parameter '{unknown[0]}' for technique '{cls.name}'; valid parameters: "
                         + (", ".join(sorted(spec)) or "(none)"))
    out = {k: p.default for k, p in spec.items()}
    for k, v in params.items():
        out[k] = spec[k].parse(k, v)
    return out


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


def technique_names() -> list[str]:
    from . import _all  # noqa: F401  (imports every technique module)
    return sorted(REGISTRY)


def get_technique(name: str) -> type[Technique]:
    technique_names()
    if name not in REGISTRY:
        raise unknown_choice("technique", name, REGISTRY)
    return REGISTRY[name]


def create_technique(name: str, scene, params: dict | None = None) -> Technique:
    return get_technique(name)(scene, params)


def to_image(values, res: tuple[int, int]) -> np.ndarray:
    """Dr.Jit colour array (row-major pixels, y down) -> H x W x 3 float32 numpy."""
    w, h = res
    return np.asarray(dr.ravel(values), np.float32).reshape(h, w, 3)
