"""``lights=sll-oracle``: per-cell light lists found by casting rays (an oracle baseline),
:mod:`dyngi.sampling.sll`."""
from ..sampling.sll import SLLSelector
from .base import register

register("sll-oracle", SLLSelector, "ray-cast per-cell visible light lists (an oracle baseline)")
