"""Built-in analogs of DDGI Resampling's Table 1 scenes: ``room-door``, ``villa-sun``, ``pink-room``.

Majercik et al. 2022 (Sec. 4, Fig. 8, Table 1) measure the time to equal MAPE on six interiors; the
public models are not in ``../shared``, so these small procedural rooms stand in for three of them
(``living-room``, :mod:`dyngi.scene.builtin_living`, is the paper's thin-walled exception). What
each keeps of the paper's scene is what Table 1 depends on: where the light comes from and how
much of the image is lit only indirectly.

All three are built of **thick two-sided solids** (closed boxes with a ``twosided`` diffuse BSDF:
walls 0.2-0.3 m, floor and roof slabs), so no surface is a single polygon that DDGI's Chebyshev
test could not resolve (the Living Room's defect), and each carries a probe grid that lies
entirely inside the rooms' air, clear of every wall, slab and the sunlit outside (our choice:
the paper spreads 16 x 8 x 16 probes over the scene's bounding box; ours are a few hundred so
that the probe update's rays stay near the paper's ratio of probe rays to pixels, 0.25 at
1080p, at the CPU's resolutions). The rays-per-pixel ratio at a given resolution is printed by
``dyngi reproduce ddgi-resampling``.

* ``room-door`` -- *Room Door*: two 4 x 2.6 x 4 m rooms side by side, separated by a 0.2 m
  wall with a 1.05 x 2.05 m door opening. The **only light** is an area light under the
  ceiling of the far room, which the camera cannot see (no camera ray reaches it; the test
  checks it); light reaches the viewed room only through the door. Indirect light
  dominates the image: the hardest of Table 1 for a path tracer (4095 frames in the paper).
* ``villa-sun`` -- *Greek Villa*: a 6 x 3 x 5 m whitewashed hall with 0.3 m walls, a 0.3 m
  roof slab, two tall windows in the +x wall, two columns and a bench; a directional sun
  (elevation 35 degrees) through the windows draws two patches on the terracotta floor,
  a dim constant sky fills the windows; the rest of the room is lit indirectly. The
  ground slab reaches 5 m beyond the walls (the sunlit ground outside reflects in).
* ``pink-room`` -- *Pink Room / Red Ball*: a closed 4 x 2.6 x 4 m room with pink walls,
  a red diffuse ball (radius 0.5 m) and a white cabinet, lit by a **cove light**: an
  upward-facing strip on top of a shelf along the -x wall, 0.6 m under the ceiling, that
  no camera ray reaches (the test checks it). Its direct light falls on the ceiling and
  the wall above the shelf only; the floor, the ball and the walls below the shelf are
  lit by the ceiling's bounce (the paper's Pink Room, modified from Wig42's *Modern
  Living Room*, is a living room lit mostly indirectly: PT+ReSTIR needs 29 frames there,
  Table 1): strong colour bleeding from walls and ball, contact shadows under the ball.

Each has a second camera, :data:`OTHER_VIEWS`, looking away from the first (they overlap little): ``dyngi
reproduce ddgi-resampling`` fits the DDGI methods' emission slider on it rather than on the measured view.

Each is static for the first second (Table 1 is measured on static frames at t = 0); then one
thing moves between t = 1 and 2 s (the door leaf swings, the sun rises, the ball rolls), 4 s clips.
"""
from __future__ import annotations

import numpy as np

from .animation import RigidMotion, SunMotion, Track
from .builder import SceneBuilder
from .builtin_default import _sky, _sun, _sun_dir, _twosided
from .camera import Camera
from .geometry import box, cylinder, merge, quad, uv_sphere
from .library import builtin

WHITE_WALL = (0.75, 0.73, 0.69)
WOOD = (0.48, 0.36, 0.24)


HOLD_MOVE_HOLD = [0.0, 1.0, 2.0, 4.0]
"""Keyframe times of the analogs' one animation: hold until t = 1 s, move until t = 2 s, hold to 4 s."""


def _ceiling_light(center, half: float):
    """Square area-light quad of half-size ``half`` at ``center``, facing down (-y)."""
    return quad(center, (half, 0, 0), (0, 0, half))


# -- Room Door ---------------------------------------------------------------------------------------
DOOR_H = 2.6                                   # interior height
DOOR_ROOM = ((0.1, 4.1), (-2.0, 2.0))          # viewed room: x, z interior ranges
DOOR_FAR = ((-4.1, -0.1), (-2.0, 2.0))         # the lit room behind the wall
DOOR_OPENING = (-1.75, -0.7, 2.05)              # z0, z1, top of the opening in the wall x in [-0.1, 0.1]
DOOR_LIGHT = ((-3.3, DOOR_H - 0.01, 1.2), 0.3)  # centre, half-size
DOOR_LIGHT_RADIANCE = (180.0, 156.0, 120.0)
DOOR_PROBE_BOX = ((-3.85, 0.2, -1.8), (3.85, 2.4, 1.8))
DOOR_PROBE_COUNTS = (8, 4, 5)   # columns at x = +-0.55, +-1.65, ...: none inside the middle wall
DOOR_CAMERA = Camera((3.9, 1.75, 1.85), (0.0, 0.55, -1.0), (0, 1, 0), 78.0)


@builtin("room-door", "Two rooms joined by a door; the only light is in the unseen far room",
         "DDGI Resampling's Room Door (Table 1: lit only through a door)")
def room_door():
    """Two thick-walled rooms side by side; the one area light sits in the far room, out of the camera's sight,
    and reaches the viewed room only through a 1.05 x 2.05 m door opening (the paper's *Room Door*,
    Table 1; see the module docstring). A door leaf in the viewed room swings 25 degrees towards the
    opening between t = 1 and 2 s (static before)."""
    H = DOOR_H
    b = SceneBuilder("room-door")
    b.mesh("floor", box((-4.3, -0.2, -2.2), (4.3, 0.0, 2.2)), _twosided(WOOD))
    b.mesh("ceiling", box((-4.3, H, -2.2), (4.3, H + 0.2, 2.2)), _twosided((0.8, 0.8, 0.78)))
    z0, z1, top = DOOR_OPENING
    walls = [box((-4.3, 0.0, -2.2), (-4.1, H, 2.2)), box((4.1, 0.0, -2.2), (4.3, H, 2.2)),
             box((-4.1, 0.0, -2.2), (4.1, H, -2.0)), box((-4.1, 0.0, 2.0), (4.1, H, 2.2)),
             # the middle wall with the door opening
             box((-0.1, 0.0, -2.0), (0.1, H, z0)), box((-0.1, 0.0, z1), (0.1, H, 2.0)),
             box((-0.1, top, z0), (0.1, H, z1))]
    b.mesh("walls", merge(walls), _twosided(WHITE_WALL))
    # the viewed room: a sofa and a low table; the far room: a cabinet and a rug-coloured block
    b.mesh("sofa", merge([box((2.2, 0.0, 1.2), (4.05, 0.45, 1.75)), box((2.2, 0.0, 1.75), (4.05, 0.9, 1.95))]),
           _twosided((0.25, 0.32, 0.5)))
    b.mesh("table", box((2.4, 0.0, -0.3), (3.4, 0.42, 0.5)), _twosided(WOOD))
    b.mesh("cabinet", box((-4.05, 0.0, -1.9), (-3.5, 1.6, -0.6)), _twosided((0.55, 0.25, 0.18)))
    b.mesh("bed", box((-2.6, 0.0, -0.2), (-0.8, 0.5, 1.9)), _twosided((0.7, 0.66, 0.55)))
    # door leaf, open: perpendicular to the wall in the viewed room, hinged at the opening's -z edge
    b.mesh("door_leaf", box((0.1, 0.0, z0 - 0.04), (0.96, top - 0.02, z0)), _twosided(WOOD))
    c, hs = DOOR_LIGHT
    b.mesh("light", _ceiling_light(c, hs), _twosided((0.0, 0.0, 0.0)), DOOR_LIGHT_RADIANCE)
    ang = -np.radians(25.0)   # towards +z: half-closing over the opening
    b.animate(RigidMotion("door_leaf", angle=Track(HOLD_MOVE_HOLD, [[0.0], [0.0], [ang], [ang]],
                                                   interp="smooth"), pivot=(0.1, 0.0, z0)))
    return b.build(DOOR_CAMERA, "Two rooms joined by a door; the only light is in the unseen far room",
                   duration=4.0, probe_box=DOOR_PROBE_BOX, probe_counts=DOOR_PROBE_COUNTS)


# -- Greek Villa ------------------------------------------------------------------------------------
VILLA_X, VILLA_H, VILLA_Z, VILLA_T = 3.0, 3.0, 2.5, 0.3   # interior half-sizes, height, wall thickness
VILLA_WINDOWS = ((-1.9, -0.9), (0.9, 1.9))                 # z ranges of the +x wall's two windows
VILLA_WINDOW_Y = (0.9, 2.4)
VILLA_SUN = _sun_dir(35.0, 10.0)
VILLA_SUN_LATER = _sun_dir(48.0, -10.0)
VILLA_SUN_IRRADIANCE = (9.0, 8.4, 7.4)
VILLA_SKY = (0.10, 0.13, 0.18)
VILLA_PROBE_BOX = ((-2.8, 0.2, -2.3), (2.8, 2.8, 2.3))
VILLA_PROBE_COUNTS = (8, 4, 7)
VILLA_CAMERA = Camera((-2.7, 1.6, 2.2), (1.5, 0.55, -1.0), (0, 1, 0), 72.0)


def villa_walls():
    """(V, F) of the villa's 0.3 m walls: closed boxes, the +x wall cut around its two windows."""
    X, H, Z, T = VILLA_X, VILLA_H, VILLA_Z, VILLA_T
    y0, y1 = VILLA_WINDOW_Y
    (a0, a1), (b0, b1) = VILLA_WINDOWS
    parts = [box((-X - T, 0.0, -Z - T), (-X, H, Z + T)),            # -x wall
             box((-X, 0.0, -Z - T), (X + T, H, -Z)), box((-X, 0.0, Z), (X + T, H, Z + T)),   # -z, +z walls
             # +x wall: full-height piers between and beside the windows, sill and lintel under/over each
             box((X, 0.0, -Z), (X + T, H, a0)), box((X, 0.0, a1), (X + T, H, b0)), box((X, 0.0, b1), (X + T, H, Z))]
    for z0, z1 in VILLA_WINDOWS:
        parts += [box((X, 0.0, z0), (X + T, y0, z1)), box((X, y1, z0), (X + T, H, z1))]
    return merge(parts)


@builtin("villa-sun", "Thick-walled sunlit hall with two windows, columns and a bench; mostly lit indirectly",
         "DDGI Resampling's Greek Villa (Table 1: a sunlit interior)")
def villa_sun():
    """A 6 x 3 x 5 m hall of 0.3 m walls and slabs, lit by a sun through two tall windows (two patches on the
    floor) and a dim sky; the paper's *Greek Villa* (Table 1; see the module docstring). The sun rises
    from 35 to 48 degrees between t = 1 and 2 s, moving the patches (static before)."""
    X, H, Z, T = VILLA_X, VILLA_H, VILLA_Z, VILLA_T
    b = SceneBuilder("villa-sun")
    G = 5.0
    b.mesh("ground", box((-X - G, -0.3, -Z - G), (X + G, 0.0, Z + G)), _twosided((0.6, 0.38, 0.26)))
    b.mesh("roof", box((-X - T, H, -Z - T), (X + T, H + 0.3, Z + T)), _twosided((0.8, 0.78, 0.74)))
    b.mesh("walls", villa_walls(), _twosided((0.8, 0.78, 0.72)))
    b.mesh("columns", merge([cylinder((-0.4, 0.0, z), 0.18, H, n=16, caps=False) for z in (-1.2, 1.2)]),
           _twosided((0.85, 0.83, 0.78)))
    b.mesh("bench", merge([box((-2.95, 0.0, -1.6), (-2.5, 0.45, 1.6))]), _twosided((0.2, 0.3, 0.55)))
    b.mesh("table", merge([box((0.6, 0.7, -0.5), (1.6, 0.76, 0.5))] +
                          [box((x, 0.0, z), (x + 0.08, 0.7, z + 0.08)) for x in (0.65, 1.47) for z in (-0.45, 0.37)]),
           _twosided(WOOD))
    b.add("sun", _sun(VILLA_SUN, VILLA_SUN_IRRADIANCE))
    b.add("sky", _sky(VILLA_SKY))
    b.animate(SunMotion("sun", Track(HOLD_MOVE_HOLD, [VILLA_SUN, VILLA_SUN, VILLA_SUN_LATER, VILLA_SUN_LATER],
                                     interp="smooth")))
    return b.build(VILLA_CAMERA, "Thick-walled sunlit hall with two windows", duration=4.0,
                   probe_box=VILLA_PROBE_BOX, probe_counts=VILLA_PROBE_COUNTS)


# -- Pink Room / Red Ball ------------------------------------------------------------------------
PINK_X, PINK_H, PINK_Z, PINK_T = 2.0, 2.6, 2.0, 0.15
PINK_WALL = (0.85, 0.5, 0.6)
PINK_BALL = ((0.3, 0.5, -0.5), 0.5)          # centre, radius
PINK_SHELF = ((-PINK_X, 1.95, -1.9), (-1.78, 2.0, 1.9))   # the cove's shelf along the -x wall (lo, hi)
PINK_LIGHT = ((-1.89, 2.005, 0.0), (0.08, 1.8))           # centre, half-sizes (x, z): on the shelf, facing +y
PINK_LIGHT_RADIANCE = (8.8, 8.1, 6.9)   # about the power of a 0.6 m ceiling panel of radiance 14
PINK_PROBE_BOX = ((-1.85, 0.15, -1.85), (1.85, 2.45, 1.85))
PINK_PROBE_COUNTS = (6, 4, 6)
PINK_CAMERA = Camera((-1.75, 1.5, 1.8), (0.4, 0.6, -0.7), (0, 1, 0), 68.0)


@builtin("pink-room", "Closed pink room with a red diffuse ball and a cabinet, lit mostly indirectly by a hidden "
         "cove light", "DDGI Resampling's Pink Room / Red Ball (Table 1: colour bleeding, indirect light)")
def pink_room():
    """A closed 4 x 2.6 x 4 m room of 0.15 m walls: pink walls, a red diffuse ball of radius 0.5 m, a white
    cabinet, lit by a 0.16 x 3.6 m cove light facing the ceiling from a shelf on the -x wall (hidden from
    the camera); strong colour bleeding, the view lit by the ceiling's bounce (the paper's *Pink Room* and
    *Red Ball*, Table 1; see the module docstring). The ball rolls 0.8 m towards the camera between
    t = 1 and 2 s (static before)."""
    X, H, Z, T = PINK_X, PINK_H, PINK_Z, PINK_T
    b = SceneBuilder("pink-room")
    b.mesh("floor", box((-X - T, -T, -Z - T), (X + T, 0.0, Z + T)), _twosided((0.62, 0.58, 0.52)))
    b.mesh("ceiling", box((-X - T, H, -Z - T), (X + T, H + T, Z + T)), _twosided((0.8, 0.8, 0.8)))
    walls = [box((-X - T, 0.0, -Z - T), (-X, H, Z + T)), box((X, 0.0, -Z - T), (X + T, H, Z + T)),
             box((-X, 0.0, -Z - T), (X, H, -Z)), box((-X, 0.0, Z), (X, H, Z + T))]
    b.mesh("walls", merge(walls), _twosided(PINK_WALL))
    c, r = PINK_BALL
    b.mesh("ball", uv_sphere(c, r, 16, 32), _twosided((0.8, 0.08, 0.06)))
    b.mesh("cabinet", box((-1.95, 0.0, -1.95), (-0.9, 0.9, -1.4)), _twosided((0.8, 0.8, 0.78)))
    b.mesh("shelf", box(*PINK_SHELF), _twosided((0.8, 0.8, 0.78)))
    lc, (hx, hz) = PINK_LIGHT
    b.mesh("light", quad(lc, (0, 0, hz), (hx, 0, 0)), _twosided((0.0, 0.0, 0.0)), PINK_LIGHT_RADIANCE)
    b.animate(RigidMotion("ball", translate=Track(HOLD_MOVE_HOLD, [[0, 0, 0], [0, 0, 0], [-0.5, 0, 0.6],
                                                                         [-0.5, 0, 0.6]], interp="smooth")))
    return b.build(PINK_CAMERA, "Closed pink room with a red ball, lit by a hidden cove light", duration=4.0,
                   probe_box=PINK_PROBE_BOX, probe_counts=PINK_PROBE_COUNTS)


OTHER_VIEWS = {
    "room-door": Camera((0.4, 1.6, -1.85), (4.0, 0.6, 1.4), (0, 1, 0), 78.0),    # the viewed room's sofa corner
    "villa-sun": Camera((2.7, 1.6, -2.2), (-1.5, 0.55, 1.0), (0, 1, 0), 72.0),   # the bench, windows behind
    "pink-room": Camera((1.75, 1.5, -1.8), (-0.4, 0.6, 0.7), (0, 1, 0), 68.0),   # the shelf wall from below
}
"""A second view of each analog (our choice), looking away from the scene's camera: the emission slider of
``dyngi reproduce ddgi-resampling`` is fitted on it (a fit on the measured view would be an oracle)."""
