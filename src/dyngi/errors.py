"""The one error type users see.

Every problem caused by input (a missing file, an unknown scene or technique, a
bad parameter, NaN in a mesh, an unwritable output folder) raises
:class:`DyngiError` with one line that names the problem and, where there is a
closed set of valid choices, lists them. The CLI prints that line and exits
with status 2 -- no traceback.
"""
from __future__ import annotations


class DyngiError(Exception):
    """A user-facing error: one line, names the problem and the valid choices."""


def unknown_choice(kind: str, name: str, choices) -> DyngiError:
    """Build the standard "unknown X 'y'; valid: a, b, c" error."""
    valid = ", ".join(sorted(choices))
    return DyngiError(f"unknown {kind} '{name}'; valid {kind}s: {valid}")
