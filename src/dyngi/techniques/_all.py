"""Imports every technique module so that each registers itself."""
from . import path  # noqa: F401
from . import ddgi  # noqa: F401
