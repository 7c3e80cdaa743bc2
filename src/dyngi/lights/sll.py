"""``lights=sll``: static light lists from a conservative PVS over coarse leaves (the VLC paper's SLL
baseline, Dittebrandt et al. Sec. 7), :mod:`dyngi.sampling.pvs`."""
from ..sampling.pvs import PVSLightLists
from .base import register

register("sll", PVSLightLists, "static light lists from a conservative PVS (VLC paper Sec. 7 baseline)")
