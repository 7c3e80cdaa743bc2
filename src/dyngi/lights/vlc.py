"""``lights=vlc``: the Visibility Light Cache (Dittebrandt et al., Sec. 4-6), :mod:`dyngi.sampling.vlc`: it
learns from the NEE samples it is handed (``record``) and looks points up in an adaptive octree."""
from ..sampling.vlc import VLCSelector
from .base import register

register("vlc", VLCSelector, "Visibility Light Cache: learned visible lights per octree leaf (VLC paper Sec. 4)",
         learns=True, needs_octree=True)
