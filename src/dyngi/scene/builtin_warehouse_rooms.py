"""Built-in ``warehouse-rooms``: a Quake-like industrial level of six rooms and many lights (issue 28).

Stands for scene (a) of Dittebrandt et al. (Sec. 7.1, Fig. 8; Quake 2 RTX's warehouse) where the
claim "the VLC has almost an order of magnitude lower error than the SLL and the LH" needs what
``warehouse-lights`` lacks: many lights that are close but occluded (on the other side of a wall),
and lights in neighbouring rooms that a potentially-visible set keeps:

* six 9 x 9 m rooms (3 x 2; ~4.5 m high) with 0.3 m walls; rooms connect by doors (2 m wide,
  3 m high) and windows (sill 1.2 m, top 2.6 m), so from most rooms two or three other rooms are
  potentially visible; the wall between rooms (1, 0) and (1, 1) is solid;
* 9 ceiling lights (0.4 x 0.4 m) per room, and 3 wall lamps (0.3 x 0.3 m, 3 m up, 5 cm off the
  wall on a bracket) on *both* faces of every interior wall;
* a closed storage room (3 x 3 m, no opening) in the corner of room (1, 1) with two bright
  lights inside: lights behind walls, never visible from outside;
* a mezzanine deck (2.6 m up, 3.4 m deep along the outer wall, on two posts) in every room, with 8
  ceiling lights above it: seen from the floor under the deck they are the closest lights and face
  it (high unoccluded irradiance) but the deck hides them, as a Quake level's catwalks do;
* a shelf rack per room (local occlusion).

134 emitter quads in all (268 triangle lights: 54 ceiling lights, 48 above the decks, 30 wall
lamps, 2 in the store). The walls sit on the leaf boundaries of ``lights=sll``'s default PVS grid (9 leaves
along x: ~3.03 m leaves, 3 x 3 leaves per room), so the grid stands in for BSP leaves that follow
the walls. The camera walks from room (0, 0) through the door into room (1, 0)
and turns towards the window into room (2, 0) over 6 s, looking ~20 degrees down (no light in view:
a directly seen emitter's anti-aliased edge pixels would dominate every technique's MSE alike). Static geometry, static lights.
"""
from __future__ import annotations

from .builder import SceneBuilder
from .builtin_default import DARK, _ceiling, _ceiling_light, _floor, _wall
from .camera import CameraPath
from .animation import Track
from .geometry import box, diffuse, merge, quad
from .library import builtin

ROOM = 9.0
NX, NZ = 3, 2
HEIGHT = 4.5
WALL = 0.3
Z_ROOM = 8.94        # rooms along z are 8.94 m, so that z walls fall on the PVS grid's leaf boundaries
CEILING_RADIANCE = (16.0, 15.0, 13.2)
LAMP_RADIANCE = (14.0, 12.6, 10.0)
STORE_RADIANCE = (40.0, 36.0, 30.0)
SILL, WIN_TOP = 1.2, 2.6
DECK, MEZZ = 2.6, 3.4   # mezzanine deck height and depth from the outer wall


def _window_wall(axis, pos, a0, a1, windows):
    """A wall with window openings (b0, b1): solid below the sill, openings between SILL and WIN_TOP."""
    parts = [_wall(axis, pos, a0, a1, SILL, thick=WALL)]
    parts.append(_wall(axis, pos, a0, a1, HEIGHT - SILL, [(b0, b1, WIN_TOP - SILL) for b0, b1 in windows],
                       thick=WALL, y0=SILL))
    return merge(parts)


def _lamp(axis, pos, along, y, facing, half=0.15):
    """A wall lamp quad 5 cm off the wall plane ``axis = pos``, facing ``facing`` (+1 / -1) along the axis."""
    off = pos + facing * (WALL / 2 + 0.3)
    if axis == "x":
        c = (off, y, along)
        a, b = ((0, half, 0), (0, 0, half)) if facing > 0 else ((0, 0, half), (0, half, 0))
    else:
        c = (along, y, off)
        a, b = ((half, 0, 0), (0, half, 0)) if facing > 0 else ((0, half, 0), (half, 0, 0))
    return quad(c, a, b)


def _mezzanine_span(j):
    """z range of the mezzanine deck in the rooms of row j (along the outer wall, clear of the doors)."""
    return (WALL / 2, MEZZ) if j == 0 else (NZ * Z_ROOM - MEZZ, NZ * Z_ROOM - WALL / 2)


def warehouse_rooms_layout():
    """The interior walls: (axis, position, span start, span end, kind, openings) per wall segment."""
    X0, X1, X2, X3 = 0.0, ROOM, 2 * ROOM, 3 * ROOM
    Zm, Z1 = Z_ROOM, 2 * Z_ROOM
    return [("x", X1, 0.0, Zm, "door", [(3.5, 5.5)]), ("x", X1, Zm, Z1, "window", [(Zm + 3.0, Zm + 6.0)]),
            ("x", X2, 0.0, Zm, "window", [(3.0, 6.0)]), ("x", X2, Zm, Z1, "door", [(Zm + 3.5, Zm + 5.5)]),
            ("z", Zm, X0, X1, "door", [(6.0, 8.0)]), ("z", Zm, X1, X2, "solid", []),
            ("z", Zm, X2, X3, "window", [(X2 + 2.5, X2 + 6.5)])]


def _build():
    b = SceneBuilder("warehouse-rooms")
    X, Z, H = NX * ROOM, NZ * Z_ROOM, HEIGHT
    b.mesh("floor", _floor(0, X, 0, Z), diffuse((0.4, 0.39, 0.37)))
    b.mesh("ceiling", _ceiling(0, X, 0, Z, H), diffuse((0.55, 0.55, 0.55)))
    outer = [_wall("x", 0.0, -WALL / 2, Z + WALL / 2, H, thick=WALL), _wall("x", X, -WALL / 2, Z + WALL / 2, H, thick=WALL),
             _wall("z", 0.0, 0.0, X, H, thick=WALL), _wall("z", Z, 0.0, X, H, thick=WALL)]
    inner = []
    lamps = []
    for axis, pos, a0, a1, kind, opens in warehouse_rooms_layout():
        if kind == "door":
            inner.append(_wall(axis, pos, a0, a1, H, [(o0, o1, 3.0) for o0, o1 in opens], thick=WALL))
        elif kind == "window":
            inner.append(_window_wall(axis, pos, a0, a1, opens))
        else:
            inner.append(_wall(axis, pos, a0, a1, H, thick=WALL))
        # three lamps on each face, away from the openings (they stay close but occluded from the far side)
        free = [a0 + 0.2 * (a1 - a0), a0 + 0.5 * (a1 - a0), a0 + 0.8 * (a1 - a0)]
        free = [t for t in free if not any(o0 - 0.4 <= t <= o1 + 0.4 for o0, o1 in opens)] or [a0 + 0.1 * (a1 - a0)]
        for t in free:
            for facing in (-1, 1):
                lamps.append(_lamp(axis, pos, t, 3.0, facing))
    # the closed store in room (1, 1)'s far corner
    sx0, sz0 = 2 * ROOM - 3.0 - WALL / 2, Z - 3.0
    store = merge([_wall("x", sx0, sz0, Z, H, thick=WALL), _wall("z", sz0, sx0 - WALL / 2, 2 * ROOM, H, thick=WALL)])
    b.mesh("walls", merge(outer + inner + [store]), diffuse((0.55, 0.52, 0.47)))
    racks, decks = [], []
    for i in range(NX):
        for j in range(NZ):
            x0, z0 = i * ROOM, j * Z_ROOM
            zr = z0 + 6.2 if j == 0 else z0 + 1.8         # the rack stands on the open side
            racks += [box((x0 + 2.0, 0.0, zr), (x0 + 6.0, 2.4, zr + 0.8))]
            zm0, zm1 = _mezzanine_span(j)
            decks += [box((x0 + WALL / 2, DECK, zm0), (x0 + ROOM - WALL / 2, DECK + 0.2, zm1)),
                      box((x0 + 3.0, 0.0, zm1 - 0.3), (x0 + 3.3, DECK, zm1 - 0.0)),
                      box((x0 + 6.0, 0.0, zm1 - 0.3), (x0 + 6.3, DECK, zm1 - 0.0))]
    b.mesh("racks", merge(racks), diffuse((0.33, 0.3, 0.42)))
    b.mesh("mezzanines", merge(decks), diffuse((0.45, 0.45, 0.47)))
    for i in range(NX):
        for j in range(NZ):
            for a in range(3):
                for c in range(3):
                    b.mesh(f"light_{i}{j}_{a}{c}", _ceiling_light(i * ROOM + 1.5 + 3.0 * a, H - 0.01,
                                                                  j * Z_ROOM + 1.5 + 2.97 * c, half=0.2),
                           diffuse(DARK), CEILING_RADIANCE)
            zm0, zm1 = _mezzanine_span(j)
            for a in range(4):       # the deck's own lights, above it: close to the floor below, occluded there
                for c, z in enumerate((zm0 + 0.8, zm1 - 0.8)):
                    b.mesh(f"deck_light_{i}{j}_{a}{c}", _ceiling_light(i * ROOM + 1.1 + 2.25 * a, H - 0.01, z,
                                                                      half=0.2), diffuse(DARK), CEILING_RADIANCE)
    for k, lamp in enumerate(lamps):
        b.mesh(f"lamp_{k:02d}", lamp, diffuse(DARK), LAMP_RADIANCE)
    for k, (x, z) in enumerate(((sx0 + 1.0, sz0 + 1.5), (sx0 + 2.2, sz0 + 1.5))):
        b.mesh(f"store_light_{k}", _ceiling_light(x, H - 0.01, z, half=0.25), diffuse(DARK), STORE_RADIANCE)
    # looking ~20 degrees down: the lights (>= 3 m up) stay out of view, so a pixel's error is NEE's and the
    # indirect light's, not the anti-aliasing of a directly seen emitter (their edge pixels dominated the MSE)
    walk = [[1.5, 1.7, 5.0], [6.0, 1.7, 5.2], [10.5, 1.7, 5.0], [14.0, 1.7, 4.5]]
    look = [[9.0, -1.0, 3.0], [12.0, -0.5, 3.5], [18.0, -1.0, 4.0], [20.0, -0.5, 2.5]]
    times = [0.0, 2.0, 4.0, 6.0]
    cam = CameraPath(Track(times, walk, interp="smooth"), Track(times, look, interp="smooth"), (0, 1, 0), 70.0)
    return b.build(cam, "Six industrial rooms with doors, windows, mezzanine decks and 134 lights (lamps on "
                   "both faces of the walls, a closed store)", duration=6.0,
                   probe_box=((0.3, 0.3, 0.3), (X - 0.3, H - 0.3, Z - 0.3)), probe_counts=(24, 4, 16))


@builtin("warehouse-rooms", "Quake-like industrial level: six rooms joined by doors and windows, mezzanine decks, "
         "134 lights (ceiling lights, lights over the decks, wall lamps, a closed store)",
         "VLC/CDQ scene (a): Quake 2 RTX warehouse (many lights in neighbouring rooms and behind walls)")
def warehouse_rooms():
    """The VLC paper's warehouse (Quake 2 RTX) stand-in: six rooms joined by doors and windows, mezzanine
    decks with lights above them that the floor cannot see, wall lamps and a closed store, so that many
    lights are potentially visible but occluded (the case that separates the VLC from the SLL's PVS and
    from the light hierarchy). Details in the module docstring."""
    return _build()
