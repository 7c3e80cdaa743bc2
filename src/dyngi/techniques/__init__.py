"""Techniques behind one interface, and their registry."""
from .base import (REGISTRY, Frame, FrameResult, Param, StageTimer, Technique, create_technique,
                   get_technique, register, technique_names)

__all__ = ["REGISTRY", "Frame", "FrameResult", "Param", "StageTimer", "Technique", "create_technique",
           "get_technique", "register", "technique_names"]
