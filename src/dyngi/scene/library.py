"""Registry of built-in procedural animated scenes.

Each entry is a factory ``f() -> Scene`` registered with :func:`builtin`
together with a one-line description and the paper scene it stands in for.
The scenes themselves live in :mod:`dyngi.scene.builtin`.
"""
from __future__ import annotations

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


def builtin_names() -> list[str]:
    from . import builtin as _  # noqa: F401  (registers the scenes)
    from . import builtin_hall as _hall  # noqa: F401
    from . import builtin_smcir as _smcir  # noqa: F401
    return sorted(BUILTINS)


def make_builtin(name: str):
    from . import builtin as _  # noqa: F401
    from . import builtin_hall as _hall  # noqa: F401
    from . import builtin_smcir as _smcir  # noqa: F401
    if name not in BUILTINS:
        raise unknown_choice("scene", name, BUILTINS)
    e = BUILTINS[name]
    sc = e.factory()
    sc.description = sc.description or e.description
    sc.stands_for = sc.stands_for or e.stands_for
    return sc
