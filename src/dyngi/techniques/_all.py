"""Imports every technique module so that each registers itself."""
from . import path  # noqa: F401
from . import ddgi  # noqa: F401
from .adgi import technique as _adgi  # noqa: F401
from . import isddgi  # noqa: F401
from . import ir  # noqa: F401
from . import smcir  # noqa: F401
from . import restir  # noqa: F401
from . import mir  # noqa: F401
from . import tcas  # noqa: F401
from . import ddgi_primary  # noqa: F401
from . import ddgi_resampling  # noqa: F401
from . import neept  # noqa: F401
