"""Built-in procedural animated scenes (the default scenes and the test fixtures).

Each stands in for a scene of one of the papers; the docstring of each factory
says which and what it exercises. Units are metres; y is up.
"""
from __future__ import annotations

import numpy as np

from .animation import ParamTrack, RigidMotion, Track
from .builder import SceneBuilder
from .camera import Camera
from .geometry import box, diffuse, quad
from .library import builtin

WHITE = (0.725, 0.71, 0.68)
RED = (0.63, 0.065, 0.05)
GREEN = (0.14, 0.45, 0.091)
CORNELL_LIGHT = (17.0, 12.0, 4.0)


def _cornell_shell(b: SceneBuilder, light_size=(0.25, 0.2)):
    """Room [-1,1] x [0,2] x [-1,1], open at z=+1; light quad under the ceiling."""
    b.mesh("floor", quad((0, 0, 0), (0, 0, 1), (1, 0, 0)), diffuse(WHITE))
    b.mesh("ceiling", quad((0, 2, 0), (1, 0, 0), (0, 0, 1)), diffuse(WHITE))
    b.mesh("back", quad((0, 1, -1), (1, 0, 0), (0, 1, 0)), diffuse(WHITE))
    b.mesh("left", quad((-1, 1, 0), (0, 1, 0), (0, 0, 1)), diffuse(RED))
    b.mesh("right", quad((1, 1, 0), (0, 0, 1), (0, 1, 0)), diffuse(GREEN))
    lx, lz = light_size
    b.mesh("light", quad((0, 1.98, 0), (lx, 0, 0), (0, 0, lz)), diffuse((0.0, 0.0, 0.0)), CORNELL_LIGHT)


def _cornell_boxes(b: SceneBuilder):
    b.mesh("short_box", box((0.05, 0.0, -0.05), (0.65, 0.6, 0.55)), diffuse(WHITE))
    b.mesh("tall_box", box((-0.65, 0.0, -0.7), (-0.05, 1.2, -0.1)), diffuse(WHITE))


CORNELL_CAMERA = Camera((0.0, 1.0, 3.9), (0.0, 1.0, 0.0), (0.0, 1.0, 0.0), 39.3)
CORNELL_PROBES = (((-0.9, 0.1, -0.9), (0.9, 1.9, 0.9)), (8, 8, 8))


@builtin("cornell-moving-light", "Cornell box whose ceiling light slides left-right",
         "DDGI/ADGI light-moves test; the classic diffuse interreflection box")
def cornell_moving_light():
    b = SceneBuilder("cornell-moving-light")
    _cornell_shell(b)
    _cornell_boxes(b)
    b.animate(RigidMotion("light", translate=Track([0, 1, 2], [[-0.6, 0, 0], [0.6, 0, 0], [-0.6, 0, 0]],
                                                    interp="smooth", loop=True)))
    return b.build(CORNELL_CAMERA, "Cornell box whose ceiling light slides left-right",
                   duration=2.0, probe_box=CORNELL_PROBES[0], probe_counts=CORNELL_PROBES[1])


@builtin("cornell-moving-box", "Cornell box whose short box slides across the floor",
         "DDGI dynamic-geometry test: probes must re-classify and re-converge")
def cornell_moving_box():
    b = SceneBuilder("cornell-moving-box")
    _cornell_shell(b)
    _cornell_boxes(b)
    b.animate(RigidMotion("short_box", translate=Track([0, 1, 2], [[0, 0, 0], [-0.6, 0, 0.3], [0, 0, 0]],
                                                        interp="smooth", loop=True),
                          angle=Track([0, 2], [[0.0], [np.pi]], loop=True), pivot=(0.35, 0, 0.25)))
    return b.build(CORNELL_CAMERA, "Cornell box whose short box slides across the floor",
                   duration=2.0, probe_box=CORNELL_PROBES[0], probe_counts=CORNELL_PROBES[1])


@builtin("cornell-static", "Static Cornell box (convergence and progressive-accumulation tests)",
         "the classic Cornell box")
def cornell_static():
    b = SceneBuilder("cornell-static")
    _cornell_shell(b)
    _cornell_boxes(b)
    return b.build(CORNELL_CAMERA, "Static Cornell box", duration=1.0,
                   probe_box=CORNELL_PROBES[0], probe_counts=CORNELL_PROBES[1])


@builtin("furnace", "Closed sphere, diffuse albedo 0.5 and emission 0.5: radiance 1 everywhere",
         "the furnace test of every integrator")
def furnace():
    from .geometry import uv_sphere
    b = SceneBuilder("furnace")
    b.mesh("sphere", uv_sphere((0, 0, 0), 1.0, 24, 48, inward=True), diffuse((0.5, 0.5, 0.5)), (0.5, 0.5, 0.5))
    return b.build(Camera((0.0, 0.0, 0.5), (0.0, 0.0, -1.0), (0, 1, 0), 60.0), "furnace", duration=1.0,
                   probe_box=((-0.5, -0.5, -0.5), (0.5, 0.5, 0.5)), probe_counts=(4, 4, 4))
