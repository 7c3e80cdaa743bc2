"""Built-in ``living-room``: a thin-walled sunlit room (issue 15, item 7).

Stands for the DDGI Resampling paper's *Living Room* (Majercik et al. 2022,
Fig. 8 and Table 1), the one scene where DDGI visibly leaks: a furnished room
whose outer walls are modelled as single polygons without thickness, a strong
sun outside and the interior lit through a window.

* The room is x in [-3, 3], y in [0, 2.7], z in [-2.5, 2.5]. Its outer walls,
  the ceiling (which is also the roof) and the floor are **single-layer**: flat
  two-sided quads, no thickness (the ``walls`` shape holds only quads lying in
  the four planes ``x = +-3``, ``z = +-2.5``; the test checks it). The +x wall
  has a 2 x 1.3 m window (z in [-1, 1], y in [0.8, 2.1]), open (no glass).
* A strong directional sun (elevation 35 deg, from beyond the +x wall) and a
  dim constant sky outside; the sun falls through the window onto the floor
  and the sofa, and lights the outside of the walls, the roof and the ground
  around the house (the floor quad extends 4 m beyond the walls: the sunlit
  ground touches the walls' feet).
* Furniture: a sofa against the -x wall, a coffee table, a bookshelf on the
  -z wall (closed boxes); a chimney on the roof (up to y = 3.3).
* **Probe grid** (issue 22): inside the house, 0.15 m from the walls, floor and
  ceiling (x in [-2.85, 2.85], y in [0.15, 2.55], z in [-2.35, 2.35]) with
  9 x 5 x 8 probes (spacing 0.71 x 0.6 x 0.67 m). Until issue 22 the box was
  the house's bounding box extended by 0.4 m (x in [-3.4, 3.4], y up to 3.1):
  whole layers of probes lay *outside* the single-layer walls and above the
  roof, in the sun, nearer to the walls than the spacing, and an interior point
  near a wall interpolated sunlit exterior probes that the Chebyshev test
  cannot reject through a surface of zero thickness (ddgi +65% near the walls'
  inside; the tests then *required* that leak). The walls stay single-layer:
  what leaks through them now is what the interior probes' interpolation does
  near a sunlit wall (ddgi +8% within 0.3 m of the walls, +3% elsewhere).

Static for the first second (the leak tests hold t = 0 and measure converged probes); then the sun
moves (elevation 35 -> 45 deg, azimuth 10 -> -15 deg) between t = 1 and 2 s, so the lit patch moves
across the floor; duration 4 s.
``tests/scene/test_living_room.py`` checks that the leak of ``ddgi`` (and ``ddgi-primary``) near the
walls stays small against Mitsuba's ``path``.
"""
from __future__ import annotations

from .animation import SunMotion, Track
from .builder import SceneBuilder
from .builtin_default import _sky, _sun, _sun_dir, _twosided
from .camera import Camera
from .geometry import box, merge, quad
from .library import builtin

LIVING_X, LIVING_H, LIVING_Z = 3.0, 2.7, 2.5
LIVING_WINDOW = (-1.0, 1.0, 0.8, 2.1)          # z0, z1, y0, y1 of the +x wall's opening
LIVING_SUN = _sun_dir(35.0, 10.0)              # from beyond +x, slightly towards +z
LIVING_SUN_LATER = _sun_dir(45.0, -15.0)       # where it has moved to at t = 2 s
LIVING_SUN_IRRADIANCE = (9.0, 8.4, 7.4)
LIVING_SKY = (0.10, 0.13, 0.18)
LIVING_PROBE_BOX = ((-2.85, 0.15, -2.35), (2.85, 2.55, 2.35))
LIVING_PROBE_COUNTS = (9, 5, 8)
WALL = (0.72, 0.70, 0.66)


def near_wall_mask(pos, dist: float = 0.3):
    """(near, rest): boolean masks of world points ``pos`` (..., 3) inside the room within ``dist`` of a
    wall's or the ceiling's inside, and the other points inside the room (where the leak is measured)."""
    import numpy as np

    pos = np.asarray(pos, np.float64)
    X, H, Z = LIVING_X, LIVING_H, LIVING_Z
    inside = (np.abs(pos[..., 0]) < X + 1e-3) & (np.abs(pos[..., 2]) < Z + 1e-3) & (pos[..., 1] < H + 1e-3)
    d = np.minimum.reduce([X - np.abs(pos[..., 0]), Z - np.abs(pos[..., 2]), H - pos[..., 1]])
    return inside & (d < dist), inside & (d >= dist)


def _wall_x(x: float, z0: float, z1: float, y0: float, y1: float):
    """Quad in the plane x = const (normal +x), z in [z0, z1], y in [y0, y1]."""
    return quad((x, (y0 + y1) / 2, (z0 + z1) / 2), (0, (y1 - y0) / 2, 0), (0, 0, (z1 - z0) / 2))


def _wall_z(z: float, x0: float, x1: float, y0: float, y1: float):
    """Quad in the plane z = const (normal +z), x in [x0, x1], y in [y0, y1]."""
    return quad(((x0 + x1) / 2, (y0 + y1) / 2, z), ((x1 - x0) / 2, 0, 0), (0, (y1 - y0) / 2, 0))


def living_walls():
    """(V, F) of the single-layer outer walls: quads in the planes x = +-X and z = +-Z, the +x one with the
    window opening (four quads around it)."""
    X, H, Z = LIVING_X, LIVING_H, LIVING_Z
    wz0, wz1, wy0, wy1 = LIVING_WINDOW
    return merge([
        _wall_x(-X, -Z, Z, 0.0, H),
        _wall_x(X, -Z, wz0, 0.0, H), _wall_x(X, wz1, Z, 0.0, H),
        _wall_x(X, wz0, wz1, 0.0, wy0), _wall_x(X, wz0, wz1, wy1, H),
        _wall_z(-Z, -X, X, 0.0, H), _wall_z(Z, -X, X, 0.0, H),
    ])


@builtin("living-room", "Thin-walled (single-layer) living room lit by a strong sun through a window; "
         "probe volume inside the house (the walls leak little)",
         "DDGI Resampling's Living Room (Fig. 8, Table 1: where DDGI leaks)")
def living_room():
    """Single-layer walls, roof and floor; sun + sky outside; see the module docstring."""
    return _living("living-room", sun=True)


LIVING_ENV_SKY = (2.0, 2.3, 2.8)
"""The bright sky of ``living-room-sky`` (the only light: the interior is lit through the window)."""
LIVING_GLOSSY_FLOOR = {"type": "twosided", "bsdf": {
    "type": "roughplastic", "distribution": "ggx", "alpha": 0.1, "int_ior": 1.5, "nonlinear": True,
    "diffuse_reflectance": {"type": "rgb", "value": [0.45, 0.30, 0.18]}}}
"""A varnished wooden floor (GGX alpha 0.1), the glossy floor of the room the issue measured."""


@builtin("living-room-sky", "The thin-walled living room lit only by a bright sky (environment) through its "
         "window, with a glossy wooden floor: ReSTIR's environment candidates mostly occluded",
         "a real living room lit through its windows by an environment map")
def living_room_sky():
    """``living-room`` without the sun: a bright constant sky (environment emitter) is the only light, seen
    through the window; the floor is varnished wood (``roughplastic`` GGX alpha 0.1). Static."""
    return _living("living-room-sky", sun=False)


def _living(name: str, sun: bool):
    """The room of ``living-room`` (``sun``: sun + dim sky, diffuse floor, animated sun) or of
    ``living-room-sky`` (bright sky only, glossy floor, static)."""
    X, H, Z = LIVING_X, LIVING_H, LIVING_Z
    b = SceneBuilder(name)
    # floor = ground: one quad reaching 4 m beyond the walls (facing +y)
    G = 4.0
    b.mesh("floor", quad((0.0, 0.0, 0.0), (0, 0, Z + G), (X + G, 0, 0)),
           _twosided((0.55, 0.48, 0.40)) if sun else LIVING_GLOSSY_FLOOR)
    b.mesh("ceiling", quad((0.0, H, 0.0), (X, 0, 0), (0, 0, Z)), _twosided((0.75, 0.74, 0.72)))
    b.mesh("walls", living_walls(), _twosided(WALL))
    sofa = merge([box((-2.95, 0.0, -1.2), (-2.1, 0.45, 1.2)), box((-2.95, 0.45, -1.2), (-2.75, 0.95, 1.2))])
    b.mesh("sofa", sofa, _twosided((0.45, 0.18, 0.12)))
    b.mesh("table", merge([box((-1.3, 0.38, -0.6), (-0.3, 0.44, 0.6))] +
                          [box((x, 0.0, z), (x + 0.05, 0.38, z + 0.05)) for x in (-1.25, -0.4) for z in (-0.55, 0.5)]),
           _twosided((0.35, 0.25, 0.16)))
    b.mesh("shelf", box((-1.5, 0.0, -2.48), (0.3, 1.9, -2.1)), _twosided((0.5, 0.5, 0.55)))
    b.mesh("chimney", box((1.5, H, 1.4), (2.0, 3.3, 1.9)), _twosided((0.5, 0.35, 0.3)))
    cam = Camera((-2.5, 1.55, 2.2), (1.5, 0.9, -1.4), (0, 1, 0), 75.0)
    if not sun:
        b.add("sky", _sky(LIVING_ENV_SKY))
        return b.build(cam, "Thin-walled living room lit by a bright sky through its window, glossy floor",
                       duration=4.0, probe_box=LIVING_PROBE_BOX, probe_counts=LIVING_PROBE_COUNTS)
    b.add("sun", _sun(LIVING_SUN, LIVING_SUN_IRRADIANCE))
    b.add("sky", _sky(LIVING_SKY))
    b.animate(SunMotion("sun", Track([0.0, 1.0, 2.0, 4.0], [LIVING_SUN, LIVING_SUN, LIVING_SUN_LATER,
                                                           LIVING_SUN_LATER], interp="smooth")))
    return b.build(cam, "Thin-walled living room lit by the sun through a window", duration=4.0,
                   probe_box=LIVING_PROBE_BOX, probe_counts=LIVING_PROBE_COUNTS)
