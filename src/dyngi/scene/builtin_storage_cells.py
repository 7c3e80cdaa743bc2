"""Built-in ``storage-cells``: a block of 256 small, tall storage cells, one ceiling light each.

The scene where *light selection* limits the error (the VLC paper's warehouse, Fig. 8 (a), "almost an
order of magnitude": Quake 2 RTX's light lists hold many lights that are potentially visible but
occluded). ``warehouse-rooms`` cannot decide that claim: there an oracle light list (ray-cast per-cell
visible lists, ``lights=sll-oracle``) reaches only ~0.9x the PVS lists' MSE, so selection is not what
limits its error. Here it is, by construction:

* 16 x 16 cells of 1.6 x 1.6 m, 3.6 m high, thin walls (0.12 m), a hatch (0.7 x 1.2 m) in the middle of
  every interior wall, so the conservative PVS (:mod:`dyngi.lights.pvs`: portals through the hatches,
  grid leaves that straddle the walls) links every cell to every other: each list holds all 512
  triangle lights (the oracle's ray-cast lists ~3, ``lights=sll-oracle``: its 32 cells along x and z are
  half a storage cell each, aligned with the walls);
* one 0.5 x 0.5 m ceiling light per cell, facing down: from a point on a cell's floor the lights of the
  neighbouring cells are nearly as close and face it as much as its own light (horizontal 1.6 m against
  3.6 m up), so the unoccluded-irradiance importance of a PVS list spreads over the neighbours' lights,
  while the walls hide all of them but the own cell's (and the few seen through a door): most lights of
  a list are occluded from any one point. Dark surfaces (albedo 0.1-0.12, a Quake level's) keep the
  indirect light, which selection does not help, small against the direct light.

512 triangle lights (256 quads, one emitter mesh). The camera stands in cell (4, 4) and turns from the wall towards the door
into cell (5, 4) over 4 s, looking ~25 degrees down (no emitter in view: a directly seen emitter's edge
pixels would dominate every technique's MSE alike). Static geometry, static lights.
"""
from __future__ import annotations

from .animation import Track
from .builder import SceneBuilder
from .builtin_default import DARK, _ceiling, _ceiling_light, _floor, _wall
from .camera import CameraPath
from .geometry import diffuse, merge
from .library import builtin

CELL = 1.6
N = 16
HEIGHT = 3.6
WALL = 0.12
DOOR_HALF, DOOR_TOP = 0.35, 1.2
LIGHT_HALF = 0.25
RADIANCE = (30.0, 28.0, 24.0)


def _build():
    b = SceneBuilder("storage-cells")
    X = N * CELL
    b.mesh("floor", _floor(0, X, 0, X), diffuse((0.1, 0.1, 0.09)))
    b.mesh("ceiling", _ceiling(0, X, 0, X, HEIGHT), diffuse((0.1, 0.1, 0.1)))
    # outer walls inside the bounds [0, X]: the oracle's 32 cells along x and z are then half a storage cell
    # each, aligned with the walls (an oracle list leaks no light through a wall)
    h = WALL / 2
    walls = [_wall("x", h, 0.0, X, HEIGHT, thick=WALL), _wall("x", X - h, 0.0, X, HEIGHT, thick=WALL),
             _wall("z", h, 0.0, X, HEIGHT, thick=WALL), _wall("z", X - h, 0.0, X, HEIGHT, thick=WALL)]
    for k in range(1, N):          # interior walls, one segment per cell side, a door in its middle
        for j in range(N):
            a0, a1 = j * CELL, (j + 1) * CELL
            c = 0.5 * (a0 + a1)
            door = [(c - DOOR_HALF, c + DOOR_HALF, DOOR_TOP)]
            walls.append(_wall("x", k * CELL, a0, a1, HEIGHT, door, thick=WALL))
            walls.append(_wall("z", k * CELL, a0, a1, HEIGHT, door, thick=WALL))
    b.mesh("walls", merge(walls), diffuse((0.12, 0.115, 0.11)))
    # one emitter mesh of 2 x 256 triangles (each triangle a light of the emitter table; one mesh keeps the
    # build fast)
    b.mesh("lights", merge([_ceiling_light((i + 0.5) * CELL, HEIGHT - 0.01, (j + 0.5) * CELL, half=LIGHT_HALF)
                            for i in range(N) for j in range(N)]), diffuse(DARK), RADIANCE)
    x0, z0 = 4 * CELL, 4 * CELL
    walk = [[x0 + 0.35, 1.5, z0 + 0.3], [x0 + 0.4, 1.5, z0 + 0.35]]
    look = [[x0 + 0.5, 0.2, z0 + 1.6], [x0 + 1.6, 0.3, z0 + 0.8]]
    times = [0.0, 4.0]
    cam = CameraPath(Track(times, walk, interp="smooth"), Track(times, look, interp="smooth"), (0, 1, 0), 75.0)
    return b.build(cam, "A block of 16 x 16 small tall storage cells joined by hatches, one ceiling light each "
                   "(512 triangle lights, most occluded from any one point)", duration=4.0,
                   probe_box=((0.2, 0.2, 0.2), (X - 0.2, HEIGHT - 0.2, X - 0.2)), probe_counts=(20, 4, 20))


@builtin("storage-cells", "16 x 16 small tall storage cells joined by hatches, one ceiling light each (512 triangle "
         "lights in every PVS list, most occluded from any one point)",
         "VLC scene (a): Quake 2 RTX warehouse, where light selection limits the error")
def storage_cells():
    """The scene where light selection limits the error (module docstring): every PVS list holds nearly
    all 512 triangle lights, a point sees about one cell's."""
    return _build()
