"""``lights=lighttree``: a light BVH over the emitter triangles (Conty Estevez & Kulla 2018; pbrt-v4's
``BVHLightSampler``, Sec. 12.6.3), :mod:`dyngi.sampling.lighttree`."""
from ..sampling.lighttree import LightTreeSelector
from .base import register

register("lighttree", LightTreeSelector, "light BVH with importance per node (Conty & Kulla 2018; pbrt-v4 12.6.3)")
