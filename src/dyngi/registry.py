"""Plug-in registries (bottom layer): the one :class:`Param` type that techniques, light samplers, direction
samplers and probe volumes declare their settings with, and :func:`discover_modules`, the one way a package
finds its plug-ins -- every module of the package is imported once and registers itself, so a new technique,
light sampler or direction sampler is one new file and needs no edit elsewhere (as scenes and reproductions).
"""
from __future__ import annotations

import importlib
import pkgutil
from dataclasses import dataclass
from typing import Any, Iterable

import numpy as np

from .errors import DyngiError


@dataclass(frozen=True)
class Param:
    """One declared setting: its default (whose type parses string values), a one-line doc, and optional
    ``choices`` / ``min`` / ``max``; :meth:`parse` raises one :class:`~dyngi.errors.DyngiError` naming the
    parameter and what is valid."""
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


def discover_modules(package: str, path: Iterable[str], *, skip: Iterable[str] = (), recursive: bool = False,
                     optional: dict | None = None) -> None:
    """Import every module of ``package`` (its ``__path__`` is ``path``) in name order, except names in
    ``skip`` and private ``_`` names; ``recursive`` walks sub-packages too. With ``optional`` (a dict), a
    module that fails with :class:`ImportError` (an optional dependency missing) is recorded there as
    ``name -> reason`` instead of raising, so the other plug-ins stay usable."""
    skip = set(skip)
    mods = (pkgutil.walk_packages(path, prefix=f"{package}.") if recursive
            else (m._replace(name=f"{package}.{m.name}") for m in pkgutil.iter_modules(path)))
    for m in sorted(mods, key=lambda m: m.name):
        short = m.name.rsplit(".", 1)[-1]
        if short in skip or short.startswith("_"):
            continue
        if optional is None:
            importlib.import_module(m.name)
            continue
        try:
            importlib.import_module(m.name)
        except ImportError as e:
            optional[short] = str(e)
