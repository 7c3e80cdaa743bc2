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


class _NoPaperValue:
    """The paper gives no value for a setting of ours (:attr:`Param.paper`)."""
    _instance = None

    def __new__(cls):
        if cls._instance is None:
            cls._instance = super().__new__(cls)
        return cls._instance

    def __repr__(self) -> str:
        return "NO_PAPER_VALUE"

    def __reduce__(self):
        return (_NoPaperValue, ())


NO_PAPER_VALUE = _NoPaperValue()
""":attr:`Param.paper` of a setting that is ours where the paper gives no value (no paper-literal row)."""


@dataclass(frozen=True)
class Param:
    """One declared setting: its default (whose type parses string values), a one-line doc, and optional
    ``choices`` / ``min`` / ``max``; :meth:`parse` raises one :class:`~dyngi.errors.DyngiError` naming the
    parameter and what is valid.

    ``ours``: the setting (or its default) is our choice, not the paper's (issue 40): ``doc`` says why.
    ``paper``: the value the paper gives for it (the *paper-literal* row of a claim sets it), or
    :data:`NO_PAPER_VALUE` where the paper gives none (the setting gets no paper-literal row). A claim's
    rows (:mod:`dyngi.experiments.claims`) are built from these marks: the default row, the paper-literal
    row (every marked setting with a paper value at it), and one ablation row per such setting.
    """
    default: Any
    doc: str = ""
    choices: tuple | None = None
    min: float | None = None
    max: float | None = None
    ours: bool = False
    paper: Any = NO_PAPER_VALUE

    def __post_init__(self):
        if self.paper is not NO_PAPER_VALUE and not self.ours:
            raise ValueError("Param(paper=...) is only for a setting marked ours=True")
        if self.ours and not self.doc:
            raise ValueError("a Param marked ours=True needs a doc that says why")

    @property
    def has_paper_value(self) -> bool:
        """Is this a setting of ours with a value the paper gives (an ablation row sets it)?"""
        return self.ours and self.paper is not NO_PAPER_VALUE

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
