"""Registry of built-in procedural animated scenes.

Each entry is a factory ``f() -> Scene`` registered with :func:`builtin`
together with a one-line description and the paper scene it stands in for.
The scenes themselves live in the ``dyngi.scene.builtin_*`` modules (the default ones in
:mod:`dyngi.scene.builtin_default`), found by :func:`_load_builtins`.
"""
from __future__ import annotations

import importlib
import os
import pkgutil
from dataclasses import dataclass
from typing import Callable

from ..errors import unknown_choice


@dataclass
class BuiltinEntry:
    name: str
    factory: Callable
    description: str
    stands_for: str


BUILTINS: dict[str, BuiltinEntry] = {}


def builtin(name: str, description: str, stands_for: str = ""):
    """Decorator registering a scene factory under ``name``."""

    def deco(f):
        BUILTINS[name] = BuiltinEntry(name, f, description, stands_for)
        return f

    return deco


def _load_builtins() -> None:
    """Imports every ``dyngi.scene.builtin_*`` module (each registers its scenes with :func:`builtin`),
    so a new scene module needs no edit here."""
    for m in sorted(pkgutil.iter_modules(_package_path())):
        if m.name.startswith("builtin_"):
            importlib.import_module(f"{__package__}.{m.name}")


def _package_path():
    return [os.path.dirname(os.path.abspath(__file__))]


def builtin_names() -> list[str]:
    _load_builtins()
    return sorted(BUILTINS)


def make_builtin(name: str):
    _load_builtins()
    if name not in BUILTINS:
        raise unknown_choice("scene", name, BUILTINS)
    e = BUILTINS[name]
    sc = e.factory()
    sc.description = sc.description or e.description
    sc.stands_for = sc.stands_for or e.stands_for
    return sc
