"""``lights=uniform``: every emitter triangle with pmf 1/L (pbrt-v4's ``UniformLightSampler``, Sec. 12.6.1)."""
from ..sampling.light_select import UniformSelector
from .base import register

register("uniform", UniformSelector, "every emitter triangle with pmf 1/L")
