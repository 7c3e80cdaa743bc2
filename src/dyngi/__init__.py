"""dyngi -- real-time dynamic global illumination research on Mitsuba 3 + Dr.Jit."""
from .errors import DyngiError

__version__ = "0.1.0"
__all__ = ["DyngiError", "__version__"]
